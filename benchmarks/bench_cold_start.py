"""The first board on a fresh machine against the next one (issue: cold start).

Run: ``PYTHONPATH=. python benchmarks/bench_cold_start.py [--quick] [--workers 2]
[--skip-board]``.

* **Compile**: :func:`stepdamp_env.bench.leaderboard.warm_up` in a fresh numba
  cache, serially (``workers=1``) and in ``--workers`` processes, each in its
  own process; then once more, warm.
* **Board**: ``stepdamp leaderboard`` (full, or ``--quick``) with every cache
  empty (numba, identification, grids: a fresh ``XDG_CACHE_HOME``), then again
  with them filled. Prints both wall times and their ratio (target: cold within
  1.5 x warm).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

WARM_UP = ("import sys, time; from stepdamp_env.motorfile import load_system; "
           "from stepdamp_env.bench.leaderboard import warm_up; "
           "print(warm_up(load_system('patent'), workers=int(sys.argv[1])))")


def _env(cache: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CACHE_DIR", "STEPDAMP_CACHE_DIR", "_STEPDAMP_NUMBA_CACHE_DIR",
                        "_STEPDAMP_NUMBA_CACHE_BASE")}
    return {**env, "XDG_CACHE_HOME": cache, "MPLBACKEND": "Agg",
            "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}


def compile_time(workers: int, cache: str) -> float:
    out = subprocess.run([sys.executable, "-c", WARM_UP, str(workers)], check=True,
                         capture_output=True, text=True, env=_env(cache), cwd=ROOT)
    return float(out.stdout.split()[-1])


def board_time(quick: bool, workers: int, cache: str, out: str) -> float:
    cmd = [sys.executable, "-m", "stepdamp_env.cli", "leaderboard", "--out", out,
           "--no-progress", "--workers", str(workers)] + (["--quick"] if quick else [])
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, env=_env(cache), cwd=ROOT, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--quick", action="store_true", help="the quick board instead of the full")
    p.add_argument("--skip-board", action="store_true", help="the compile times only")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        serial = compile_time(1, os.path.join(tmp, "c1"))
        parallel = compile_time(args.workers, os.path.join(tmp, "c2"))
        warm = compile_time(args.workers, os.path.join(tmp, "c2"))
        print(f"compile (warm_up, fresh numba cache): serial {serial:.1f} s, "
              f"{args.workers} processes {parallel:.1f} s (ratio {parallel / serial:.2f}); "
              f"warm load {warm:.1f} s")
        if args.skip_board:
            return
        cache = os.path.join(tmp, "board")
        cold = board_time(args.quick, args.workers, cache, os.path.join(tmp, "o1"))
        hot = board_time(args.quick, args.workers, cache, os.path.join(tmp, "o2"))
        print(f"{'quick' if args.quick else 'full'} board, stepdamp leaderboard end to end: "
              f"cold {cold:.1f} s, warm {hot:.1f} s, cold / warm = {cold / hot:.2f}")


if __name__ == "__main__":
    main()
