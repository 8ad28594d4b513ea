"""The first board on a fresh machine against the next one (issue: cold start).

Run: ``PYTHONPATH=. python benchmarks/bench_cold_start.py [--quick] [--workers 2]
[--skip-board] [--skip-serial] [--skip-numba-inliner]``.

* **Compile**: :func:`stepdamp_env.bench.leaderboard.warm_up` (the kernels) and
  :func:`stepdamp_env.bench.warmup.warm_lanes` (the SIMD lanes) in a fresh numba
  cache, serially (``workers=1``) and in ``--workers`` processes, each in its
  own process; then once more, warm. Then in ``--workers`` processes with
  numba's own inliner (``STEPDAMP_NUMBA_INLINER=numba``, see
  ``stepdamp_env.numba_inline``), the reference of the patched one.
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
           "from stepdamp_env.bench.warmup import warm_lanes; "
           "w = int(sys.argv[1]); k = warm_up(load_system('patent'), workers=w); "
           "print(k, warm_lanes(workers=w, always=True))")


def _env(cache: str, inliner: str = "patched") -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CACHE_DIR", "STEPDAMP_CACHE_DIR", "_STEPDAMP_NUMBA_CACHE_DIR",
                        "_STEPDAMP_NUMBA_CACHE_BASE")}
    return {**env, "XDG_CACHE_HOME": cache, "MPLBACKEND": "Agg",
            "STEPDAMP_NUMBA_INLINER": inliner,
            "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}


def compile_time(workers: int, cache: str, inliner: str = "patched") -> tuple[float, float]:
    """Seconds to compile (or load) the kernels and the SIMD lanes."""
    out = subprocess.run([sys.executable, "-c", WARM_UP, str(workers)], check=True,
                         capture_output=True, text=True, env=_env(cache, inliner), cwd=ROOT)
    kernels, lanes = out.stdout.split()[-2:]
    return float(kernels), float(lanes)


def _seconds(t: tuple[float, float]) -> str:
    return f"{t[0]:.1f} + {t[1]:.1f} = {sum(t):.1f} s"


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
    p.add_argument("--skip-serial", action="store_true", help="no serial compile")
    p.add_argument("--skip-numba-inliner", action="store_true",
                   help="no compile with numba's own inliner (the slow reference)")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        parallel = compile_time(args.workers, os.path.join(tmp, "c2"))
        warm = compile_time(args.workers, os.path.join(tmp, "c2"))
        print(f"compile (kernels + SIMD lanes, fresh numba cache): {args.workers} processes "
              f"{_seconds(parallel)}; warm load {_seconds(warm)}")
        if not args.skip_serial:
            serial = compile_time(1, os.path.join(tmp, "c1"))
            print(f"compile serially: {_seconds(serial)} ({args.workers} processes / serial "
                  f"= {sum(parallel) / sum(serial):.2f})")
        if not args.skip_numba_inliner:
            plain = compile_time(args.workers, os.path.join(tmp, "c3"), "numba")
            print(f"compile with numba's own inliner, {args.workers} processes: "
                  f"{_seconds(plain)}; patched / numba's = {sum(parallel) / sum(plain):.2f}")
        if args.skip_board:
            return
        cache = os.path.join(tmp, "board")
        cold = board_time(args.quick, args.workers, cache, os.path.join(tmp, "o1"))
        hot = board_time(args.quick, args.workers, cache, os.path.join(tmp, "o2"))
        print(f"{'quick' if args.quick else 'full'} board, stepdamp leaderboard end to end: "
              f"cold {cold:.1f} s, warm {hot:.1f} s, cold / warm = {cold / hot:.2f}")


if __name__ == "__main__":
    main()
