"""Point-to-point moves: the S-curve command, the closed metrics window, the
position error over a run, and stepdamp-bench v4's moves suite."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stepdamp_env import kernel as K
from stepdamp_env import get_preset
from stepdamp_env.params import ParameterError
from stepdamp_env.simulation import (RunSettings, SpeedProfile, max_move_distance_rev,
                                     simulate)

TWO_PI = 2 * math.pi


def _command(kind: int, speed_rps: float, accel_rps2: float, distance_rev: float, ts):
    th, w = zip(*(K.command(t, kind, TWO_PI * speed_rps, TWO_PI * accel_rps2,
                            TWO_PI * distance_rev) for t in ts))
    return np.array(th), np.array(w)


@pytest.mark.parametrize("distance", [3.0, -2.0, 0.05])
def test_s_curve_integrates_to_its_distance_with_bounded_jerk(distance):
    speed, accel = 2.0, 20.0
    prof = SpeedProfile(speed_rps=speed, accel_rps2=accel, kind="move", ramp="s-curve",
                        distance_rev=distance)
    ts = np.linspace(0, prof.duration_s() * 1.1, 80001)
    th, w = _command(K.PROFILE.S_CURVE, speed, accel, distance, ts)
    assert th[-1] == pytest.approx(TWO_PI * distance, abs=1e-12)
    assert w[-1] == 0.0
    # The speed command is the derivative of the position command.
    integral = np.concatenate([[0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(ts))])
    assert np.max(np.abs(integral - th)) < 1e-5
    # Acceleration: continuous from 0, its peak the profile's (an S-curve), never above.
    a = np.diff(w) / np.diff(ts)
    peak = TWO_PI * accel
    assert np.max(np.abs(a)) <= peak * (1 + 1e-6)
    assert abs(a[0]) < 1e-3 * peak
    assert np.max(np.abs(np.diff(a))) < 1e-2 * peak
    v_top = min(speed, math.sqrt(2 * accel * abs(distance) / math.pi))
    assert np.max(np.abs(w)) == pytest.approx(TWO_PI * v_top, rel=1e-6)
    if v_top == speed:
        assert np.max(np.abs(a)) == pytest.approx(peak, rel=1e-4)
    # It arrives when duration_s says, not before.
    end = prof.duration_s()
    assert abs(th[ts < end * (1 - 1e-3)][-1]) < TWO_PI * abs(distance)


@pytest.mark.parametrize("ramp", ["trapezoid", "s-curve"])
def test_cruise_and_longest_move_invert_duration(ramp):
    prof = SpeedProfile(speed_rps=1.5, accel_rps2=30.0, kind="move", ramp=ramp, distance_rev=2.0)
    start, length = prof.cruise()
    assert start == pytest.approx(prof.ramp_s)
    assert start * 2 + length == pytest.approx(prof.duration_s())
    ts = np.linspace(start + 1e-6, start + length - 1e-6, 101)
    code = K.PROFILE.MOVE if ramp == "trapezoid" else K.PROFILE.S_CURVE
    _, w = _command(code, 1.5, 30.0, 2.0, ts)
    assert np.all(w == TWO_PI * 1.5)
    for d in (0.01, 2.0, 40.0):
        p = SpeedProfile(speed_rps=1.5, accel_rps2=30.0, kind="move", ramp=ramp, distance_rev=d)
        assert max_move_distance_rev(1.5, 30.0, p.duration_s(), ramp) == pytest.approx(d)


def test_a_closed_window_is_a_run_stopped_at_its_end():
    """Metrics over [a, b) equal those of a run measured from a and stopped at b."""
    from stepdamp_env.env.scalar import StepperDampEnv

    def metrics(until):
        env = StepperDampEnv(motor="patent", speed_rps=1.0, measure_from_s=0.2,
                             measure_until_s=until, agent_hz=1000.0)
        env.reset(seed=3)
        steps = 300 if until is None else 400
        for _ in range(steps):
            env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        return env.run_metrics().to_dict()

    stopped, closed = metrics(None), metrics(0.3)
    for k in ("rms_velocity_error_rad_s", "harmonic_amplitude_rad_s", "position_ripple_steps",
              "rms_injected_current_a"):
        assert closed[k] == stopped[k], k


def test_run_position_error_is_the_rms_over_every_sample():
    system = get_preset("patent")
    prof = SpeedProfile(speed_rps=2.0, accel_rps2=100.0, kind="move", ramp="s-curve",
                        distance_rev=1.0)
    res = simulate(system, profile=prof, settings=RunSettings(), trace=True)
    err = np.asarray(res.trace["theta_cmd"]) - np.asarray(res.trace["theta"])
    want = math.sqrt(np.mean(err ** 2)) / system.motor.full_step_rad
    assert res.metrics.run_position_error_steps == pytest.approx(want, rel=1e-9)
    # The rotor ends where the command rests: within a fraction of a step.
    assert abs(err[-1]) < 0.2 * system.motor.full_step_rad


def test_env_move_options_are_checked():
    from stepdamp_env.env.scalar import StepperDampEnv

    with pytest.raises(ParameterError, match="profile"):
        StepperDampEnv(profile="jerk")
    with pytest.raises(ParameterError, match="distance_rev"):
        StepperDampEnv(distance_rev=1.0)
    with pytest.raises(ParameterError, match="distance_rev"):
        StepperDampEnv(profile="move", speed_rps=1.0)
    with pytest.raises(ParameterError, match="measure_until_s"):
        StepperDampEnv(measure_from_s=0.3, measure_until_s=0.2)
    with pytest.raises(ParameterError, match="measure_until_s needs measure_from_s"):
        StepperDampEnv(measure_until_s=0.2)
    with pytest.raises(ParameterError, match="ramp"):
        StepperDampEnv(ramp="s-curve")
    with pytest.raises(ParameterError, match=r"0 < \|distance_rev\| <= 1e6"):
        StepperDampEnv(profile="move", speed_rps=1.0, distance_rev=0.0)
    with pytest.raises(ParameterError, match="ramp='s-curve' needs kind='move'"):
        SpeedProfile(speed_rps=1.0, ramp="s-curve")


def test_a_move_too_short_to_cruise_is_refused_in_one_line():
    from stepdamp_env.bench.runner import move_window

    prof = SpeedProfile(speed_rps=2.0, accel_rps2=20.0, kind="move", distance_rev=0.1)
    with pytest.raises(ParameterError, match="distance_rev=0.1 never reaches"):
        move_window(get_preset("patent"), prof)


def test_the_moves_suite_is_v4s_only():
    from stepdamp_env.bench.protocol import ALL_SUITES
    from stepdamp_env.bench.protocols.v3 import full_protocol_v3
    from stepdamp_env.bench.protocols.v4 import full_protocol_v4
    from stepdamp_env.bench.suites import SUITES_THROUGH_V3, suite_of, tuned_suite

    assert SUITES_THROUGH_V3 == ALL_SUITES == ("open-loop", "servo", "mid-band")
    assert "moves" not in full_protocol_v3().suites
    assert "moves" in full_protocol_v4().suites
    assert suite_of("open-loop", "current") == "open-loop"
    assert tuned_suite("moves", {"open-loop": 1}) == "open-loop"
    assert tuned_suite("moves", {"moves": 1, "open-loop": 1}) == "moves"


def test_v4_moves_cells_cruise_a_whole_window_through_the_lower_resonances():
    from stepdamp_env.bench.protocols.v4 import quick_protocol_v4
    from stepdamp_env.bench.runner import move_window

    protocol = quick_protocol_v4()
    motors = protocol.motors()
    for motor in motors:
        speeds, labels = motor.speeds("moves")
        ol_speeds, ol_labels = motor.speeds("open-loop")
        headline = sorted(v for v, lb in zip(ol_speeds, ol_labels) if not lb.startswith("off"))
        assert sorted(set(speeds)) == headline[-2:]
        assert [lb.split("-", 1)[1] for lb in labels] == ["trapezoid", "s-curve"] * len(
            set(speeds))
        m = motor.system.motor
        limit = protocol.move_torque_share * m.Km * motor.system.drive.holding_current / m.J
        for j, v in enumerate(speeds):
            cmd = protocol.run_command(motor, "moves", j)
            assert TWO_PI * cmd["accel_rps2"] <= limit * (1 + 1e-12)
            prof = SpeedProfile(speed_rps=v, kind=cmd["profile"], ramp=cmd["ramp"],
                                accel_rps2=cmd["accel_rps2"], distance_rev=cmd["distance_rev"])
            start, length, end = move_window(motor.system, prof, motor.settle_s("moves"))
            assert start == pytest.approx(prof.ramp_s)
            assert protocol.window_s <= length < protocol.window_s + 1.0 / (m.Nr * v) + 1e-9
            assert end == pytest.approx(prof.duration_s() + motor.settle_s("moves"))
        assert protocol.run_command(motor, "open-loop", 0) == {}


def test_simulate_runs_an_s_curve_move_and_refuses_a_ramp_without_one(capsys):
    import json

    from stepdamp_env.cli import main

    assert main(["simulate", "--speed", "2", "--move", "1", "--ramp", "s-curve", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["profile"] == "move" and record["ramp"] == "s-curve"
    assert record["move_rev"] == 1.0
    assert record["run_position_error_steps"] > 0.0
    assert main(["simulate", "--speed", "2", "--ramp", "s-curve"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--ramp" in err


@pytest.mark.slow
def test_a_v4_moves_board_on_a_users_motor_scores_each_ramp_as_a_cell_and_plots(tmp_path):
    import json
    import lzma

    from stepdamp_env.bench.protocols.v4 import CATALOGUE_PATH
    from stepdamp_env.cli import main

    with open(CATALOGUE_PATH, encoding="utf-8") as fh:
        items = [m for m in json.load(fh) if m["name"] == "qsh4218-35-10-027"]
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(items))
    out = tmp_path / "board"
    assert main(["leaderboard", "--protocol", "v4", "--quick", "--motors", str(path),
                 "--suite", "moves", "--entries", "tuned-gain-pair", "plant-bound",
                 "--eval-seeds", "1", "--out", str(out), "--no-progress", "--workers", "1"]) == 0
    board = json.loads((out / "leaderboard.json").read_text())
    (motor,) = board["protocol"]["motors"]
    labels = motor["grids"]["moves"]["speed_labels"]
    (t,) = board["tables"]
    # Its two fastest open-loop headline speeds (h4, h2), each with both ramps: 4 cells.
    assert t["cells"]["split"] == len(labels) == 4
    assert [lb.split("-", 1)[1] for lb in labels] == ["trapezoid", "s-curve"] * 2
    assert t["bound_check"]["holds"] == 1, t["bound_check"]
    with lzma.open(out / "leaderboard_runs.json.xz", "rt", encoding="utf-8") as fh:
        kept = json.load(fh)
    runs = [r for e in kept["entries"] if e["name"] == "none" for r in e["runs"]]
    assert sorted(r["speed_label"] for r in runs) == sorted(labels)
    assert all(r["window_s"] >= board["protocol"]["window_s"] for r in runs)
    assert (out / "velocity_error_moves.png").stat().st_size > 10_000
