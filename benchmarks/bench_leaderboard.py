"""Wall time of ``stepdamp leaderboard``: the full stepdamp-bench v0 protocol and --quick.

Run: ``PYTHONPATH=. python benchmarks/bench_leaderboard.py [--workers 2] [--skip-full]``.
Each variant runs as its own ``stepdamp leaderboard`` process (imports, numba
cache load, identification, every model-based baseline in ``BASELINE_NAMES``,
both suites, result files and figures), so the times are what a user waits.
Targets on 2 cores: full < 5 min, quick < 1 min.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def time_variant(quick: bool, workers: int, out: str) -> float:
    cmd = [sys.executable, "-m", "stepdamp_env.cli", "leaderboard", "--out", out,
           "--no-progress", "--workers", str(workers)] + (["--quick"] if quick else [])
    env = {**os.environ, "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=ROOT, env=env, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--skip-full", action="store_true")
    args = parser.parse_args()
    import stepdamp_env.bench as bench

    print(f"policies: {', '.join(bench.default_policy_names())}; workers: {args.workers}")
    with tempfile.TemporaryDirectory() as tmp:
        variants = [("quick", True, 60.0)] + ([] if args.skip_full else [("full", False, 300.0)])
        for label, quick, target in variants:
            wall = time_variant(quick, args.workers, os.path.join(tmp, label))
            status = "ok" if wall < target else "OVER TARGET"
            print(f"{label:5s}: {wall:7.1f} s wall (target < {target:.0f} s) {status}")


if __name__ == "__main__":
    main()
