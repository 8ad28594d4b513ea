"""One process pool for every batch of independent runs (sweeps, leaderboards)."""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable, Sequence

__all__ = ["default_workers", "pool_map"]


def default_workers() -> int:
    """Every core this process may use."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
               else (os.cpu_count() or 1))


def pool_map(fn: Callable[[Any], Any], jobs: Sequence[Any], workers: int, *,
             initializer: Callable[..., None] | None = None, initargs: tuple = (),
             min_jobs: int = 2, max_chunk: int | None = None, bar: Any = None) -> list[Any]:
    """``[fn(job) for job in jobs]``, in order, in this process or on ``workers`` processes.

    Runs serially (after calling ``initializer(*initargs)`` here) when
    ``workers <= 1`` or there are fewer than ``min_jobs`` jobs. Workers are
    forked where the platform can, so they inherit what the parent loaded
    (compiled kernels, models). ``bar`` (a tqdm bar) is advanced per result.
    """
    out: list[Any] = []
    if workers <= 1 or len(jobs) < min_jobs:
        if initializer is not None:
            initializer(*initargs)
        for job in jobs:
            out.append(fn(job))
            if bar is not None:
                bar.update()
        return out
    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    chunk = max(1, len(jobs) // (workers * 8))
    if max_chunk is not None:
        chunk = min(chunk, max_chunk)
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context(method),
                             initializer=initializer, initargs=initargs) as pool:
        for r in pool.map(fn, jobs, chunksize=chunk):
            out.append(r)
            if bar is not None:
                bar.update()
    return out
