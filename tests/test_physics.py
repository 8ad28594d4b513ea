"""Whole-run physics: energy, stiffness, current-loop bandwidth, stiction, convergence."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stepdamp_env import kernel as K
from stepdamp_env.presets import get_preset
from stepdamp_env.simulation import RunSettings, SpeedProfile, build_config, simulate

from conftest import run_raw


def _energy_terms(c, s0, s1):
    p = K.plant_params(c)
    L, J = c[K.CONFIG.L], c[K.CONFIG.J]
    mag = 0.5 * L * (s1[K.STATE.IA] ** 2 + s1[K.STATE.IB] ** 2 - s0[K.STATE.IA] ** 2 - s0[K.STATE.IB] ** 2)
    kin = 0.5 * J * (s1[K.STATE.OMEGA] ** 2 - s0[K.STATE.OMEGA] ** 2)
    det = K.detent_potential(s1[K.STATE.THETA], p) - K.detent_potential(s0[K.STATE.THETA], p)
    losses = s1[K.STATE.E_CU] + s1[K.STATE.E_DAMP] + s1[K.STATE.E_FRIC] + s1[K.STATE.E_LOAD]
    return s1[K.STATE.E_IN], mag + kin + det + losses


@pytest.mark.parametrize("mode,damping,load", [("open-loop", "none", 0.0),
                                                ("open-loop", "patent-ff", 0.02),
                                                ("servo", "patent-ff", 0.0)])
def test_energy_balance_closes_over_a_whole_run(patent, mode, damping, load):
    # Supplied = copper + magnetic change + kinetic change + detent potential
    # change + viscous + friction + load work, at a resonant speed with a ramp.
    system = patent.replace(load_torque=load)
    speed = system.predicted_resonances_rps()[4]
    settings = RunSettings(mode=mode, base_controller=damping)
    c = build_config(system, SpeedProfile(speed), settings)
    from stepdamp_env.simulation import initial_state

    s0 = initial_state(c)
    _, s1, _, _ = run_raw(system, SpeedProfile(speed), settings, n_periods=10000,
                          state=s0.copy(), trace_every=10000)
    supplied, accounted = _energy_terms(c, s0, s1)
    assert supplied > 0.01       # joules: a real run, not a trivially small one
    assert abs(supplied - accounted) / supplied < 1e-3
    # Every channel is actually exercised.
    assert s1[K.STATE.E_CU] > 0 and s1[K.STATE.E_DAMP] > 0 and s1[K.STATE.E_FRIC] > 0
    if load:
        assert s1[K.STATE.E_LOAD] > 0


def test_energy_balance_tightens_with_a_finer_step(patent):
    speed = patent.predicted_resonances_rps()[2]
    errors = []
    for sub in (1, 4):
        settings = RunSettings(substeps=sub)
        c = build_config(patent, SpeedProfile(speed), settings)
        from stepdamp_env.simulation import initial_state

        s0 = initial_state(c)
        _, s1, _, _ = run_raw(patent, SpeedProfile(speed), settings, n_periods=6000,
                              state=s0.copy())
        supplied, accounted = _energy_terms(c, s0, s1)
        errors.append(abs(supplied - accounted) / supplied)
    assert errors[1] <= errors[0]


def test_static_stiffness_matches_km_i_nr(still):
    # Detent and friction off, a small load torque: the rotor settles where
    # Km*I*sin(Nr*dtheta) = -T, i.e. stiffness Km*I*Nr for small angles.
    base = get_preset("patent")
    torque = 0.01
    system = base.replace(Kd1=0.0, Kd2=0.0, Kd4=0.0, Fs=0.0, D=0.05, load_torque=torque)
    _, s, _, _ = run_raw(system, still, n_periods=20000, trace_every=20000)
    disp = s[K.STATE.THETA]
    m, i_hold = system.motor, system.drive.holding_current
    k_lin = m.Km * i_hold * m.Nr
    assert abs(s[K.STATE.OMEGA]) < 1e-6
    assert torque / -disp == pytest.approx(k_lin, rel=0.01)
    exact = -math.asin(torque / (m.Km * i_hold)) / m.Nr
    assert disp == pytest.approx(exact, rel=1e-3)


@pytest.mark.parametrize("fc", [500.0, 1500.0, 2500.0])
def test_current_loop_step_response_matches_designed_bandwidth(still, fc):
    # Rotor effectively locked (huge J, no detent), a 0.2 A step of the d
    # current from zero, small enough not to saturate the bridge. The step
    # response of an LTI loop fixes its frequency response: the impulse
    # response is its first difference, and |T(f)| is -3 dB at the bandwidth.
    base = get_preset("patent")
    system = base.replace(J=10.0, Kd1=0.0, Kd2=0.0, Kd4=0.0, holding_current=0.2,
                          current_bandwidth_hz=fc)
    _, _, _, tr = run_raw(system, still, n_periods=2000, state=np.zeros(len(K.STATE)))
    step = tr["ia"] / 0.2             # angle 0: id = ia
    impulse = np.diff(np.concatenate([[0.0], step]))
    freqs = np.arange(1.0, 5000.0, 1.0)
    k = np.arange(len(impulse))
    gain = np.abs(np.exp(-2j * np.pi * np.outer(freqs, k) / system.drive.pwm_hz) @ impulse)
    bandwidth = freqs[np.argmax(gain < 1 / math.sqrt(2))]
    assert bandwidth == pytest.approx(fc, rel=0.2)
    assert gain.max() < 1.01          # no resonant peaking at these bandwidths
    assert step[-1] == pytest.approx(1.0, abs=1e-9)
    # The first sample after the step still shows the old current: the
    # computation delay plus the hold means nothing moves for one period.
    assert step[1] == 0.0 and step[2] > 0.0


def test_current_loop_anti_windup_recovers_from_saturation(still):
    # A 1.9 A step on a 12 V bus saturates the bridge for a while; with the
    # back-calculation anti-windup the current settles without a windup overshoot.
    base = get_preset("patent")
    system = base.replace(J=10.0, Kd1=0.0, Kd2=0.0, Kd4=0.0, Vdc=12.0)
    _, _, _, tr = run_raw(system, still, n_periods=2000, state=np.zeros(len(K.STATE)))
    i_target = system.drive.holding_current
    assert np.any(np.abs(tr["va"]) > 0.99 * 12.0)          # it did saturate
    assert tr["ia"].max() < 1.05 * i_target
    assert tr["ia"][-1] == pytest.approx(i_target, rel=1e-6)


def test_stiction_holds_below_breakaway_and_slides_above(still):
    base = get_preset("patent")
    # No winding current (servo mode with zero gains and no feedforward), no
    # detent, and a negligible Km so back-EMF currents add no electrical drag.
    free = base.replace(Kd1=0.0, Kd2=0.0, Kd4=0.0, D=0.0, Kp_vel=0.0, Kp_pos=0.0, Ki_pos=0.0,
                        Km=1e-9)
    fs = free.motor.Fs
    settings = RunSettings(mode="servo", base_controller="none")
    held = free.replace(load_torque=0.9 * fs)
    _, s, _, _ = run_raw(held, still, settings, n_periods=4000)
    assert s[K.STATE.THETA] == 0.0 and s[K.STATE.OMEGA] == 0.0
    # Above breakaway: constant deceleration (load - Fs)/J in the negative sense.
    load = 3.0 * fs
    slid = free.replace(load_torque=load)
    n = 4000
    _, s, _, _ = run_raw(slid, still, settings, n_periods=n)
    t = n / free.drive.pwm_hz
    J = free.motor.J
    assert s[K.STATE.OMEGA] == pytest.approx(-(load - fs) / J * t, rel=1e-6)
    assert s[K.STATE.THETA] == pytest.approx(-0.5 * (load - fs) / J * t * t, rel=1e-3)


def test_coulomb_friction_stops_a_coasting_rotor_and_keeps_it_stopped(still):
    base = get_preset("patent")
    free = base.replace(Kd1=0.0, Kd2=0.0, Kd4=0.0, D=0.0, Kp_vel=0.0, Kp_pos=0.0, Ki_pos=0.0,
                        Km=1e-9)
    settings = RunSettings(mode="servo", base_controller="none")
    c = build_config(free, still, settings)
    from stepdamp_env.simulation import initial_state

    s = initial_state(c)
    w0 = 2.0
    s[K.STATE.OMEGA] = w0
    fs, J = free.motor.Fs, free.motor.J
    t_stop = w0 * J / fs
    n = int(2 * t_stop * free.drive.pwm_hz)
    _, s, _, tr = run_raw(free, still, settings, n_periods=n, state=s)
    assert s[K.STATE.OMEGA] == 0.0
    assert s[K.STATE.THETA] == pytest.approx(0.5 * w0 * t_stop, rel=1e-3)
    assert np.all(tr["omega"] >= 0.0)        # no reversal


@pytest.mark.parametrize("mode,encoder_cpr", [("open-loop", 4000), ("servo", 1 << 20)])
def test_metrics_converge_against_a_ten_times_finer_plant_step(patent, mode, encoder_cpr):
    system = patent.replace(encoder_cpr=encoder_cpr)
    speed = system.predicted_resonances_rps()[2]
    coarse = simulate(system, speed_rps=speed, settings=RunSettings(mode=mode, substeps=1))
    fine = simulate(system, speed_rps=speed, settings=RunSettings(mode=mode, substeps=10))
    a, b = coarse.metrics, fine.metrics
    for key in ("rms_velocity_error_rad_s", "p2p_velocity_error_rad_s", "max_position_lag_rad"):
        assert getattr(a, key) == pytest.approx(getattr(b, key), rel=1e-3), key
    for h in (1, 2, 4):
        assert a.harmonic_amplitude_rad_s[h] == pytest.approx(
            b.harmonic_amplitude_rad_s[h], rel=1e-3, abs=1e-3 * b.rms_velocity_error_rad_s)


def test_servo_with_a_coarse_encoder_agrees_statistically(patent):
    # With 4000 counts/rev a 1e-9 rad difference moves a count edge by a period,
    # and the quantised loop carries that on: the runs then agree as samples of
    # the same noise, not to the bit (1e-3 holds with a fine encoder, above).
    speed = patent.predicted_resonances_rps()[2]
    a = simulate(patent, speed_rps=speed, settings=RunSettings(mode="servo", substeps=1))
    b = simulate(patent, speed_rps=speed, settings=RunSettings(mode="servo", substeps=10))
    assert a.metrics.rms_velocity_error_rad_s == pytest.approx(
        b.metrics.rms_velocity_error_rad_s, rel=0.02)
    assert a.metrics.max_position_lag_rad == pytest.approx(b.metrics.max_position_lag_rad,
                                                           rel=1e-3)


def test_rk4_error_falls_with_the_fourth_power_of_the_step(patent):
    # Errors against a 64-substep reference shrink about 16x per halving of
    # the step. Friction off: a stick-slip decision is taken once per substep,
    # so breakaway instants are first order in the step by design.
    system = patent.replace(Fs=0.0)
    speed = patent.predicted_resonances_rps()[4]
    finals = {}
    for sub in (1, 2, 4, 64):
        _, s, _, _ = run_raw(system, SpeedProfile(speed), RunSettings(substeps=sub),
                             n_periods=2000)
        finals[sub] = s[K.STATE.THETA]
    e1 = abs(finals[1] - finals[64])
    e2 = abs(finals[2] - finals[64])
    e4 = abs(finals[4] - finals[64])
    assert e1 < 1e-6                       # rad, against a 1.96e-4 rad microstep
    assert e1 / e2 > 8 and e2 / e4 > 8


def test_same_inputs_give_bit_identical_traces(patent):
    a = simulate(patent, speed_rps=1.3, base_controller="patent-ff", trace=True)
    b = simulate(patent, speed_rps=1.3, base_controller="patent-ff", trace=True)
    for key in a.trace:
        assert np.array_equal(a.trace[key], b.trace[key]), key
    assert a.metrics == b.metrics


def test_chunked_runs_equal_one_long_run(patent):
    # The environment advances the kernel in agent steps; that must not change a bit.
    prof = SpeedProfile(1.0)
    c = build_config(patent, prof, RunSettings())
    from stepdamp_env.simulation import initial_state

    s_long = initial_state(c)
    s_chunk = s_long.copy()
    empty = np.zeros((0, len(K.TRACE)))
    u = np.zeros(len(K.INPUT))
    K.run_periods(c, s_long, np.zeros(len(K.ACC)), u, 2000, empty, 1)
    for _ in range(100):
        K.run_periods(c, s_chunk, np.zeros(len(K.ACC)), u, 20, empty, 1)
    assert np.array_equal(s_long, s_chunk)


def test_trace_voltages_are_the_applied_winding_voltages_one_period_late(patent):
    res = simulate(patent, speed_rps=1.0, trace=True, duration_s=0.5)
    tr = res.trace
    assert np.all(np.abs(tr["va"]) <= patent.drive.Vdc + 1e-9)
    # Computation delay: what period k applies was computed from period k-1's samples,
    # so the d/q voltage in the frame of k-1 follows the PI of k-1.
    assert tr["va"][0] == pytest.approx(patent.motor.R * patent.drive.holding_current)


def test_open_loop_park_angle_uses_microstep_quantised_command(patent):
    res = simulate(patent, speed_rps=0.5, trace=True, duration_s=0.5)
    c = build_config(patent, SpeedProfile(0.5), RunSettings())
    micro = c[K.CONFIG.MICROSTEP]
    q = np.floor(res.trace["theta_cmd"] / micro) * micro
    # id is measured in the frame of the quantised command angle: the holding
    # current is along it, so id ~ holding current and iq ~ 0.
    assert np.median(res.trace["id"]) == pytest.approx(patent.drive.holding_current, rel=0.02)
    assert np.max(np.abs(q - res.trace["theta_cmd"])) <= micro


def test_servo_velocity_estimate_has_encoder_resolution(patent):
    res = simulate(patent, speed_rps=1.0, mode="servo", trace=True, duration_s=0.6)
    counts = res.trace["theta_fb"] / (2 * math.pi / patent.servo.encoder_cpr)
    assert np.allclose(counts, np.round(counts), atol=1e-6)
    steady = res.trace["t"] > res.window_start_s
    assert np.mean(res.trace["omega_fb"][steady]) == pytest.approx(2 * math.pi * 1.0, rel=0.02)
