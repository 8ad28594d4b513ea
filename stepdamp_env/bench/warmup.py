"""The warm-up before a board forks its workers: every compiled kernel, env step
and fit loaded once (compiled first, in parallel, where this code's numba cache
is cold), so that the workers inherit them."""

from __future__ import annotations

import os
import sys
import time
from typing import Any, Callable

import numpy as np

from .. import fixedmath as fm
from .. import lanes, numba_cache
from ..env.engine import StepperDampBatch
from ..env.scalar import StepperDampEnv
from ..env.v1 import StepperDampV1Env, StepperDampV1VectorEnv
from ..estimators import kalman_velocity_gains
from ..fixednet import mlp_forward
from ..parallel import pool_map
from ..params import SystemParams
from ..simulation import RunSettings, SpeedProfile, simulate

__all__ = ["warm_up", "warm_lanes", "compiled_marker", "machine_tag"]


def compiled_marker(part: str = "") -> str | None:
    """The file the warm-up leaves once this code has compiled for this CPU (None:
    nothing is cached); ``part`` "lanes": the SIMD lanes' (:func:`warm_lanes`).
    Like numba's cache (:func:`.numba_cache.package_subpath`), it is the code's,
    wherever the code is installed (``pip install .`` beside ``-e .``, a CI
    checkout). Its name holds :func:`machine_tag`: a cache shared by another CPU
    (or ``NUMBA_CPU_NAME``) compiles anew, so the notice is given again."""
    where = numba_cache.active_cache_dir()           # "": nothing is cached, always cold
    if not where:
        return None
    return os.path.join(where, f"compiled{'-' + part if part else ''}-{machine_tag()}")


def machine_tag() -> str:
    """12 hex digits of numba's target machine (triple, CPU name and features):
    what numba's cache index keys compiled code by, besides the code."""
    import hashlib

    from numba.core.registry import cpu_target

    machine = repr(cpu_target.target_context.codegen().magic_tuple())
    return hashlib.sha256(machine.encode()).hexdigest()[:12]


def _warm_plain(system: SystemParams) -> None:
    """The kernel's plain loop (simulation, StepperDamp-v0, v1's harmonic actions),
    and the small compiled helpers of identification, estimators and statistics."""
    simulate(system, settings=RunSettings(settle_s=0.0, window_s=0.001), trace=True,
             profile=SpeedProfile(speed_rps=0.5, accel_rps2=1000.0))
    env = StepperDampEnv(motor=system, speed_rps=0.5, measure_from_s=0.0)
    env.reset(seed=0)
    env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    env.run_metrics()
    _warm_batch(StepperDampEnv(motor=system, speed_rps=0.5, measure_from_s=0.0))
    _warm_batch(StepperDampV1Env(motor=system, speed_rps=0.5, measure_from_s=0.0,
                                 action_mode="harmonic"))
    fm.lstsq(np.eye(3), np.ones(3))
    fm.atan2(1.0, 1.0)
    fm.dot(np.ones(3), np.ones(3))
    fm.weighted_rows(np.eye(3), np.ones(3))
    fm.exp_array(np.zeros(3))
    fm.random_walk_kalman_update(np.zeros((1, 2)), np.eye(2)[None].copy(), np.ones((1, 2)),
                                 np.zeros(1), 1e-4, 0.09)
    kalman_velocity_gains(5e-5, 2.0 * np.pi / 4000.0, 1e4)
    # The learned entries' network, with the argument types bench.network passes.
    mlp_forward(np.zeros((1, 1), np.float32), np.ones(1), np.zeros(1),
                np.array([1, 1], np.int64), np.zeros(1, np.int64))


def _warm_law(system: SystemParams) -> None:
    """The kernel's loop with the damping law (StepperDamp-v1's default actions)."""
    _warm_batch(StepperDampV1Env(motor=system, speed_rps=0.5, measure_from_s=0.0))
    env = StepperDampV1Env(motor=system, speed_rps=0.5, measure_from_s=0.0,
                           render_mode="rgb_array")
    env.reset(seed=0)
    env.step(np.zeros(env.action_space.shape, dtype=np.float32))


def _warm_batch(env: StepperDampEnv | StepperDampV1Env) -> None:
    env.reset(seed=0)
    batch = StepperDampBatch([env])
    batch.step(np.zeros((1, env.action_space.shape[0]), dtype=np.float32))


#: The warm-up in two parts that share no kernel loop (without and with the
#: damping law: each inlines the whole drive; small helpers compile in both).
_WARM_PARTS = (_warm_plain, _warm_law)


def _warm_part(job: tuple[int, SystemParams]) -> None:
    numba_cache.call_with_frame_room(_WARM_PARTS[job[0]], job[1])


def warm_up(system: SystemParams, workers: int = 1, progress: bool = False) -> float:
    """Load the compiled kernel, env steps and fits once, before forking, so that
    the workers inherit them instead of each loading the numba cache again.
    Where this version's numba cache is cold, the parts compile in ``workers``
    processes first (they share no compiled code), with a line on stderr if
    ``progress``. Returns the seconds spent."""
    return _compile_once(compiled_marker(), _warm_part,
                         [(k, system) for k in range(len(_WARM_PARTS))], workers, progress,
                         "the simulation kernels", "one to two minutes")


def _warm_lanes(action_mode: str) -> None:
    """The SIMD lanes' loop of one action mode: "harmonic" (plain) or
    "damping-gains" (with the damping law)."""
    env = StepperDampV1VectorEnv(num_envs=lanes.LANES + 5, simd=True, agent_hz=500.0,
                                 action_mode=action_mode)
    env.reset(seed=0)
    numba_cache.call_with_frame_room(
        env.step, np.zeros(env.action_space.shape, dtype=np.float32))


#: The lanes' two loops (without and with the damping law: they share no loop).
LANES_PARTS = ("harmonic", "damping-gains")


def warm_lanes(workers: int = 1, progress: bool = False, always: bool = False,
               here: bool = True) -> float:
    """:func:`warm_up` for the SIMD lanes, where batches step in them by default
    (:func:`.lanes.simd_by_default`; else nothing to do, unless ``always``,
    as the tests, which step in lanes on any CPU): compiled in ``workers``
    processes first where this code's cache is cold (about a minute, announced
    on stderr if ``progress``), then loaded here unless not ``here`` (processes
    that do not fork from this one: only the cache is filled). Returns the seconds
    spent."""
    if not (always or lanes.simd_by_default(lanes.LANES)):
        return 0.0
    return _compile_once(compiled_marker("lanes"), _warm_lanes, list(LANES_PARTS), workers,
                         progress, "the SIMD lanes", "about a minute", here)


def _compile_once(marker: str | None, part: Callable[[Any], None], jobs: list[Any],
                  workers: int, progress: bool, what: str, how_long: str,
                  here: bool = True) -> float:
    """Run ``part`` on each job here (unless not ``here``); where ``marker`` is
    missing (this code's cache cold) first on ``workers`` processes, which fill
    the numba cache in parallel, announced on stderr if ``progress``; then leave
    the marker. Returns the seconds spent."""
    start = time.perf_counter()
    cold = marker is None or not os.path.exists(marker)
    if cold and progress:
        print(f"compiling {what} for this version of the code, once "
              f"({min(workers, len(jobs))} process(es); {how_long})...",
              file=sys.stderr, flush=True)
    if cold and workers > 1:
        try:
            pool_map(part, jobs, min(workers, len(jobs)), min_jobs=2)
        except Exception:       # noqa: BLE001 - a part failed: compiled here below
            pass
    if here or workers <= 1:
        for job in jobs:
            part(job)
    if cold and marker is not None:
        _mark(marker)
        if progress:
            print(f"compiled in {time.perf_counter() - start:.0f} s", file=sys.stderr,
                  flush=True)
    return time.perf_counter() - start


def _mark(marker: str) -> None:
    try:
        with open(marker, "w", encoding="utf-8") as fh:
            fh.write("compiled\n")
    except OSError:
        pass
