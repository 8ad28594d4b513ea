"""Bounded work from accepted input (issue "Reliability v2", items 4 and 8).

Name lengths, list sizes, the simulated time of one run, the trace's memory
(estimated before allocating), signals honoured within a second in the
simulation loop, the env's acceleration minimum, and an out-of-space error that
names its file. The chunked simulation loop gives the same bits as one call.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
import tracemalloc

import numpy as np
import pytest

import stepdamp_env.simulation as S
from stepdamp_env.bench.protocols import drawn
from stepdamp_env import io as sio
from stepdamp_env import kernel as K
from stepdamp_env.bench.protocols.v1 import (full_protocol_v1,
                                             load_motors_file)
from stepdamp_env.cli import main
from stepdamp_env.env import EnvOptions, EnvOptionsV1
from stepdamp_env.limits import LIMITS
from stepdamp_env.params import ParameterError, SystemParams
from stepdamp_env.presets import get_preset
from stepdamp_env.simulation import (MAX_DURATION_S, MIN_ACCEL_RPS2, RunSettings, SpeedProfile,
                                     build_config, initial_state, new_accumulators,
                                     run_periods_chunked, simulate)

PATENT = get_preset("patent")


def _one_line_error(capsys, command: str) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"stepdamp {command}: error:") and "\n" not in err, err
    return err


def _cli(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "stepdamp_env.cli", *args],
                          capture_output=True, text=True, timeout=300, **kw)


# ---------------------------------------------------------------------------
# The chunked loop: the same bits as one kernel call
# ---------------------------------------------------------------------------
CASES = {
    "open-loop": (PATENT, SpeedProfile(1.3), RunSettings(base_controller="patent-ff")),
    "servo": (PATENT.replace(current_noise_a=0.01),
              SpeedProfile(0.4, kind="move", distance_rev=0.3, accel_rps2=20.0),
              RunSettings(mode="servo", base_controller="patent-ff", noise_seed=7,
                          velocity_estimator="kalman", substeps=2)),
    "voltage-mode": (PATENT.replace(drive_mode="voltage"), SpeedProfile(2.1),
                     RunSettings(base_controller="patent-ff")),
}


def _fingerprint(result) -> dict:
    out = {"metrics": json.dumps(result.metrics.to_dict(), sort_keys=True),
           "state": result.final_state.tobytes(), "acc": result.accumulators.tobytes(),
           "duration_s": result.duration_s}
    for name, values in (result.trace or {}).items():
        out[f"trace {name}"] = values.tobytes()
    return out


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("trace_every", [1, 7])
def test_chunked_simulate_is_bit_identical_to_one_call(case, trace_every, monkeypatch):
    system, profile, settings = CASES[case]
    monkeypatch.setattr(S, "CHUNK_PLANT_STEPS", 1 << 60)             # one call
    whole = simulate(system, profile=profile, settings=settings, trace=True,
                     trace_every=trace_every)
    # 997 plant steps a call: chunks of 997 or 498 periods (substeps 2), which
    # trace_every = 7 does not divide; rows must line up across the chunks.
    monkeypatch.setattr(S, "CHUNK_PLANT_STEPS", 997)
    calls = []
    run_periods = K.run_periods

    def counted(*args):
        calls.append(args[4])
        return run_periods(*args)

    monkeypatch.setattr(K, "run_periods", counted)
    chunked = simulate(system, profile=profile, settings=settings, trace=True,
                       trace_every=trace_every)
    monkeypatch.setattr(K, "run_periods", run_periods)
    n = round(whole.duration_s * system.drive.pwm_hz)
    assert sum(calls) == n and len(calls) > 15 and max(calls) == 997 // settings.substeps
    assert len(whole.trace["t"]) == -(-n // trace_every)
    assert _fingerprint(chunked) == _fingerprint(whole)
    # And without a trace (the default path).
    plain = simulate(system, profile=profile, settings=settings)
    assert plain.final_state.tobytes() == whole.final_state.tobytes()
    assert plain.accumulators.tobytes() == whole.accumulators.tobytes()


@pytest.mark.parametrize("trace_every,chunk", [(1, 1), (3, 1), (5000, 997), (997, 997),
                                               (64, 1000), (1, 1 << 18)])
def test_run_periods_chunked_against_one_kernel_call(trace_every, chunk, monkeypatch):
    """Straight against ``kernel.run_periods``, trace rows at p // trace_every."""
    system, profile, settings = CASES["open-loop"]
    n = 3001 if chunk == 1 else 23_456
    runs = []
    for chunked in (False, True):
        c = build_config(system, profile, settings, window_start_s=0.01)
        s, acc = initial_state(c), new_accumulators()
        trace = np.zeros((-(-n // trace_every), len(K.TRACE)))
        u = np.zeros(len(K.INPUT))
        if chunked:
            monkeypatch.setattr(S, "CHUNK_PLANT_STEPS", chunk)
            rows = run_periods_chunked(c, s, acc, u, n, trace, trace_every)
        else:
            rows = K.run_periods(c, s, acc, u, n, trace, trace_every)
        runs.append((rows, s.tobytes(), acc.tobytes(), trace.tobytes()))
    assert runs[0][0] == -(-n // trace_every)
    assert runs[1] == runs[0]


# ---------------------------------------------------------------------------
# Simulated time of one run
# ---------------------------------------------------------------------------
def test_cli_huge_move_exits_2_quickly():
    t0 = time.perf_counter()
    done = _cli("simulate", "--speed", "1", "--move", "1e6")
    assert time.perf_counter() - t0 < 30          # an interpreter start, no simulation
    assert done.returncode == 2, done.stderr
    err = done.stderr.strip()
    assert "\n" not in err and "--move" in err and "allowed" in err, err
    assert "|--move| <= 9999" in err, err


def test_api_huge_move_names_distance_rev():
    t0 = time.perf_counter()
    with pytest.raises(ParameterError, match=r"distance_rev=1e\+06 .*allowed "
                                             r"\|distance_rev\| <= 999") as info:
        simulate(PATENT, profile=SpeedProfile(1.0, kind="move", distance_rev=1e6))
    assert "\n" not in str(info.value)
    assert time.perf_counter() - t0 < 1.0
    # The limit itself runs (only checked, not simulated here: 2e8 periods).
    from stepdamp_env.simulation import max_move_distance_rev
    d = max_move_distance_rev(1.0, 50.0, MAX_DURATION_S - 0.32)
    assert SpeedProfile(1.0, kind="move", distance_rev=d).duration_s() <= MAX_DURATION_S


def test_api_duration_and_ramp_capped():
    with pytest.raises(ParameterError, match=r"duration_s=20000 s .*allowed range "
                                             r"\(0\.\d+, 10000\] s"):
        simulate(PATENT, speed_rps=1.0, duration_s=2e4)
    # A ramp that alone outlasts the cap (the API has no acceleration minimum).
    with pytest.raises(ParameterError, match=r"accel_rps2=1e-06 takes 1e\+06 s.*allowed "
                                             r"accel_rps2 >= 0\.0001"):
        simulate(PATENT, profile=SpeedProfile(1.0, accel_rps2=1e-6))
    # The window opens in time but ends past the cap: a shorter duration_s is a way out.
    with pytest.raises(ParameterError, match=r"accel_rps2 >= 0\.000100008 rev/s\^2 or a "
                                             r"duration_s in \(9999\.82, 10000\] s$"):
        simulate(PATENT, profile=SpeedProfile(1.0, accel_rps2=1 / 9999.5))


def test_cli_slow_ramp_names_accel(capsys):
    assert main(["simulate", "--speed", "1000", "--accel", "1e-3"]) == 2
    err = _one_line_error(capsys, "simulate")
    assert "--accel >= 0.1" in err, err


# ---------------------------------------------------------------------------
# Trace memory, estimated before allocating
# ---------------------------------------------------------------------------
def test_api_trace_memory_refused_before_allocating():
    tracemalloc.start()
    try:
        with pytest.raises(ParameterError) as info:
            simulate(PATENT, speed_rps=1.0, duration_s=MAX_DURATION_S, trace=True)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("trace:"), msg
    assert "GiB" in msg and "duration_s" in msg and "trace_every" in msg, msg
    assert peak < 64 * 2 ** 20, peak
    # The advice holds: raising trace_every as told fits.
    every = int(msg.rsplit("at least ", 1)[1].rstrip(")"))
    S.check_trace_memory(round(MAX_DURATION_S * 20_000), every, 20_000.0)


@pytest.mark.parametrize("ext", ["csv", "npz"])
def test_cli_trace_memory_refused_before_allocating(ext, tmp_path, capsys):
    out = tmp_path / f"trace.{ext}"
    t0 = time.perf_counter()
    assert main(["simulate", "--speed", "1", "--duration", "1e4", "--trace", str(out)]) == 2
    assert time.perf_counter() - t0 < 5.0
    err = _one_line_error(capsys, "simulate")
    assert "--trace" in err and "--duration" in err and "GiB" in err, err
    assert not out.exists() and os.listdir(tmp_path) == []


# ---------------------------------------------------------------------------
# Names and lists
# ---------------------------------------------------------------------------
def test_motor_name_bound():
    assert PATENT.replace(name="n" * LIMITS.name_chars).name == "n" * LIMITS.name_chars
    for bad in ("n" * (LIMITS.name_chars + 1), "", "two\nlines", "tab\there"):
        with pytest.raises(ParameterError, match=r"^name=.*allowed range: 1 to 200 "
                                                 r"printable") as info:
            PATENT.replace(name=bad)
        assert "\n" not in str(info.value) and len(str(info.value)) < 250
    with pytest.raises(ParameterError, match="name must be text"):
        SystemParams(PATENT.motor, name=5)


def test_cli_huge_name_exits_2_one_line(tmp_path, capsys):
    path = tmp_path / "motor.json"
    path.write_text(json.dumps({"name": "x" * 20_000_000}))
    t0 = time.perf_counter()
    assert main(["simulate", "--motor", str(path), "--speed", "1"]) == 2
    assert time.perf_counter() - t0 < 10.0
    err = _one_line_error(capsys, "simulate")
    assert "name=" in err and "20000000 characters" in err and "1 to 200" in err, err
    assert len(err) < 300


def test_motors_file_duplicates_found_before_validation(tmp_path, monkeypatch):
    path = tmp_path / "motors.json"
    motor = {"name": "same", "base": "patent", "J": 2e-5}
    data = [motor] * 300_000
    path.write_text(json.dumps(data))
    protocol = full_protocol_v1()
    t0 = time.perf_counter()
    with pytest.raises(ParameterError, match=r"--motors .*must be unique, repeated: "
                                             r"\['same'\]$") as info:
        load_motors_file(str(path), protocol)
    # Reading and parsing the 13 MB file is most of it (about a second here).
    assert time.perf_counter() - t0 < 5.0
    assert "\n" not in str(info.value)
    # Without the reading: the names' check alone (was a minute of validation).
    monkeypatch.setattr(drawn, "read_json_file", lambda *a: data)
    t0 = time.perf_counter()
    with pytest.raises(ParameterError, match="must be unique"):
        load_motors_file(str(path), protocol)
    assert time.perf_counter() - t0 < 0.5
    monkeypatch.undo()
    path.write_text(json.dumps(["patent"] * 300_000))
    t0 = time.perf_counter()
    with pytest.raises(ParameterError, match=r"repeated: \['patent'\]$"):
        load_motors_file(str(path), protocol)
    assert time.perf_counter() - t0 < 1.0
    # Many repeated names: five shown.
    path.write_text(json.dumps([f"m{k % 1000}" for k in range(300_000)]))
    with pytest.raises(ParameterError, match=r"repeated: \[.*\] and 995 more$"):
        load_motors_file(str(path), protocol)


def test_motors_file_size_bound(tmp_path):
    path = tmp_path / "motors.json"
    path.write_text(json.dumps([{"name": f"m{k}"} for k in range(LIMITS.custom_motors + 1)]))
    t0 = time.perf_counter()
    with pytest.raises(ParameterError, match=r"--motors .* holds 1001 motors; allowed 1 to "
                                             r"1000$"):
        load_motors_file(str(path), full_protocol_v1())
    assert time.perf_counter() - t0 < 1.0


# ---------------------------------------------------------------------------
# The env's acceleration minimum is the CLI's
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("options", [EnvOptions, EnvOptionsV1])
def test_env_accel_minimum(options):
    for bad in (1e-308, 5e-324, 9.99e-4, 0.0):
        with pytest.raises(ParameterError, match=r"^accel_rps2=.* is outside its allowed "
                                                 r"range \[0\.001, 100000\.0\]$"):
            options(accel_rps2=bad)
    assert options(accel_rps2=MIN_ACCEL_RPS2).accel_rps2 == MIN_ACCEL_RPS2


def test_cli_accel_minimum_is_the_same_constant(capsys):
    assert MIN_ACCEL_RPS2 == 1e-3
    with pytest.raises(SystemExit) as info:
        main(["simulate", "--speed", "1", "--accel", "9.99e-4"])
    assert info.value.code == 2
    assert "[0.001, 1e+06]" in capsys.readouterr().err


# ---------------------------------------------------------------------------
# A full disk names the file
# ---------------------------------------------------------------------------
def _enospc(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_enospc_on_write_names_the_path(tmp_path, monkeypatch):
    path = str(tmp_path / "out.json")
    monkeypatch.setattr(sio.json, "dump", _enospc)
    with pytest.raises(OSError) as info:
        sio.write_json(path, {"a": 1})
    assert info.value.errno == errno.ENOSPC and info.value.filename == path
    assert path in str(info.value) and "->" not in str(info.value)
    assert os.listdir(tmp_path) == []              # no temporary file left


def test_enospc_on_rename_names_the_path(tmp_path, monkeypatch):
    path = str(tmp_path / "out.json")

    def replace(src, dst):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), src, None, dst)

    monkeypatch.setattr(sio.os, "replace", replace)
    with pytest.raises(OSError) as info:
        sio.write_json(path, {"a": 1})
    monkeypatch.undo()
    assert info.value.errno == errno.ENOSPC and info.value.filename == path
    assert os.listdir(tmp_path) == []


def test_cli_enospc_names_the_path(tmp_path, monkeypatch, capsys):
    path = str(tmp_path / "trace.npz")
    monkeypatch.setattr(np, "savez_compressed", _enospc)
    assert main(["simulate", "--speed", "1", "--trace", path]) == 2
    err = _one_line_error(capsys, "simulate")
    assert repr(path) in err and os.strerror(errno.ENOSPC) in err, err
    assert os.listdir(tmp_path) == []


# ---------------------------------------------------------------------------
# Signals: a long simulate stops within a second
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def startup_s():
    """Compile (or load the cache) once; the wall time of a warm start."""
    _cli("simulate", "--speed", "1")
    t0 = time.perf_counter()
    done = _cli("simulate", "--speed", "1")
    assert done.returncode == 0, done.stderr
    return time.perf_counter() - t0


@pytest.mark.slow
@pytest.mark.parametrize("sig,status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_long_simulate_stops_within_a_second_of_a_signal(sig, status, startup_s):
    # 2e8 PWM periods: half a minute or more of simulation.
    # Ctrl-C's default action even where the suite runs in the background (a shell
    # starts background jobs with SIGINT ignored, and children inherit that: the run
    # then went on, in the compiled loop, as faulthandler's dump showed).
    # faulthandler: a run that outlives the signal is aborted and says where it sat.
    proc = subprocess.Popen([sys.executable, "-X", "faulthandler", "-m", "stepdamp_env.cli",
                             "simulate", "--speed", "1", "--duration", str(MAX_DURATION_S)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT,
                                                             signal.default_int_handler))
    try:
        # Well inside the simulation loop (a warm start and its short run is startup_s).
        time.sleep(max(1.5, 2.0 * startup_s))
        assert proc.poll() is None, "the run ended before the signal"
        proc.send_signal(sig)
        t0 = time.perf_counter()
        try:
            out, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGABRT)
            out, err = proc.communicate(timeout=30)
            pytest.fail(f"no exit 30 s after signal {sig!r}; where it sat:\n{err[-4000:]}")
        elapsed = time.perf_counter() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == status, (proc.returncode, err)
    assert elapsed < 1.0, elapsed
    assert "Traceback" not in err, err
    if sig == signal.SIGINT:
        assert err.strip() == "stepdamp simulate: interrupted; earlier results are unchanged"


def test_a_run_of_more_plant_steps_than_the_limit_is_refused_before_it_starts(capsys):
    start = time.monotonic()
    assert main(["simulate", "--speed", "2", "--duration", "10000", "--substeps", "1000"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "plant steps" in err and "substeps" in err
    assert time.monotonic() - start < 30
