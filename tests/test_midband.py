"""The voltage-mode drive, the mid-band analysis and stepdamp-bench v2's mid-band suite."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from stepdamp_env import kernel as K
from stepdamp_env.analysis import (HIGH_RIPPLE, bridge_gain, bridge_limit_rps, measured_band,
                                   midband, operating_point, rotor_damping, undamped_ripple)
from stepdamp_env.params import ParameterError, SystemParams
from stepdamp_env.motorfile import load_system, parse_set_overrides
from stepdamp_env.presets import get_preset, preset_names
from stepdamp_env.simulation import RunSettings, SpeedProfile, build_config, initial_state

from conftest import run_raw
from test_physics import _energy_terms


# -- the parameter --------------------------------------------------------------
def test_drive_mode_is_a_parameter_json_key_and_set_name(tmp_path):
    patent = get_preset("patent")
    assert patent.drive.drive_mode == "current"
    # Left out of the flat dict while it is the default: older files stay byte-identical.
    assert "drive_mode" not in patent.to_dict()
    voltage = patent.replace(drive_mode="voltage")
    assert voltage.to_dict()["drive_mode"] == "voltage"
    assert SystemParams.from_dict(voltage.to_dict()) == voltage
    path = tmp_path / "m.json"
    path.write_text(json.dumps({"base": "patent", "drive_mode": "voltage"}))
    assert load_system(str(path)).drive.drive_mode == "voltage"
    assert parse_set_overrides(["drive_mode=voltage"]) == {"drive_mode": "voltage"}
    for bad in ("fast", 1.0, None):
        with pytest.raises(ParameterError, match=r"drive_mode=.* is not one of \['current', "
                                                 r"'voltage'\]"):
            patent.replace(drive_mode=bad)
    with pytest.raises(ParameterError, match="--set drive_mode"):
        parse_set_overrides(["drive_mode=Voltage"])


def test_current_mode_config_is_unchanged_and_voltage_mode_sets_its_model():
    patent = get_preset("patent")
    c = build_config(patent, SpeedProfile(1.0), RunSettings())
    assert c[K.CONFIG.DRIVE_MODE] == K.DRIVE.CURRENT
    cv = build_config(patent.replace(drive_mode="voltage"), SpeedProfile(1.0), RunSettings())
    assert cv[K.CONFIG.DRIVE_MODE] == K.DRIVE.VOLTAGE
    assert (cv[K.CONFIG.R_EST], cv[K.CONFIG.L_EST]) == (patent.motor.R, patent.motor.L)
    assert np.array_equal(np.delete(c, K.CONFIG.DRIVE_MODE), np.delete(cv, K.CONFIG.DRIVE_MODE))


# -- the kernel's voltage law -----------------------------------------------------
def _voltage_step(system, theta, ia, ib, period, speed_rps):
    c = build_config(system, SpeedProfile(speed_rps, accel_rps2=1e9), RunSettings())
    q = K.controller_params(c)
    cs = (1.0, 2.0, theta, 2 * math.pi * speed_rps, 0.0, theta, ia, ib, 0.0, 0.0)
    return c, K.control_step(float(period), theta, ia, ib, cs, q, (0.0,) * len(K.INPUT))[:3]


@pytest.mark.slow
def test_voltage_law_is_the_winding_model_turned_to_the_next_period():
    # No current feedback: the voltages do not depend on the measured currents,
    # the PI integrators are left alone, and the vector is the model's
    # (R*I, w_e*L*I + Km*w) turned to the middle of the period it is applied in.
    system = get_preset("patent").replace(drive_mode="voltage", microsteps=65536)
    speed = 2.0
    period = 1000
    c, (cs1, v1, obs1) = _voltage_step(system, 0.1, 1.9, 0.0, period, speed)
    _, (cs2, v2, _) = _voltage_step(system, 0.1, -3.0, 0.7, period, speed)
    assert v1 == v2
    assert cs1[:2] == (1.0, 2.0)
    m, hold = system.motor, system.drive.holding_current
    w = 2 * math.pi * speed
    w_e = m.Nr * w
    vd, vq = m.R * hold, w_e * m.L * hold + m.Km * w
    angle = obs1[7] + 1.5 * c[K.CONFIG.DT] * w_e
    expect = (vd * math.cos(angle) - vq * math.sin(angle),
              vd * math.sin(angle) + vq * math.cos(angle))
    assert v1 == pytest.approx(expect, abs=1e-9)


def test_voltage_mode_holds_the_commanded_current_in_steady_state():
    # A winding model equal to the winding and no detent, friction or load: the
    # steady currents are the commanded ones (d = holding current, q = 0).
    base = get_preset("patent").replace(Kd1=0.0, Kd2=0.0, Kd4=0.0, Fs=0.0, D=0.0,
                                        drive_mode="voltage", microsteps=65536)
    _, s, _, tr = run_raw(base, SpeedProfile(1.0, accel_rps2=20.0), n_periods=40000,
                          trace_every=1)
    tail = slice(-2000, None)
    assert np.max(np.abs(tr["id"][tail] - 1.9)) < 0.02
    assert np.max(np.abs(tr["iq"][tail])) < 0.02
    assert s[K.STATE.INT_D] == initial_state(build_config(
        base, SpeedProfile(1.0, accel_rps2=20.0), RunSettings()))[K.STATE.INT_D]


def test_energy_balance_of_the_voltage_mode_drive_closes_to_0_1_percent():
    # Inside the mid-band, where the rotor swings hardest.
    system = get_preset("patent").replace(drive_mode="voltage", load_torque=0.02)
    settings = RunSettings()
    profile = SpeedProfile(5.0)
    c = build_config(system, profile, settings)
    s0 = initial_state(c)
    _, s1, _, _ = run_raw(system, profile, settings, n_periods=20000, state=s0.copy(),
                          trace_every=20000)
    supplied, accounted = _energy_terms(c, s0, s1)
    assert supplied > 0.1
    assert abs(supplied - accounted) / supplied < 1e-3
    assert s1[K.STATE.E_LOAD] > 0 and s1[K.STATE.E_FRIC] > 0


# -- the analysis -----------------------------------------------------------------
def test_bridge_gain_is_one_inside_the_circle_and_falls_outside():
    assert bridge_gain(30.0, 48.0) == pytest.approx(1.0, abs=1e-12)
    g = [abs(bridge_gain(a, 48.0)) for a in (34.0, 40.0, 60.0, 200.0)]
    assert all(x > y for x, y in zip(g, g[1:]))
    # The fundamental of a square-ish wave never beats the hexagon's corner Vdc.
    assert all(abs(bridge_gain(a, 48.0)) * a <= 48.0 * 4 / math.pi for a in (60.0, 200.0))


def test_rotor_mode_at_low_speed_is_the_holding_spring():
    # Current mode: the spring alone, wn. Voltage mode: the back-EMF's currents
    # through R + L*s load the rotor too, (J*s^2 + D*s + k)*(R + L*s) + Km^2*s = 0
    # (at wn > R/L they stiffen it: about 1.36 wn on the patent preset).
    for name in preset_names():
        current = get_preset(name)
        _, lam = rotor_damping(current, 0.01)
        assert abs(lam) == pytest.approx(current.natural_frequency(), rel=0.03)
        voltage = current.replace(drive_mode="voltage")
        _, lam = rotor_damping(voltage, 0.01)
        m = voltage.motor
        k = m.Km * voltage.drive.holding_current * m.Nr
        roots = np.roots(np.polymul([m.J, m.D, k], [m.L, m.R]) + [0, 0, m.Km ** 2, 0])
        want = max(roots, key=lambda r: r.imag)
        assert lam == pytest.approx(want, rel=2e-3)


@pytest.mark.slow
def test_the_current_loop_removes_the_band_and_a_faster_winding_moves_it():
    for name in preset_names():
        system = get_preset(name)
        assert midband(system).unstable_rps is None
        assert midband(system.replace(drive_mode="voltage")).unstable_rps is not None
    # The band is where the winding's lag L/R matters at the electrical speed: a
    # faster winding (L halved) moves it to higher speeds.
    patent = get_preset("patent").replace(drive_mode="voltage")
    slow, fast = midband(patent), midband(patent.replace(L=patent.motor.L / 2))
    assert fast.unstable_rps[0] > 1.2 * slow.unstable_rps[0]
    assert fast.unstable_rps[1] > 1.2 * slow.unstable_rps[1]


def test_the_band_is_symmetric_in_the_direction_of_rotation():
    system = get_preset("patent").replace(drive_mode="voltage", Fs=0.0)
    for v in (2.0, 5.0, 9.0):
        assert rotor_damping(system, -v)[0] == pytest.approx(rotor_damping(system, v)[0],
                                                             abs=1e-6)


def test_operating_point_balances_the_load():
    system = get_preset("patent").replace(drive_mode="voltage", load_torque=0.05)
    op = operating_point(system, 2.0)
    m = system.motor
    torque = m.Km * (-op.i_d_a * math.sin(op.eps_rad) + op.i_q_a * math.cos(op.eps_rad))
    assert torque == pytest.approx(m.D * 4 * math.pi + m.Fs + 0.05, rel=1e-6)
    assert op.eps_rad < 0          # the rotor trails its command
    assert bridge_limit_rps(system) == pytest.approx(8.395, abs=0.01)


@pytest.mark.slow
@pytest.mark.parametrize("name", preset_names())
def test_simulated_band_matches_the_eigenvalue_band_within_10_percent(name):
    # The test: undamped, 1-15 rev/s, the voltage-mode drive rips in a
    # band where the current-mode drive is smooth, below the speed where the
    # current-mode drive runs out of bridge; its edges within 10 % of the
    # predicted ones.
    system = get_preset(name)
    predicted = midband(system.replace(drive_mode="voltage")).unstable_rps
    measured = measured_band(system, np.arange(1.0, 15.01, 0.5))
    assert predicted is not None and measured.band_rps is not None
    for got, want in zip(measured.band_rps, predicted):
        assert abs(got - want) <= 0.1 * want, (measured.band_rps, predicted)
    assert measured.current_mode_limit_rps > measured.band_rps[1]
    for v in np.linspace(*measured.band_rps, 5)[1:-1]:
        ripple, lost = undamped_ripple(system, float(v), "current")
        assert ripple < HIGH_RIPPLE and not lost


# -- the env and stepdamp-bench v2 ------------------------------------------------
def test_env_accepts_drive_mode():
    import gymnasium as gym

    import stepdamp_env  # noqa: F401  (registers the envs)

    env = gym.make("StepperDamp-v1", motor="patent", overrides={"drive_mode": "voltage"},
                   speed_rps=5.0)
    env.reset(seed=0)
    assert env.unwrapped.system.drive.drive_mode == "voltage"
    env.close()


@pytest.fixture(scope="module")
def v2_quick_board():
    from stepdamp_env.bench import quick_protocol_v2, run_leaderboard

    import stepdamp_baselines

    stepdamp_baselines.register_policies()
    protocol = quick_protocol_v2()
    return run_leaderboard(protocol, ["none", "velocity-feedback", "sensorless-damping"],
                           workers=2, progress=False)


def test_v2_mid_band_feedback_at_least_halves_the_undamped_ripple(v2_quick_board):
    rows = [e for e in v2_quick_board["entries"] if e["suite"] == "mid-band"]
    assert {e["split"] for e in rows} == {"interpolation", "extrapolation"}
    for e in rows:
        if e["name"] in ("velocity-feedback", "sensorless-damping"):
            assert e["headline"]["iqm"] <= 0.5, (e["name"], e["split"], e["headline"])
            assert "runs_lost" in e["step_losses"]
    motor = v2_quick_board["protocol"]["motors"][0]
    assert motor["grids"]["mid-band"]["speed_labels"] == ["m0.3", "m0.7"]
    assert motor["parameters"].get("drive_mode") is None      # the plant as drawn


def test_v2_open_loop_and_servo_equal_v1(v2_quick_board):
    from stepdamp_env.bench import quick_protocol_v1, run_leaderboard

    v1 = run_leaderboard(quick_protocol_v1(), ["none", "velocity-feedback"], workers=2,
                         progress=False)
    key = lambda e: (e["name"], e["suite"], e["split"])   # noqa: E731
    mine = {key(e): e["headline"] for e in v2_quick_board["entries"]
            if e["suite"] != "mid-band" and e["name"] != "sensorless-damping"}
    theirs = {key(e): e["headline"] for e in v1["entries"]}
    assert mine == theirs


def test_cli_analyse_and_suite_errors(tmp_path):
    out = subprocess.run([sys.executable, "-m", "stepdamp_env.cli", "analyse", "--motor",
                          "patent", "--json"], capture_output=True, text=True, check=True)
    rows = json.loads(out.stdout)
    assert [r["drive_mode"] for r in rows] == ["current", "voltage"]
    assert rows[1]["unstable_rps"][0] == pytest.approx(3.5, abs=0.05)
    bad = subprocess.run([sys.executable, "-m", "stepdamp_env.cli", "leaderboard",
                          "--protocol", "v1", "--quick", "--suite", "mid-band",
                          "--out", str(tmp_path / "x")],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1
    assert "--protocol v2" in bad.stderr
