"""stepdamp-bench v1: splits, settling, statistics (golden values, rliable), the board's
JSON fields and ``--motors``."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from stepdamp_env.bench import full_protocol, quick_protocol
from stepdamp_env.bench.motors import holds_its_load, protocol_motors
from stepdamp_env.bench.protocols import protocol_for
from stepdamp_env.bench.protocols.v1 import (SHIFTS, full_protocol_v1, in_training_distribution,
                                             load_motors_file, quick_protocol_v1)
from stepdamp_env.bench.report import open_runs_file
from stepdamp_env.bench.stats import (iqm, probability_of_improvement,
                                      stratified_bootstrap_ci, two_level_bootstrap)
from stepdamp_env.params import ParameterError
from stepdamp_env.presets import get_preset
from stepdamp_env.simulation import RunSettings, SpeedProfile, simulate


# ---------------------------------------------------------------------------
# Splits
# ---------------------------------------------------------------------------
def test_splits_are_disjoint_and_deterministic():
    motors = protocol_motors(full_protocol_v1())
    names = [m.name for m in motors]
    assert len(names) == len(set(names)) == 36
    params = [json.dumps({k: v for k, v in m.system.to_dict().items() if k != "name"},
                         sort_keys=True) for m in motors]
    assert len(set(params)) == len(params), "a motor appears twice"
    by_split = {s: [m for m in motors if m.split == s] for s in ("interpolation",
                                                                 "extrapolation")}
    assert len(by_split["interpolation"]) == 16 and len(by_split["extrapolation"]) == 20
    # A fresh draw (cache bypassed) gives the same motors.
    again = protocol_motors(dataclasses.replace(full_protocol_v1(), variant="again"))
    assert [m.system for m in again] == [m.system for m in motors]
    # No v1 motor is a v0 protocol motor or a preset (agents train on presets).
    v0 = {m.system.motor for m in protocol_motors(full_protocol())}
    assert not v0 & {m.system.motor for m in motors}


def test_training_distribution_contains_interpolation_and_excludes_extrapolation():
    p = full_protocol_v1()
    for m in protocol_motors(p):
        preset = get_preset(m.nominal.name).replace(current_noise_a=p.current_noise_a,
                                                    encoder_cpr=p.encoder_cpr)
        inside = in_training_distribution(m.system, preset, p)
        assert inside == (m.split == "interpolation"), m.name
        assert holds_its_load(m.system, p.holding_margin), m.name
    # Each shift alone puts a motor outside: its own field leaves the training box.
    box = {n: (lo, hi) for n, lo, hi in p.training_randomization}
    shifts = {s.name: s for s in SHIFTS}
    for m in protocol_motors(p):
        if m.split != "extrapolation":
            continue
        preset = get_preset(m.nominal.name)
        for field_name, *_ in shifts[m.family].changes:
            value, base = m.system.to_dict()[field_name], preset.to_dict()[field_name]
            if field_name in box:
                lo, hi = box[field_name]
                assert not lo <= value / base <= hi, (m.name, field_name)
            else:
                assert value != base, (m.name, field_name)


def test_declared_shifts_reach_the_nominal_model_and_hidden_ones_do_not():
    motors = {m.name: m for m in protocol_motors(full_protocol_v1())}
    m = motors["patent~x-0.9-degree"]
    assert m.system.motor.Nr == m.nominal.motor.Nr == 100
    m = motors["patent~x-low-bus"]
    assert m.system.drive.Vdc == m.nominal.drive.Vdc == 24.0
    m = motors["patent~x-inertia"]
    assert m.system.motor.J >= 2.5 * get_preset("patent").motor.J
    assert m.nominal.motor.J == get_preset("patent").motor.J
    m = motors["patent~x-load-torque"]
    assert m.system.motor.load_torque > 0 and m.nominal.motor.load_torque == 0


def test_physics_rule_and_servo_grid():
    p = full_protocol_v1()
    weak = get_preset("patent").replace(load_torque=0.2)      # 0.57 N*m holding torque
    assert not holds_its_load(weak, p.holding_margin)
    for m in protocol_motors(p):
        speeds, labels = m.speeds("servo")
        f4 = m.system.predicted_resonances_rps()[4]
        assert np.allclose(speeds, np.array(p.servo_factors) * f4)
        assert all(lb != "off" for lb in labels)            # every servo speed is scored
        ol, ol_labels = m.speeds("open-loop")
        assert sorted(ol_labels) == sorted(["h4", "h2", "h1", "off", "off", "off", "off"])


# ---------------------------------------------------------------------------
# Settling
# ---------------------------------------------------------------------------
def test_settling_follows_the_decay_time_without_a_clip():
    p = full_protocol_v1()
    motors = {m.name: m for m in protocol_motors(p)}
    slow = motors["qsh5718-56-28-126~x-inertia"]
    m = slow.system.motor
    assert slow.settle_s("open-loop") == pytest.approx(4.0 * 2.0 * m.J / m.D)
    assert slow.settle_s("open-loop") > 0.6                 # v0 would clip it to 0.6 s
    assert p.settle_times(get_preset("patent"))["servo"] == pytest.approx(0.1)


@pytest.mark.parametrize("suite", ["open-loop", "servo"])
def test_the_window_opens_in_steady_state(suite):
    """Undamped, the slowest-settling motor's ripple in the window equals the steady
    state's: the mean of windows 1, 2 and 3 s later (the transient has died; no
    clip left it inside). One later window alone is no reference: in servo at the
    lowest speeds the encoder's counts beat, and 0.3 s windows a second apart
    differ by more than 6 % by themselves."""
    motors = {m.name: m for m in protocol_motors(full_protocol_v1())}
    m = motors["qsh5718-56-28-126~x-inertia"]
    speeds, labels = m.speeds(suite)
    for v in speeds[:3]:
        rms = []
        for extra in (0.0, 1.0, 2.0, 3.0):
            res = simulate(m.system, profile=SpeedProfile(speed_rps=v, accel_rps2=50.0),
                           settings=RunSettings(mode=suite, base_controller="none", window_s=0.3,
                                                settle_s=m.settle_s(suite) + extra))
            rms.append(res.metrics.rms_velocity_error_rad_s)
        assert rms[0] == pytest.approx(np.mean(rms[1:]), rel=0.06), (suite, v, rms)


# ---------------------------------------------------------------------------
# Statistics
# ---------------------------------------------------------------------------
def _fixed_data():
    rng = np.random.default_rng(20261122)
    x = rng.lognormal(-3.5, 0.6, size=(6, 5))              # motors x cells
    y = x * rng.lognormal(0.15, 0.2, size=(6, 5))
    return x, y, np.repeat(np.arange(6), 5), {m: m % 2 for m in range(6)}


def test_statistics_golden_values():
    x, y, motors, strata = _fixed_data()
    assert iqm(x.ravel()) == pytest.approx(0.03137428228779488, rel=1e-12)
    lo, hi = two_level_bootstrap(x.ravel(), motors, strata)
    assert (lo, hi) == pytest.approx((0.023159814933293433, 0.0414697117096736), rel=1e-12)
    poi = probability_of_improvement(x.ravel(), motors, y.ravel(), motors, strata=strata)
    assert poi["p"] == pytest.approx(0.6)
    assert poi["ci95"] == pytest.approx([0.43333333333333335, 0.76], rel=1e-12)
    alone = probability_of_improvement(x.ravel(), motors, y.ravel(), motors, strata=strata,
                                       interval=False)
    assert alone["p"] == poi["p"] and all(math.isnan(v) for v in alone["ci95"])


def test_an_entry_against_itself_is_a_coin_toss():
    x, _, motors, strata = _fixed_data()
    poi = probability_of_improvement(x.ravel(), motors, x.ravel(), motors, strata=strata)
    assert poi["p"] == 0.5
    # Against a copy below every cell of the original it is certain.
    poi = probability_of_improvement(1e-3 * x.ravel(), motors, x.ravel(), motors)
    assert poi["p"] == 1.0 and poi["ci95"] == [1.0, 1.0]


def test_two_level_bootstrap_widens_with_motor_variance():
    """Resampling motors as well as cells: an interval that sees motor-to-motor
    spread is wider than v0's, which resamples cells within fixed motors."""
    rng = np.random.default_rng(3)
    motor_level = rng.lognormal(-3.5, 0.5, size=12)
    x = (motor_level[:, None] * rng.lognormal(0.0, 0.03, size=(12, 5))).ravel()
    motors = np.repeat(np.arange(12), 5)
    lo1, hi1 = stratified_bootstrap_ci(x, motors)
    lo2, hi2 = two_level_bootstrap(x, motors)
    assert hi2 - lo2 > 5 * (hi1 - lo1)


@pytest.mark.slow
def test_statistics_agree_with_rliable():
    """rliable (test-only dependency) on fixed data: the IQM equals it, the
    probability of improvement equals it (scores negated: rliable's higher is
    better); v0's stratified interval, v1's two-level one (rliable's task
    bootstrap) and the probability of improvement's interval (motors fixed)
    match its percentile intervals to Monte Carlo accuracy."""
    rly = pytest.importorskip("rliable.library")
    metrics = pytest.importorskip("rliable.metrics")
    rng = np.random.default_rng(5)
    runs = rng.lognormal(-3.0, 0.5, size=(8, 12))           # rliable: runs x tasks
    other = rng.lognormal(-2.9, 0.5, size=(8, 12))
    tasks = np.repeat(np.arange(12)[None], 8, axis=0).ravel()
    assert iqm(runs.ravel()) == pytest.approx(metrics.aggregate_iqm(runs), rel=1e-12)
    ours = probability_of_improvement(runs.ravel(), tasks, other.ravel(), tasks)["p"]
    assert ours == pytest.approx(metrics.probability_of_improvement(-runs, -other), rel=1e-12)

    def agg(s):
        return np.array([metrics.aggregate_iqm(s)])

    np.random.seed(0)
    _, ci = rly.get_interval_estimates({"a": runs}, agg, reps=5000)
    lo, hi = stratified_bootstrap_ci(runs.ravel(), tasks, resamples=20000)
    width = ci["a"][1, 0] - ci["a"][0, 0]
    assert abs(lo - ci["a"][0, 0]) < 0.06 * width and abs(hi - ci["a"][1, 0]) < 0.06 * width
    # Two levels (tasks, then runs within them): rliable's task bootstrap.
    _, ci = rly.get_interval_estimates({"a": runs}, agg, reps=5000, task_bootstrap=True)
    lo, hi = two_level_bootstrap(runs.ravel(), tasks, resamples=20000)
    width = ci["a"][1, 0] - ci["a"][0, 0]
    assert abs(lo - ci["a"][0, 0]) < 0.06 * width and abs(hi - ci["a"][1, 0]) < 0.06 * width
    # The probability of improvement's interval with motors fixed (rliable has no
    # task bootstrap for it).
    _, ci = rly.get_interval_estimates({"xy": (-runs, -other)},
                                       metrics.probability_of_improvement, reps=3000)
    res = probability_of_improvement(runs.ravel(), tasks, other.ravel(), tasks,
                                     resamples=10000, resample_motors=False)
    width = ci["xy"][1, 0] - ci["xy"][0, 0]
    assert abs(res["ci95"][0] - ci["xy"][0, 0]) < 0.08 * width
    assert abs(res["ci95"][1] - ci["xy"][1, 0]) < 0.08 * width


# ---------------------------------------------------------------------------
# Protocol selection, --motors
# ---------------------------------------------------------------------------
def test_protocol_versions():
    assert protocol_for("v0") == full_protocol() and protocol_for("v0", True) == quick_protocol()
    assert protocol_for("v1") == full_protocol_v1()
    assert protocol_for("v1", True) == quick_protocol_v1()
    assert protocol_for("v2").version == "v2" and protocol_for("v2", True).variant == "quick"
    assert protocol_for("v3").version == "v3" and protocol_for("v4").version == "v4"
    assert protocol_for("v5").version == "v5"
    with pytest.raises(ParameterError, match="--protocol"):
        protocol_for("v6")
    json.dumps(full_protocol_v1().to_dict())


def test_motors_file(tmp_path):
    p = full_protocol_v1()
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(["patent", {"base": "qsh4218-51-10-049", "name": "mine",
                                           "J": 1e-5, "encoder_cpr": 1000}]))
    systems = load_motors_file(str(path), p)
    assert [s.name for s in systems] == ["patent", "mine"]
    assert systems[0].drive.current_noise_a == 0.01 and systems[0].servo.encoder_cpr == 4000
    assert systems[1].servo.encoder_cpr == 1000                 # the file's own sensor
    motors = protocol_motors(p.with_custom_motors(systems))
    assert [m.split for m in motors] == ["custom", "custom"]
    assert all(m.nominal == m.system for m in motors)
    for bad, match in (("[]", "non-empty"), ("{", "not valid JSON"),
                       ('[{"J": -1}]', "motor 0"), ('["patent", "patent"]', "unique")):
        path.write_text(bad)
        with pytest.raises(ParameterError, match=match):
            load_motors_file(str(path), p)


def _cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "stepdamp_env.cli", *args],
                          capture_output=True, text=True, cwd=cwd)


@pytest.mark.slow
def test_leaderboard_on_my_motors_writes_the_v1_fields(tmp_path):
    """``--motors``: every policy on the user's motors, split custom; the JSON has
    the fields stepdamp-bench v1 promises and the runs are in the side file."""
    motors = tmp_path / "motors.json"
    motors.write_text(json.dumps([{"base": "patent", "name": "my-nema23", "J": 6e-5},
                                  {"base": "qsh4218-51-10-049", "name": "my-nema17"}]))
    out = tmp_path / "board"
    r = _cli("leaderboard", "--protocol", "v1", "--quick", "--motors", str(motors),
             "--entries", "ff-delay-comp",
             "patent-ff-oracle", "ppo-gain-selector", "--suite", "open-loop", "--no-plots",
             "--no-progress",
             "--workers", "2", "--out", str(out))
    assert r.returncode == 0, r.stderr
    with open(out / "leaderboard.json", encoding="utf-8") as fh:
        board = json.load(fh)
    p = board["protocol"]
    assert p["name"] == "stepdamp-bench" and p["version"] == "v1" and p["splits"] == ["custom"]
    assert board["wall_seconds"] > 0 and board["simulated_seconds"] > 0
    entries = {e["name"]: e for e in board["entries"]}
    assert set(entries) == {"none", "ff-delay-comp", "patent-ff-oracle", "ppo-gain-selector"}
    # Nominal equals exact on a custom motor: the labels still tell them apart.
    assert entries["patent-ff-oracle"]["oracle"]
    assert entries["patent-ff-oracle"]["env_options"]["estimate"] == "exact"
    assert entries["ff-delay-comp"]["env_options"]["estimate"] == "identified"
    assert not entries["ff-delay-comp"]["oracle"]
    for e in entries.values():
        for key in ("name", "suite", "split", "learned", "oracle", "training_seeds",
                    "headline", "probability_of_improvement"):
            assert key in e, key
        assert e["split"] == "custom" and set(e["headline"]) >= {"iqm", "ci95"}
        assert set(e["probability_of_improvement"]) == set(entries) - {e["name"]}
        assert "runs" not in e
    ppo = entries["ppo-gain-selector"]
    assert ppo["learned"] and ppo["training_seeds"] == [1, 2, 3, 4, 5]
    ff = entries["ff-delay-comp"]
    assert not ff["learned"] and ff["training_seeds"] == []
    a, b = (entries["ppo-gain-selector"]["probability_of_improvement"]["ff-delay-comp"],
            entries["ff-delay-comp"]["probability_of_improvement"]["ppo-gain-selector"])
    assert a + b == pytest.approx(1.0)
    with open_runs_file(out / board["runs_file"]) as fh:
        raw = json.load(fh)
    ppo_runs = next(x for x in raw["entries"] if x["name"] == "ppo-gain-selector")["runs"]
    assert len(ppo_runs) == 2 * 3 * 5                       # motors x resonances x seeds
    assert {r["motor"] for r in ppo_runs} == {"my-nema23", "my-nema17"}
    assert "my-nema23" in r.stdout and "custom" in r.stdout


def test_motors_option_errors_are_one_line(tmp_path):
    r = _cli("leaderboard", "--motors", str(tmp_path / "none.json"), "--out",
             str(tmp_path / "o"))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "--motors" in r.stderr
    (tmp_path / "m.json").write_text('["patent"]')
    r = _cli("leaderboard", "--protocol", "v0", "--motors", str(tmp_path / "m.json"),
             "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "--protocol v1" in r.stderr


@pytest.mark.slow
def test_v1_leaderboard_with_its_figures_and_report(tmp_path, capsys):
    from stepdamp_env.cli import main

    out = tmp_path / "lb"
    assert main(["leaderboard", "--protocol", "v1", "--quick", "--entries", "ff-delay-comp",
                 "--out", str(out), "--no-progress", "--workers", "2"]) == 0
    board = json.loads((out / "leaderboard.json").read_text())
    assert board["protocol"]["version"] == "v1"
    keys = {(e["name"], e["suite"], e["split"]) for e in board["entries"]}
    assert keys == {(n, s, sp) for n in ("none", "ff-delay-comp")
                    for s in ("open-loop", "servo") for sp in ("interpolation",
                                                               "extrapolation")}
    for name in ("performance_profile.png", "overview.png", "ripple_vs_speed_servo.png",
                 "velocity_error_resonances_open-loop.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = (out / "LEADERBOARD.md").read_text()
    assert "## servo, extrapolation" in md and "P(better than none)" in md
    capsys.readouterr()
    assert main(["report", str(out)]) == 0
    table = capsys.readouterr().out
    assert "| open-loop, interpolation | open-loop, extrapolation |" in table
    assert main(["report", str(out), "--suite", "servo"]) == 0
    assert "servo, extrapolation" in capsys.readouterr().out


def test_a_reference_that_ends_before_its_window_still_scores_every_run():
    from stepdamp_env.bench.scoring import reference_index, score_runs

    def run(speed, label, rms, failed=False, metrics=True):
        return {"motor": "m", "seed": 1, "speed_rps": speed, "speed_label": label,
                "failed": failed,
                "metrics": {"rms_velocity_error_rad_s": rms, "rms_injected_current_a": 0.0}
                if metrics else None}

    ref = reference_index([run(1.0, "h4", 2.0), run(2.0, "h2", 4.0),
                           run(3.0, "h1", math.nan, failed=True, metrics=False)])
    mine = [run(1.0, "h4", 1.0), run(2.0, "h2", 1.0), run(3.0, "h1", 1.0)]
    (cell,) = score_runs(mine, ref, failed_reference_counts=True)
    assert cell["headline"] == pytest.approx(3.0 / (2.0 + 4.0 + 3.0))   # 3.0 stands in
    lost = [run(1.0, "h4", 1.0), run(2.0, "h2", 1.0), run(3.0, "h1", 0, True, False)]
    (cell,) = score_runs(lost, ref, failed_reference_counts=True)
    assert cell["headline"] == pytest.approx((1.0 + 1.0 + 30.0) / 9.0)
    (v0,) = score_runs(lost, ref)                     # v0 leaves the speed out
    assert v0["headline"] == pytest.approx(2.0 / 6.0)


def test_probabilities_of_a_pair_are_complements():
    from stepdamp_env.bench.scoring import add_probability_of_improvement

    rng = np.random.default_rng(0)
    entries = [{"name": n, "scores": [{"motor": f"m{k}", "headline": float(v)}
                                      for k in range(6) for v in rng.lognormal(0, 1, size=c)]}
               for n, c in (("a", 5), ("b", 1), ("c", 3))]
    add_probability_of_improvement(entries, quick_protocol_v1(), {f"m{k}": 0 for k in range(6)})
    by = {e["name"]: e for e in entries}
    for x in "abc":
        for y in "abc":
            if x != y:
                p, q = by[x]["probability_of_improvement"][y], by[y]["probability_of_improvement"][x]
                assert p + q == pytest.approx(1.0)
                lo, hi = by[x]["probability_of_improvement_ci95"][y]
                assert by[y]["probability_of_improvement_ci95"][x] == pytest.approx([1 - hi, 1 - lo])


def test_protocol_settings_are_checked():
    for bad in ({"servo_factors": ()}, {"extrapolation_pairs": ((9, "inertia"),)},
                {"extrapolation_pairs": ((0, "heavy"),)}, {"interpolation_per_preset": -1},
                {"confidence": 1.0}, {"holding_margin": 0.0}, {"motor_seed": 5}):
        with pytest.raises(ParameterError):
            dataclasses.replace(full_protocol_v1(), **bad)
