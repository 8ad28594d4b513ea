"""Sensors: current-sensor noise and offset, the Kalman velocity estimator."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stepdamp_env import kernel as K
from stepdamp_env.estimators import kalman_velocity_filter, kalman_velocity_gains
from stepdamp_env.presets import get_preset
from stepdamp_env.simulation import RunSettings, SpeedProfile, build_config, simulate

from conftest import run_raw


def test_gaussian_pair_is_standard_normal_and_counter_based():
    samples = np.array([K.gaussian_pair(7, k) for k in range(40000)]).ravel()
    assert abs(samples.mean()) < 0.02
    assert samples.std() == pytest.approx(1.0, abs=0.02)
    assert np.mean(np.abs(samples) > 1.96) == pytest.approx(0.05, abs=0.005)
    assert K.gaussian_pair(7, 123) == K.gaussian_pair(7, 123)
    assert K.gaussian_pair(7, 123) != K.gaussian_pair(8, 123)
    # The two outputs of a pair are uncorrelated.
    pairs = np.array([K.gaussian_pair(3, k) for k in range(20000)])
    assert abs(np.corrcoef(pairs.T)[0, 1]) < 0.03


def test_measured_currents_carry_offset_and_noise(still):
    # Rotor locked, holding current on: the measured d current (angle 0: ia)
    # is the true one plus offset plus noise of the set standard deviation.
    system = get_preset("patent").replace(J=10.0, current_noise_a=0.05, current_offset_a=0.02,
                                          current_offset_b=-0.01, Kd1=0.0, Kd2=0.0, Kd4=0.0)
    _, _, _, tr = run_raw(system, still, RunSettings(noise_seed=11), n_periods=20000)
    error = tr["id"][1000:] - tr["ia"][1000:]
    assert error.mean() == pytest.approx(0.02, abs=0.002)
    assert error.std() == pytest.approx(0.05, rel=0.05)
    # The loop regulates the measured current, so the true one sits off by the offset.
    assert tr["ia"][1000:].mean() == pytest.approx(1.9 - 0.02, abs=0.002)


def test_noisy_runs_are_bit_identical_per_seed_and_differ_across_seeds():
    system = get_preset("patent").replace(current_noise_a=0.05)
    a = simulate(system, speed_rps=1.0, settings=RunSettings(noise_seed=1), trace=True)
    b = simulate(system, speed_rps=1.0, settings=RunSettings(noise_seed=1), trace=True)
    c = simulate(system, speed_rps=1.0, settings=RunSettings(noise_seed=2), trace=True)
    assert np.array_equal(a.trace["omega"], b.trace["omega"])
    assert not np.array_equal(a.trace["omega"], c.trace["omega"])


def test_kernel_kalman_estimator_equals_filterpy_in_steady_state():
    # Feed filterpy's filter the encoder samples the kernel saw; once its gain
    # has converged it must give the kernel's velocity estimate.
    system = get_preset("patent")
    settings = RunSettings(mode="servo", velocity_estimator="kalman")
    res = simulate(system, speed_rps=0.8, settings=settings, trace=True, duration_s=0.4)
    tr = res.trace
    c = build_config(system, SpeedProfile(0.8), settings)
    q = c[K.CONFIG.ENCODER]
    dt = c[K.CONFIG.DT]
    k0, k1 = kalman_velocity_gains(dt, q, system.servo.kalman_accel_std)
    assert (c[K.CONFIG.KF_K0], c[K.CONFIG.KF_K1]) == (k0, k1)
    # Replay the kernel's fixed-gain recursion from filterpy's predict step.
    kf = kalman_velocity_filter(dt, q, system.servo.kalman_accel_std)
    kf.x = np.array([[tr["theta_fb"][0] + 0.5 * q], [0.0]])
    replay = []
    for z in tr["theta_fb"]:
        kf.predict()
        kf.update(np.array([[z + 0.5 * q]]))
        replay.append(kf.x[1, 0])
    replay = np.array(replay)
    late = slice(len(replay) // 2, None)
    assert np.allclose(replay[late], tr["omega_fb"][late], rtol=0, atol=1e-6)


def test_kalman_estimator_tracks_speed_and_is_quieter_than_raw_difference():
    system = get_preset("patent")
    res = simulate(system, speed_rps=1.0, settings=RunSettings(mode="servo",
                                                               velocity_estimator="kalman"),
                   trace=True)
    tr = res.trace
    steady = tr["t"] > res.window_start_s
    assert np.mean(tr["omega_fb"][steady]) == pytest.approx(2 * math.pi, rel=0.01)
    raw = np.diff(tr["theta_fb"]) * system.drive.pwm_hz
    assert np.std(tr["omega_fb"][steady]) < 0.2 * np.std(raw[steady[1:]])


def test_sensor_fields_are_validated():
    with pytest.raises(ValueError, match="current_noise_a=-0.1 is outside"):
        get_preset("patent").replace(current_noise_a=-0.1)
    with pytest.raises(ValueError, match="velocity_estimator"):
        RunSettings(velocity_estimator="magic")
    with pytest.raises(ValueError, match="noise_seed"):
        RunSettings(noise_seed=-1)


def test_a_too_slow_kalman_filter_is_refused_at_once():
    """kalman_accel_std=1e-6 once iterated 14 s and then raised 'did not converge'."""
    import math
    import time

    from stepdamp_env.estimators import kalman_velocity_gains, min_kalman_accel_std
    from stepdamp_env.params import ParameterError

    dt, count = 1 / 20000, 2 * math.pi / 4000
    low = min_kalman_accel_std(dt, count)
    assert 0.1 < low < 1.0                     # rad/s^2 for the patent's encoder at 20 kHz
    t0 = time.perf_counter()
    with pytest.raises(ParameterError, match=r"kalman_accel_std=1e-06 is outside its allowed"):
        kalman_velocity_gains(dt, count, 1e-6)
    assert time.perf_counter() - t0 < 0.1
    k0, k1 = kalman_velocity_gains(dt, count, 1.001 * low)       # the edge still designs
    assert 0 < k0 < 1 and k1 > 0
