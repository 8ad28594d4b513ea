"""Wall time of ``stepdamp leaderboard``: a protocol's full variant and --quick.

Run: ``PYTHONPATH=. python benchmarks/bench_leaderboard.py [--protocol v1] [--workers 2]
[--skip-full]``.
Each variant runs as its own ``stepdamp leaderboard`` process (imports, numba
cache load, identification, every default entry (the baselines and the
reference agents; v1: every training seed), both suites, result files and
figures), so the times are what a user waits; the board's own ``wall_seconds``
(the runs, without imports and figures) and ``simulated_seconds`` are printed
beside. Targets on 2 cores: full < 5 min, quick < 1 min.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def time_variant(protocol: str, quick: bool, workers: int, out: str) -> tuple[float, dict]:
    cmd = [sys.executable, "-m", "stepdamp_env.cli", "leaderboard", "--out", out,
           "--protocol", protocol, "--no-progress",
           "--workers", str(workers)] + (["--quick"] if quick else [])
    env = {**os.environ, "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=ROOT, env=env, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    with open(os.path.join(out, "leaderboard.json"), encoding="utf-8") as fh:
        return wall, json.load(fh)


def main() -> None:
    from stepdamp_env.bench.protocols import DEFAULT_VERSION, protocol_versions

    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--protocol", choices=protocol_versions(), default=DEFAULT_VERSION)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--skip-full", action="store_true")
    args = parser.parse_args()
    import stepdamp_env.bench as bench

    from stepdamp_env.bench.protocols import protocol_for

    names = protocol_for(args.protocol).default_entries(bench.default_policy_names())
    print(f"policies: {', '.join(names)}; workers: {args.workers}")
    with tempfile.TemporaryDirectory() as tmp:
        variants = [("quick", True, 60.0)] + ([] if args.skip_full else [("full", False, 300.0)])
        for label, quick, target in variants:
            wall, board = time_variant(args.protocol, quick, args.workers,
                                       os.path.join(tmp, label))
            status = "ok" if wall < target else "OVER TARGET"
            sim = board["simulated_seconds"]
            print(f"{args.protocol} {label:5s}: {wall:7.1f} s wall (target < {target:.0f} s) "
                  f"{status}; runs {board['wall_seconds']:.1f} s, simulated {sim:.0f} s "
                  f"({sim / board['wall_seconds']:.0f} simulated s per wall s)")


if __name__ == "__main__":
    main()
