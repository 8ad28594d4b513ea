"""One process pool for every batch of independent runs (sweeps, leaderboards)."""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import multiprocessing
import os
import signal
import sys
from typing import Any, Callable, Iterator, Sequence

__all__ = ["default_workers", "pool_map", "sigint_ignored"]


def default_workers() -> int:
    """Every core this process may use."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
               else (os.cpu_count() or 1))


def _worker_start(parent: int, initializer: Callable[..., None] | None,
                  initargs: tuple) -> None:
    """In each worker: die with the parent, leave Ctrl-C to the parent, then the
    caller's initializer."""
    if sys.platform.startswith("linux"):
        libc = ctypes.util.find_library("c")
        if libc is not None:
            pr_set_pdeathsig = 1
            ctypes.CDLL(libc, use_errno=True).prctl(pr_set_pdeathsig, signal.SIGKILL)
    if os.getppid() != parent:          # the parent died before prctl took effect
        os._exit(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if initializer is not None:
        initializer(*initargs)


def pool_map(fn: Callable[[Any], Any], jobs: Sequence[Any], workers: int, *,
             initializer: Callable[..., None] | None = None, initargs: tuple = (),
             min_jobs: int = 2, max_chunk: int | None = None, bar: Any = None,
             on_result: Callable[[int, Any], None] | None = None) -> list[Any]:
    """``[fn(job) for job in jobs]``, in order, in this process or on ``workers`` processes.

    Runs serially (after calling ``initializer(*initargs)`` here) when
    ``workers <= 1`` or there are fewer than ``min_jobs`` jobs. Workers are
    forked where the platform can, so they inherit what the parent loaded
    (compiled kernels, models). ``bar`` (a tqdm bar) is advanced per result;
    ``on_result(i, result)`` is called here as each result arrives (in order).
    Workers end with the parent: on any exception here (Ctrl-C included) the
    pool is terminated, and on Linux a worker is killed when its parent dies.
    """
    out: list[Any] = []
    if workers <= 1 or len(jobs) < min_jobs:
        if initializer is not None:
            initializer(*initargs)
        for i, job in enumerate(jobs):
            out.append(fn(job))
            if on_result is not None:
                on_result(i, out[-1])
            if bar is not None:
                bar.update()
        return out
    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    chunk = max(1, len(jobs) // (workers * 8))
    if max_chunk is not None:
        chunk = min(chunk, max_chunk)
    pool = multiprocessing.get_context(method).Pool(
        workers, initializer=_worker_start, initargs=(os.getpid(), initializer, initargs))
    try:
        for r in pool.imap(fn, jobs, chunksize=chunk):
            out.append(r)
            if on_result is not None:
                on_result(len(out) - 1, r)
            if bar is not None:
                bar.update()
        pool.close()
    except BaseException:
        # A second Ctrl-C inside terminate() would leave live workers that join()
        # then waits for forever: the teardown runs with SIGINT ignored.
        with sigint_ignored():
            pool.terminate()
            pool.join()
        raise
    pool.join()
    return out


@contextlib.contextmanager
def sigint_ignored() -> Iterator[None]:
    """Run the block with Ctrl-C ignored (a teardown a second Ctrl-C must not cut
    short); outside the main thread, where signals are not ours, it does nothing."""
    try:
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:                  # not the main thread: signals are not ours
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
