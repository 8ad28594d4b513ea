"""The ``stepdamp`` command line and its result files."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from stepdamp_env import io as sio
from stepdamp_env.cli import main
from stepdamp_env.params import ParameterError
from stepdamp_env.presets import get_preset
from stepdamp_env.simulation import RunSettings
from stepdamp_env.sweep import parse_speed_range, run_sweep


def test_sweep_writes_json_and_figures(tmp_path, capsys):
    out = tmp_path / "sw"
    rc = main(["sweep", "--motor", "patent", "--speeds", "0.6:0.74:0.02", "--out", str(out),
               "--no-progress", "--set", "Fs=0.003"])
    assert rc == 0
    data = json.loads((out / "sweep.json").read_text())
    for key in ("speeds_rps", "rms_velocity_error_rad_s", "p2p_velocity_error_rad_s",
                "step_loss", "predicted_resonances_rps", "parameters", "version"):
        assert key in data
    assert len(data["speeds_rps"]) == len(data["rms_velocity_error_rad_s"]) == 8
    assert data["parameters"]["Fs"] == 0.003
    assert data["predicted_resonances_rps"]["4"] == pytest.approx(
        get_preset("patent").predicted_resonances_rps()[4])
    for name in ("sweep.png", "velocity_error_traces.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "h=4: predicted" in capsys.readouterr().out


def test_simulate_prints_metrics_and_writes_a_trace(tmp_path, capsys):
    trace = tmp_path / "run.npz"
    rc = main(["simulate", "--motor", "qsh5718-56-28-126", "--mode", "servo", "--base-controller",
               "patent-ff", "--speed", "0.5", "--duration", "0.8", "--trace", str(trace),
               "--json"])
    assert rc == 0
    metrics = json.loads(capsys.readouterr().out)
    assert metrics["mode"] == "servo" and metrics["rms_velocity_error_rad_s"] > 0
    data = np.load(trace)
    for key in ("t", "theta", "omega", "theta_cmd", "ia", "ib", "va", "vb"):
        assert data[key].shape == (16000,)
    assert np.allclose(np.diff(data["t"]), 1 / 20000)


def test_simulate_move_ends_at_its_target(capsys):
    rc = main(["simulate", "--speed", "2", "--move", "1.5", "--duration", "1.5", "--json"])
    assert rc == 0
    metrics = json.loads(capsys.readouterr().out)
    assert not metrics["step_loss"]


def test_cli_reports_bad_input_cleanly(capsys):
    assert main(["simulate", "--motor", "nope", "--speed", "1"]) == 2
    assert "unknown motor preset 'nope'" in capsys.readouterr().err
    assert main(["sweep", "--speeds", "1:0:0.1", "--out", "x"]) == 2
    assert main(["simulate", "--set", "L=-1", "--speed", "1"]) == 2
    assert "L=-1.0 is outside its allowed range" in capsys.readouterr().err


def test_speed_range_parsing():
    assert parse_speed_range("0.2:0.3:0.05").tolist() == [0.2, 0.25, 0.3]
    with pytest.raises(ValueError, match="START:STOP:STEP"):
        parse_speed_range("1:2")


def test_sweep_is_identical_across_worker_counts():
    system = get_preset("patent")
    speeds = np.linspace(0.5, 0.8, 8)
    one = run_sweep(system, speeds, RunSettings(), workers=1, progress=False)
    two = run_sweep(system, speeds, RunSettings(), workers=2, progress=False)
    assert one.metrics == two.metrics


def test_atomic_write_leaves_the_old_file_on_failure(tmp_path, monkeypatch):
    path = tmp_path / "result.json"
    sio.write_json(path, {"a": 1})

    def boom(*args, **kwargs):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(sio.json, "dump", boom)
    with pytest.raises(RuntimeError):
        sio.write_json(path, {"a": 2})
    assert json.loads(path.read_text()) == {"a": 1}
    assert os.listdir(tmp_path) == ["result.json"]


def test_result_files_get_the_usual_mode(tmp_path):
    path = tmp_path / "r.json"
    sio.write_json(path, {"a": 1})
    mask = os.umask(0)
    os.umask(mask)
    assert (path.stat().st_mode & 0o777) == (0o666 & ~mask)


@pytest.mark.parametrize("argv", [
    ["leaderboard", "--quick", "--out", "/proc/no-such-dir/x"],
    ["sweep", "--speeds", "0.5:0.6:0.1", "--out", "/proc/no-such-dir/x"],
    ["identify", "--out", "/proc/no-such-dir/x"],
    ["simulate", "--speed", "0.5", "--trace", "/proc/no-such-dir/t.npz"],
])
def test_unwritable_output_is_refused_before_any_work(argv, capsys):
    """An unwritable --out was once found only after the whole computation."""
    import time

    t0 = time.perf_counter()
    assert main(argv) == 2
    assert time.perf_counter() - t0 < 5.0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not writable" in err[0] and ("--out" in err[0] or "--trace" in err[0])


# -- one flag, one meaning (docs/cli.md's glossary) ---------------------------------------
def _audit():
    import importlib.util

    path = os.path.join(os.path.dirname(os.path.dirname(__file__)), "scripts", "audit_cli.py")
    spec = importlib.util.spec_from_file_location("audit_cli", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_flag_has_one_meaning_in_the_glossary():
    assert _audit().glossary_problems() == []


def test_the_glossary_check_finds_a_missing_flag_and_a_shared_meaning(tmp_path):
    audit = _audit()
    doc = os.path.join(os.path.dirname(os.path.dirname(__file__)), "docs", "cli.md")
    text = open(doc, encoding="utf-8").read()
    edited = tmp_path / "cli.md"
    edited.write_text(text.replace("| `--workers` | worker processes | sweep, leaderboard, "
                                   "recommend |\n", "")
                      .replace("| `--full` | the whole LEADERBOARD.md table |",
                               "| `--full` | no progress bars |")
                      .replace("| sweep | `--damping` | `--entries` |",
                               "| sweep | `--damping` | `--policy` |"))
    problems = audit.glossary_problems(str(edited))
    assert "--workers: not in the glossary (leaderboard, recommend, sweep)" in problems
    assert "meaning 'no progress bars': given to two flags" in problems
    assert any(p.startswith("sweep --damping: exit 2") for p in problems)


@pytest.mark.parametrize("argv, new", [
    (["identify", "--seed", "3", "--out", "x"], "--noise-seed"),
    (["sweep", "--damping", "none", "--out", "x"], "--entries"),
    (["train", "--set", "learning_rate=1"], "--hyperparam"),
    (["train", "--motors", "patent"], "--presets")])
def test_a_renamed_flag_is_refused_with_one_line_naming_the_new_one(argv, new, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0] == (f"stepdamp {argv[0]}: error: {argv[1]} was renamed "
                                        f"to {new} in 0.18.0")


def test_the_default_sweep_holds_every_resonance_below_the_top_speed():
    """A motor's default --speeds hold its three resonances (where its bus reaches
    them): the old fixed 0.2..3.5 rev/s missed the h=1 resonance of larger motors."""
    from stepdamp_env.analysis import bridge_limit_rps
    from stepdamp_env.bench.protocols.v4 import catalogue_systems, quick_protocol_v4
    from stepdamp_env.presets import get_preset, preset_names
    from stepdamp_env.sweep import default_speed_range, parse_speed_range

    systems = [get_preset(n) for n in preset_names()] + list(
        catalogue_systems(quick_protocol_v4()))
    weak = get_preset("patent").replace(Vdc=4.0)     # a bus below its resonances
    for system in systems + [weak]:
        v = parse_speed_range(default_speed_range(system))
        top = bridge_limit_rps(system)
        assert 100 <= len(v) <= 200, system.name
        highest = 1.25 * max(system.predicted_resonances_rps().values())
        assert v[-1] <= 1.005 * min(top, highest), system.name
        for h, speed in system.predicted_resonances_rps().items():
            if speed < top:
                assert v[0] < speed < v[-1], (system.name, h, speed, v[0], v[-1])
    with pytest.raises(ParameterError, match="Vdc=3 V.*give --speeds"):
        default_speed_range(get_preset("patent").replace(Vdc=3.0))
