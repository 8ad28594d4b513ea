"""Wall time of ``stepdamp leaderboard``: a protocol's full variant and --quick.

Run: ``PYTHONPATH=. python benchmarks/bench_leaderboard.py [--protocol v1] [--workers 2]
[--skip-full]``, or ``--against v1 [--repeat 3]`` to compare two protocols' full
boards per simulated second (see :func:`compare`).
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


def compare(protocol: str, against: str, workers: int, repeat: int, tmp: str) -> None:
    """Simulated seconds per board second (the board's ``wall_seconds``: motors,
    identification, runs and scores; caches warm) of two protocols' full
    boards, run one after the other ``repeat`` times after one warm-up run of
    each (it fills the identification and grid caches); the ratio of their
    medians is the comparison, both measured in the same run."""
    rates: dict[str, list[float]] = {protocol: [], against: []}
    for k in range(repeat + 1):
        for version in (protocol, against):
            _, board = time_variant(version, False, workers, os.path.join(tmp, version))
            rate = board["simulated_seconds"] / board["wall_seconds"]
            tag = "warm-up" if k == 0 else f"run {k}"
            print(f"{version} full, {tag}: {board['wall_seconds']:6.1f} s, simulated "
                  f"{board['simulated_seconds']:.0f} s, {rate:.0f} simulated s per s", flush=True)
            if k:
                rates[version].append(rate)
    med = {v: sorted(r)[len(r) // 2] for v, r in rates.items()}
    print(f"median: {protocol} {med[protocol]:.0f}, {against} {med[against]:.0f} simulated s "
          f"per s; {protocol} / {against} = {med[protocol] / med[against]:.3f}")


def main() -> None:
    from stepdamp_env.bench.protocols import DEFAULT_VERSION, protocol_versions

    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--protocol", choices=protocol_versions(), default=DEFAULT_VERSION)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--skip-full", action="store_true")
    parser.add_argument("--against", choices=protocol_versions(),
                        help="compare --protocol's full board with this version's")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each with --against")
    args = parser.parse_args()
    if args.against:
        with tempfile.TemporaryDirectory() as tmp:
            compare(args.protocol, args.against, args.workers, args.repeat, tmp)
        return
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
