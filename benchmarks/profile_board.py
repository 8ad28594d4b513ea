"""Where a board's time goes: the full default board in one process, timed by part.

Run: ``PYTHONPATH=. python benchmarks/profile_board.py [--quick] [--top 25]``.

``--phases [--protocol v5] [--workers 2]`` runs the board once as the CLI does
(numba's cache warm) and prints the wall time of ``run_leaderboard``'s parts:
motors, identification, the runs' batches and the scoring (``_board``).

``--by-entry [--protocol v4] [--workers 2]`` instead runs the board once (on the
CLI's pool of workers, compiled by one process: run it with numba's cache warm)
and prints the wall time of its batches summed by entry and suite (each worker
times the batches it runs: the sums exceed the board's wall time by about the
number of workers).

The board runs with one worker (every part in this process, caches warm: a first
board fills them), with timers around the kernel's entry points, the
identification, the policies' batched forward passes and the parts of
``run_leaderboard``; then cProfile's top functions by own time. Kernel time is
split into what the identification, the calibration rig and the runs spend. The
rest of the runs' time is Python: env building, policy code, the runner's step.
"""

from __future__ import annotations

import argparse
import cProfile
import collections
import functools
import os
import pstats
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TIMES: collections.Counter[str] = collections.Counter()
_STACK: list[str] = []


def timed(label: str, fn):
    """``fn`` with its wall time added to ``TIMES[label]`` (outermost call only)."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        if label in _STACK:
            return fn(*args, **kwargs)
        _STACK.append(label)
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            TIMES[label] += time.perf_counter() - t0
            _STACK.pop()
    return wrapper


def kernel_timed(fn):
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            where = ("identification" if "identification" in _STACK else
                     "rig" if "rig" in _STACK else "motors" if "motors" in _STACK else "runs")
            TIMES[f"kernel in {where}"] += time.perf_counter() - t0
    return wrapper


def install() -> None:
    from stepdamp_env import fixednet, kernel
    from stepdamp_env.bench import leaderboard, rig, runner
    from stepdamp_env.env import engine

    for name in ("run_periods", "run_periods_law", "step_batch", "step_batch_parallel"):
        setattr(kernel, name, kernel_timed(getattr(kernel, name)))
    # The SIMD lanes (most of a board's kernel time), wrapped where the engine picks
    # them: lanes' own module globals stay compiled functions (its parallel step calls
    # step_lanes).
    pick, lanes_timed = engine.batch_step, {}

    def batch_step(simd, parallel):
        step = pick(simd, parallel)
        if not simd:
            return step
        if step not in lanes_timed:
            lanes_timed[step] = kernel_timed(step)
        return lanes_timed[step]

    engine.batch_step = batch_step
    fixednet.mlp_forward = timed("policy forward (mlp_forward)", fixednet.mlp_forward)
    leaderboard.identify = timed("identification", leaderboard.identify)
    leaderboard.protocol_motors = timed("motors", leaderboard.protocol_motors)
    leaderboard.warm_up = timed("warm-up", leaderboard.warm_up)
    rig.CalibrationRig.harmonic_ripple = timed("rig", rig.CalibrationRig.harmonic_ripple)
    runner.run_episodes = timed("runs (run_episodes)", runner.run_episodes)
    leaderboard.run_episodes = runner.run_episodes
    from stepdamp_env.env import StepperDampEnv, StepperDampV1Env

    for cls in (StepperDampEnv, StepperDampV1Env):     # env building: construct and reset
        cls.__init__ = timed("env building", cls.__init__)
        cls.reset = timed("env building", cls.reset)


class _Timed:
    """A board's job function that appends each batch's wall time to a log, one
    short line per batch (module level: the pool's workers receive it pickled)."""

    def __init__(self, fn, log: str) -> None:
        self.fn, self.log = fn, log

    def __call__(self, job):
        import json

        t0 = time.perf_counter()
        out = self.fn(job)
        if hasattr(job, "spec"):            # a batch of runs (not an identification)
            with open(self.log, "a") as f:
                f.write(json.dumps([job.spec, job.suite, len(job.runs),
                                    time.perf_counter() - t0,
                                    sum(r.get("simulated_s", 0.0) for r in out)]) + "\n")
        return out


def by_entry(protocol, workers: int) -> None:
    """Run the board once; print its batches' wall time by entry and suite."""
    import json
    import tempfile

    from stepdamp_env.bench import run_leaderboard
    from stepdamp_env.parallel import pool_map

    log = tempfile.NamedTemporaryFile("w", suffix=".jsonl", delete=False).name

    def backend(fn, jobs, n, **kwargs):
        return pool_map(_Timed(fn, log), jobs, n, **kwargs)

    t0 = time.perf_counter()
    board = run_leaderboard(protocol, workers=workers, progress=False, backend=backend)
    total = time.perf_counter() - t0
    rows: dict = collections.defaultdict(lambda: [0, 0.0, 0.0])
    for line in open(log):
        spec, suite, runs, wall, sim = json.loads(line)
        for key in ((spec, suite), (spec, "(all)")):
            rows[key][0] += runs
            rows[key][1] += wall
            rows[key][2] += sim
    os.unlink(log)
    busy = sum(v[1] for k, v in rows.items() if k[1] == "(all)")
    print(f"board {total:.1f} s with {workers} workers; batches {busy:.1f} worker-s, simulated "
          f"{board['simulated_seconds']:.0f} s")
    print(f"  {'entry':28s} {'suite':16s} {'runs':>5s} {'worker-s':>9s} {'share':>6s} "
          f"{'sim s/s':>8s}")
    for (spec, suite), (runs, wall, sim) in sorted(rows.items(), key=lambda kv: -kv[1][1]):
        print(f"  {spec:28s} {suite:16s} {runs:5d} {wall:9.1f} {wall / busy:6.1%} "
              f"{sim / max(wall, 1e-9):8.0f}")


def phases(protocol, workers: int) -> None:
    """Run the board once; print the wall time of its parts."""
    from stepdamp_env.bench import leaderboard

    parts = ("warm_up", "protocol_motors", "_identify_all", "_policy_meta", "_batches",
             "_run_batches", "_board")
    for name in parts:
        setattr(leaderboard, name, timed(name, getattr(leaderboard, name)))
    t0 = time.perf_counter()
    board = leaderboard.run_leaderboard(protocol, workers=workers, progress=False,
                                        fingerprint=False)
    total = time.perf_counter() - t0
    print(f"board {total:.1f} s with {workers} workers (its wall_seconds "
          f"{board['wall_seconds']:.1f}), simulated {board['simulated_seconds']:.0f} s")
    for name in parts:
        print(f"  {name:16s} {TIMES[name]:7.1f} s  {TIMES[name] / total:6.1%}")
    rest = total - sum(TIMES[n] for n in parts)
    print(f"  {'the rest':16s} {rest:7.1f} s  {rest / total:6.1%}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true")
    p.add_argument("--top", type=int, default=25)
    p.add_argument("--by-entry", action="store_true",
                   help="time the batches by entry and suite (one board, as the CLI runs it)")
    p.add_argument("--protocol", default=None, help="protocol version (default: the default)")
    p.add_argument("--phases", action="store_true",
                   help="time run_leaderboard's parts (one board, as the CLI runs it)")
    p.add_argument("--workers", type=int, default=2, help="with --by-entry or --phases")
    args = p.parse_args()
    sys.path.insert(0, ROOT)
    t0 = time.perf_counter()
    import stepdamp_agents  # noqa: F401
    import stepdamp_baselines
    from stepdamp_env.bench import run_leaderboard
    from stepdamp_env.bench.protocols import DEFAULT_VERSION, protocol_for

    stepdamp_baselines.register_policies()
    protocol = protocol_for(args.protocol or DEFAULT_VERSION, quick=args.quick)
    imports = time.perf_counter() - t0
    if args.by_entry:
        by_entry(protocol, args.workers)
        return
    if args.phases:
        phases(protocol, args.workers)
        return
    run_leaderboard(protocol, workers=1, progress=False)          # fills the caches
    install()
    t0 = time.perf_counter()
    board = run_leaderboard(protocol, workers=1, progress=False)
    total = time.perf_counter() - t0
    print(f"imports {imports:.1f} s (not in the board's time); board {total:.1f} s in one "
          f"process, simulated {board['simulated_seconds']:.0f} s "
          f"({board['simulated_seconds'] / total:.0f} per s)")
    for label, seconds in sorted(TIMES.items(), key=lambda kv: -kv[1]):
        print(f"  {label:34s} {seconds:7.1f} s  {seconds / total:6.1%}")
    kernel = sum(v for k, v in TIMES.items() if k.startswith("kernel"))
    print(f"  {'kernel, all':34s} {kernel:7.1f} s  {kernel / total:6.1%}")
    rest = TIMES["runs (run_episodes)"] - TIMES["kernel in runs"] - TIMES["env building"] \
        - TIMES["policy forward (mlp_forward)"]
    print(f"  {'runs: Python per step':34s} {rest:7.1f} s  {rest / total:6.1%}")
    print("cProfile of the same board (its overhead slows the Python parts):", flush=True)
    prof = cProfile.Profile()
    prof.enable()
    run_leaderboard(protocol, workers=1, progress=False)
    prof.disable()
    pstats.Stats(prof).sort_stats("tottime").print_stats(args.top)


if __name__ == "__main__":
    main()
