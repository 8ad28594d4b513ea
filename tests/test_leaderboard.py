"""The stepdamp-bench v0 protocol, its statistics and the ``leaderboard`` command."""

from __future__ import annotations

import dataclasses
import json
import math
import os

import numpy as np
import pytest

from stepdamp_baselines import BASELINE_NAMES
from stepdamp_env.bench import (TRAINING_SEED_LIMIT, Protocol, ProtocolV0, full_protocol, iqm,
                                protocol_motors, quick_protocol, run_leaderboard,
                                stratified_bootstrap_ci)
from stepdamp_env.bench.report import load_leaderboard
from stepdamp_env.cli import main
from stepdamp_env.params import ParameterError

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# A policy given by file path: found from any working directory.
TEST_POLICY = os.path.join(ROOT, "tests", "leaderboard_policy.py") + ":NominalFeedforward"


def tiny_protocol() -> Protocol:
    """The quick variant on the patent preset only (a test subset, not v0 numbers)."""
    return dataclasses.replace(quick_protocol(), presets=("patent",))


def numbers(board):
    """Everything but the environment-specific parts."""
    return json.dumps({"protocol": board["protocol"], "entries": board["entries"],
                       "identification": board["identification"]}, sort_keys=True)


# -- statistics ----------------------------------------------------------------------
def test_iqm_hand_computed():
    assert iqm(range(1, 9)) == pytest.approx(4.5)                 # mean of 3, 4, 5, 6
    assert iqm([5, 1, 4, 2, 3]) == pytest.approx(3.0)             # (.15*2 + .2*3 + .15*4)/.5
    assert iqm([1.0, 2.0, 3.0, 100.0]) == pytest.approx(2.5)      # middle two
    assert iqm([7.0]) == 7.0
    assert math.isnan(iqm([]))


def test_bootstrap_interval_contains_iqm_and_narrows_with_data():
    rng = np.random.default_rng(0)
    small = rng.normal(1.0, 0.3, size=(4, 5))
    large = rng.normal(1.0, 0.3, size=(4, 80))
    widths = []
    for x in (small, large):
        values = x.ravel()
        strata = np.repeat(np.arange(4), x.shape[1])
        lo, hi = stratified_bootstrap_ci(values, strata, resamples=2000, seed=2000)
        assert lo <= iqm(values) <= hi
        widths.append(hi - lo)
    assert widths[1] < 0.5 * widths[0]
    # Fixed seed: the same interval every time.
    v = small.ravel()
    s = np.repeat(np.arange(4), 5)
    assert stratified_bootstrap_ci(v, s) == stratified_bootstrap_ci(v, s)


def test_stratified_bootstrap_keeps_per_stratum_counts():
    # Stratum a holds 3 zeros, b 5 ones: every stratified resample has exactly that
    # mix, so its IQM never moves; an unstratified bootstrap would spread.
    values = [0.0] * 3 + [1.0] * 5
    strata = ["a"] * 3 + ["b"] * 5
    lo, hi = stratified_bootstrap_ci(values, strata)
    assert lo == hi == pytest.approx(iqm(values))
    with pytest.raises(ValueError, match="strata"):
        stratified_bootstrap_ci(values, strata[:-1])


# -- protocol ---------------------------------------------------------------------------
def test_protocol_motors_seeds_and_speed_grid():
    p = full_protocol()
    assert all(s >= TRAINING_SEED_LIMIT for s in p.eval_seeds)
    motors = protocol_motors(p)
    assert len(motors) == len(p.presets) * (1 + p.randomized_per_preset)
    assert motors == protocol_motors(dataclasses.replace(p))       # deterministic
    names = [m.name for m in motors]
    assert len(set(names)) == len(names)
    for m in motors:
        assert m.system.drive.current_noise_a == 0.01 and m.system.servo.encoder_cpr == 4000
        assert m.nominal.name in p.presets
        res = m.system.predicted_resonances_rps()
        for h in (4, 2, 1):
            assert res[h] in m.speeds_rps
        assert m.speed_labels.count("off") == 4
        assert min(m.speeds_rps) >= 0.6 * res[4] * (1 - 1e-12)
        assert max(m.speeds_rps) <= 1.3 * res[1] * (1 + 1e-12)
    drawn = [m for m in motors if m.name not in p.presets]
    assert all(m.system.motor != m.nominal.motor for m in drawn)
    with pytest.raises(ParameterError, match="eval_seeds"):
        ProtocolV0(eval_seeds=(5,))
    with pytest.raises(ParameterError, match="suites"):
        ProtocolV0(suites=("closed-loop",))


# -- runs -------------------------------------------------------------------------------
# Every baseline (the stateful adaptive ones too) and the module policy.
TINY_POLICIES = [*BASELINE_NAMES, TEST_POLICY]


@pytest.fixture(scope="module")
def tiny_board():
    return run_leaderboard(tiny_protocol(), TINY_POLICIES, workers=2, progress=False)


@pytest.mark.slow
def test_deterministic_and_independent_of_workers(tiny_board):
    again = run_leaderboard(tiny_protocol(), TINY_POLICIES, workers=2, progress=False)
    serial = run_leaderboard(tiny_protocol(), TINY_POLICIES, workers=1, progress=False)
    assert numbers(again) == numbers(tiny_board)
    assert numbers(serial) == numbers(tiny_board)


def test_the_outputs_of_a_board_without_its_fingerprint_carry_it(tiny_board, tmp_path):
    # The CLI leaves the fingerprint to write_outputs (computed while the runs
    # file compresses): the files are those of the board with it, byte for byte.
    from stepdamp_env.bench.report import write_outputs

    bare = {k: v for k, v in tiny_board.items() if k != "fingerprint"}
    write_outputs(dict(tiny_board), str(tmp_path / "with"), tiny_protocol(), plots=False)
    write_outputs(bare, str(tmp_path / "without"), tiny_protocol(), plots=False)
    assert bare["fingerprint"] == tiny_board["fingerprint"]
    names = sorted(os.listdir(tmp_path / "with"))
    assert names == sorted(os.listdir(tmp_path / "without")) and "leaderboard.json" in names
    for name in names:
        assert ((tmp_path / "with" / name).read_bytes()
                == (tmp_path / "without" / name).read_bytes()), name
    assert load_leaderboard(str(tmp_path / "without"))["fingerprint"] == tiny_board["fingerprint"]


def test_none_is_one_and_the_oracle_far_below(tiny_board):
    for suite in ("open-loop", "servo"):
        e = {x["name"]: x for x in tiny_board["entries"] if x["suite"] == suite}
        assert e["none"]["headline"]["iqm"] == pytest.approx(1.0, abs=1e-12)
        assert e["patent-ff-oracle"]["headline"]["iqm"] < 0.3
        assert e["patent-ff-oracle"]["rank"] < e["none"]["rank"]
        assert e["patent-ff-oracle"]["oracle"] and not e["none"]["oracle"]
        lo, hi = e["patent-ff-oracle"]["headline"]["ci95"]
        assert lo <= e["patent-ff-oracle"]["headline"]["iqm"] <= hi
        assert e["none"]["step_losses"]["runs_lost"] == 0
        for run in e["none"]["runs"]:
            assert set(run["metrics"]) >= {"rms_velocity_error_rad_s", "step_loss",
                                           "rms_injected_current_a"}


def test_module_policy_runs(tiny_board):
    # Nominal == exact for a preset, and a zero harmonic residual is the base
    # controller bit for bit: the module policy must tie with the oracle.
    for suite in ("open-loop", "servo"):
        e = {x["name"]: x for x in tiny_board["entries"] if x["suite"] == suite}
        ours = e["test-nominal-ff"]
        assert ours["spec"] == TEST_POLICY
        assert ours["env_options"]["action_mode"] == "harmonic"
        assert [r["metrics"] for r in ours["runs"]] == \
            [r["metrics"] for r in e["patent-ff-oracle"]["runs"]]


def test_policy_may_not_set_protocol_options(monkeypatch):
    monkeypatch.syspath_prepend(ROOT)           # a package.module:attr spec
    with pytest.raises(ValueError, match="privileged"):
        run_leaderboard(tiny_protocol(), ["none", "tests.leaderboard_policy:Privileged"],
                        workers=1, progress=False)
    with pytest.raises(ValueError, match="is not a registered policy"):
        run_leaderboard(tiny_protocol(), ["no-such-policy"], workers=1, progress=False)


def test_identified_baseline_runs():
    board = run_leaderboard(tiny_protocol().with_suites(["open-loop"]),
                            ["none", "patent-ff-identified"], workers=1, progress=False)
    e = {x["name"]: x for x in board["entries"]}
    assert 0.0 < e["patent-ff-identified"]["headline"]["iqm"] < 0.5
    assert board["identification"][0]["model"]["Kd4"] > 0


@pytest.mark.slow
def test_cli_writes_leaderboard(tmp_path, capsys):
    out = tmp_path / "lb"
    rc = main(["leaderboard", "--protocol", "v0", "--quick", "--suite", "open-loop",
               "--entries", "none", "patent-ff-oracle", "--policy", TEST_POLICY,
               "--out", str(out), "--no-progress"])
    assert rc == 0
    board = json.loads((out / "leaderboard.json").read_text())
    assert set(board) >= {"protocol", "versions", "entries"}
    assert board["protocol"]["name"] == "stepdamp-bench"
    assert board["protocol"]["version"] == "v0"
    for key in ("eval_seeds", "window_s", "accel_rps2", "current_noise_a", "encoder_cpr",
                "motors", "bootstrap_resamples", "bootstrap_seed"):
        assert key in board["protocol"]
    assert set(board["versions"]) >= {"package", "numpy", "numba", "gymnasium",
                                      "stable-baselines3", "torch", "python"}
    assert {e["name"] for e in board["entries"]} == {"none", "patent-ff-oracle",
                                                     "test-nominal-ff"}
    for e in board["entries"]:
        assert e["suite"] == "open-loop"
        assert len(e["headline"]["ci95"]) == 2 and math.isfinite(e["headline"]["iqm"])
        for key in ("sweep_mean_ratio", "sweep_worst_ratio", "step_losses",
                    "rms_injected_current_a"):
            assert key in e
        assert "runs" not in e and "scores" not in e        # in the compressed runs file
    assert board["runs_file"] == "leaderboard_runs.json.xz"
    full = load_leaderboard(out)
    for e in full["entries"]:
        assert len(e["runs"]) == 4 * 3                      # presets x resonant speeds
        assert len(e["scores"]) == 4
    md = (out / "LEADERBOARD.md").read_text()
    assert "## open-loop" in md and "| 1 |" in md and "patent-ff-oracle" in md
    for name in ("overview.png", "ripple_vs_speed_open-loop.png",
                 "velocity_error_resonances_open-loop.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "headline IQM" in capsys.readouterr().out
    assert main(["report", str(out), "--suite", "open-loop"]) == 0
    table = capsys.readouterr().out
    assert "| 1 | patent-ff-oracle (oracle) | 0.07956 (no interval) | 0/12 |" in table
    assert main(["report", str(out)]) == 0
    assert "| patent-ff-oracle (oracle) | 0.07956 (no interval) |" in capsys.readouterr().out

    # A second run replaces the results as a set and keeps a file it did not write.
    (out / "notes.txt").write_text("mine")
    rc = main(["leaderboard", "--quick", "--suite", "open-loop", "--entries", "none",
               "--out", str(out), "--no-progress", "--no-plots"])
    assert rc == 0
    assert sorted(os.listdir(out)) == ["LEADERBOARD.md", "LEADERBOARD_open-loop.md",
                                       "leaderboard.json", "leaderboard_runs.json.xz",
                                       "notes.txt"]
    assert (out / "notes.txt").read_text() == "mine"
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".")]


def test_sb3_model_file_policy(tmp_path):
    from stable_baselines3 import PPO

    from stepdamp_env.env import StepperDampEnv

    env = StepperDampEnv(speed_rps=0.7, action_mode="harmonic")
    model = PPO("MlpPolicy", env, n_steps=32, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(32)
    path = tmp_path / "tiny-ppo.zip"
    model.save(path)
    board = run_leaderboard(tiny_protocol().with_suites(["open-loop"]), ["none", str(path)],
                            workers=1, progress=False)
    e = {x["name"]: x for x in board["entries"]}
    assert e["tiny-ppo"]["env_options"]["estimate"] == "identified"
    assert math.isfinite(e["tiny-ppo"]["headline"]["iqm"])


def test_summaries_show_four_digits_and_no_interval_they_do_not_have():
    from stepdamp_env.bench.report import format_summary

    assert format_summary({"iqm": 0.0178123, "ci95": [0.0175, 0.01804]}) == \
        "0.01781 [0.01750, 0.01804]"
    # --quick: one run per motor, the stratified interval has no width.
    assert format_summary({"iqm": 0.25, "ci95": [0.25, 0.25]}) == "0.2500 (no interval)"


def test_policy_styles_are_distinct_on_a_full_board():
    # Every registered entry (and a few more learned ones) gets its own colour,
    # so no two lines of a performance profile look alike.
    from stepdamp_env.bench.registry import default_policy_names
    from stepdamp_env.bench.report import policy_styles

    names = list(dict.fromkeys([*default_policy_names(), "sac-per-step", "my-agent@best"]))
    styles = policy_styles(names)
    colours = [styles[n][0] for n in names]
    assert len(set(colours)) == len(names)


def test_warm_up_marks_this_code_version_compiled(tmp_path, monkeypatch, capsys):
    """The leaderboard's warm-up leaves a marker in this code version's numba
    cache; without it (a cold cache) it says it is compiling, on stderr."""
    from stepdamp_env.bench.leaderboard import warm_up
    from stepdamp_env.bench.warmup import compiled_marker
    from stepdamp_env.motorfile import load_system

    marker = compiled_marker()
    assert marker is not None and os.path.dirname(marker) == __import__(
        "stepdamp_env.numba_cache").numba_cache.user_cache_dir()
    if os.path.exists(marker):
        os.remove(marker)
    assert warm_up(load_system("patent"), workers=1, progress=True) >= 0.0
    assert "compiling the simulation kernels" in capsys.readouterr().err
    assert os.path.exists(marker)
    warm_up(load_system("patent"), workers=1, progress=True)
    assert capsys.readouterr().err == ""


def test_the_compiled_marker_is_this_cpus():
    """numba's cache compiles anew for another CPU: the marker (and so the
    compiling notice) is per target machine too."""
    import subprocess
    import sys

    from stepdamp_env.bench.warmup import compiled_marker, machine_tag

    code = "from stepdamp_env.bench.warmup import compiled_marker; print(compiled_marker())"
    other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           check=True, env={**os.environ, "NUMBA_CPU_NAME": "nehalem",
                                            "NUMBA_CPU_FEATURES": ""}).stdout.strip()
    here = compiled_marker()
    assert here.endswith("-" + machine_tag()) and len(machine_tag()) == 12
    assert os.path.dirname(other) == os.path.dirname(here) and other != here


def test_warm_lanes_compiles_the_lanes_only_where_batches_step_in_them(monkeypatch, capsys):
    """The board's SIMD lanes are compiled by the warm-up (their own marker) where
    batches step in them by default; on a CPU without AVX2 nothing happens."""
    from stepdamp_env import lanes
    from stepdamp_env.bench.warmup import compiled_marker, warm_lanes

    marker = compiled_marker("lanes")
    assert marker is not None and marker != compiled_marker()
    monkeypatch.setattr(lanes, "simd_by_default", lambda n: False)
    if os.path.exists(marker):
        os.remove(marker)
    assert warm_lanes(workers=1, progress=True) == 0.0
    assert capsys.readouterr().err == "" and not os.path.exists(marker)
    assert warm_lanes(workers=1, progress=True, always=True) > 0.0
    assert "compiling the SIMD lanes" in capsys.readouterr().err
    assert os.path.exists(marker)
    warm_lanes(workers=1, progress=True, always=True)
    assert capsys.readouterr().err == ""
