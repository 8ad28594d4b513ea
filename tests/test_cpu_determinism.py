"""The same numbers on every x86-64 CPU, from x86-64-v2 to AVX-512, and any thread count.

The quick boards of v0 to v5 (every default entry) and rollouts of the
StepperDamp-v2 and v3 vector envs give the fingerprints stored in
``tests/data/quick_boards.json`` here; the v0 and v3 quick boards and the
rollouts give them in fresh processes under emulated CPUs too (``tests/cpu_variants.py``
says what each variant changes): the oldest CPU (every library on its
x86-64-v2 path, numba generic, the C library without FMA, one worker) and this
machine with OpenBLAS's AVX-512 kernels (one worker; skipped where OpenBLAS
picks them anyway, as on an AVX-512 machine: the first test is that cell),
side by side. An AVX2 machine, the other variants, every protocol and the
full boards: ``python benchmarks/bench_determinism.py``.
"""

from __future__ import annotations

import pytest

import cpu_variants as V

# Every board here is computed again in subprocesses, some on emulated CPUs (minutes).
pytestmark = pytest.mark.slow


# CI's budget (20 minutes) keeps two cells here: the oldest CPU (every library
# on its x86-64-v2 path, numba generic, the C library without FMA) and OpenBLAS's
# AVX-512 kernels. The AVX2 machine, the other variants and all five protocols:
# benchmarks/bench_determinism.py (docs/reproducibility.md quotes its output).
EMULATED = ("x86-64-v2", "skylakex")
#: The boards the emulated CPUs compute: the oldest (its own env wrapper) and the
#: published default; v1 and v2 run the same kernels and statistics code. v4's
#: moves suite runs kernel code of its own (the S-curve): it once differed under
#: x86-64-v2 through libm's sin and cos, which test_architecture now refuses;
#: its emulated board (about 10 minutes) is in benchmarks/bench_determinism.py.
EMULATED_PROTOCOLS = ("v0", "v3", "env-v2", "env-v3")


@pytest.fixture(scope="module")
def emulated():
    """The emulated variants, started together (each one worker: side by side on
    two cores, in about half the time one after the other)."""
    # The SIMD lanes' check under emulation: benchmarks/bench_determinism.py (CI time).
    procs = {name: V.start_variant(name, EMULATED_PROTOCOLS, lanes=False) for name in EMULATED
             if V.runs_here(name)}
    yield procs
    for proc in procs.values():
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def test_the_quick_boards_here_are_the_stored_ones(emulated):
    # The emulated CPUs' processes (the fixture) run meanwhile: CI's time.
    got = V.quick_boards(workers=2)
    assert V.differences(V.stored(), got) == []


@pytest.mark.parametrize("variant", EMULATED)
def test_the_quick_boards_on_an_emulated_cpu_are_the_stored_ones(variant, emulated):
    if variant not in emulated:
        pytest.skip(f"{variant}: this CPU cannot run its code, or it is this machine's own "
                    "configuration (the boards of the test above)")
    stored = {k: v for k, v in V.stored().items() if k in EMULATED_PROTOCOLS}
    assert V.differences(stored, V.finish_variant(emulated[variant])) == []


def test_report_check_reruns_a_boards_cells_and_finds_an_edited_file(tmp_path):
    import lzma
    import json
    import os
    import subprocess
    import sys

    from stepdamp_env.bench import protocol_motors, quick_protocol_v1

    motors = tmp_path / "motors.json"
    motors.write_text(json.dumps([protocol_motors(quick_protocol_v1())[0].system.to_dict()]))
    out = tmp_path / "board"
    env = {**os.environ, "MPLBACKEND": "Agg"}

    def stepdamp(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "stepdamp_env.cli", *args], env=env,
                              capture_output=True, text=True)

    made = stepdamp("leaderboard", "--quick", "--motors", str(motors), "--suite", "open-loop",
                    "--entries", "ff-delay-comp", "adaptive-ff", "--out", str(out), "--no-plots",
                    "--no-progress", "--workers", "1")
    assert made.returncode == 0, made.stderr[-2000:]
    check = stepdamp("report", str(out), "--check", "--sample", "4")
    assert check.returncode == 0, check.stdout + check.stderr[-2000:]
    lines = check.stdout.splitlines()
    assert sum(line.startswith("reproduces") for line in lines) >= 6     # files, motors, ident, 4 cells
    assert lines[-1].endswith("checks reproduce") and "DIFFERS" not in check.stdout
    runs = out / "leaderboard_runs.json.xz"
    raw = json.loads(lzma.open(runs).read())
    raw["entries"][0]["runs"][0]["metrics"]["rms_velocity_error_rad_s"] *= 1.0 + 1e-15
    with lzma.open(runs, "wt") as fh:
        json.dump(raw, fh)
    check = stepdamp("report", str(out), "--check", "--sample", "1")
    assert check.returncode == 1
    assert "DIFFERS     board fingerprint (the files)" in check.stdout


def test_check_finds_each_committed_run_by_its_speed():
    """Labels repeat on a grid (every off-resonance speed is "off"): --check once
    re-ran the first "off" speed for each of them and reported a difference."""
    import os

    from stepdamp_env.bench.check import job_of_run, protocol_of_board
    from stepdamp_env.bench.motors import protocol_motors
    from stepdamp_env.bench.report import load_leaderboard

    board = load_leaderboard(os.path.join(os.path.dirname(__file__), "..", "docs", "results"))
    motors = protocol_motors(protocol_of_board(board))
    repeated = 0
    for e in board["entries"]:
        for r in e["runs"]:
            job = job_of_run(motors, e, r)
            speeds, labels = motors[job.motor_index].speeds(e["suite"])
            assert speeds[job.speed_index] == r["speed_rps"]
            repeated += labels.count(r["speed_label"]) > 1
    assert repeated > 0
