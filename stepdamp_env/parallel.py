"""One process pool for every batch of independent runs (sweeps, leaderboards)."""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import multiprocessing
import os
import signal
import sys
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Callable, Iterator, Sequence

from .interrupts import signals_deferred

__all__ = ["default_workers", "pool_map", "sigint_ignored", "WorkerLostError"]


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


class WorkerLostError(RuntimeError):
    """A worker process of :func:`pool_map` died (killed, out of memory): the map
    ends at once instead of waiting for its lost jobs."""


def _run_chunk(fn: Callable[[Any], Any], chunk: Sequence[Any]) -> list[Any]:
    return [fn(job) for job in chunk]


def pool_map(fn: Callable[[Any], Any], jobs: Sequence[Any], workers: int, *,
             initializer: Callable[..., None] | None = None, initargs: tuple = (),
             min_jobs: int = 2, max_chunk: int | None = None, bar: Any = None,
             on_result: Callable[[int, Any], None] | None = None) -> list[Any]:
    """``[fn(job) for job in jobs]``, in order, in this process or on ``workers`` processes.

    Runs serially (after calling ``initializer(*initargs)`` here) when
    ``workers <= 1`` or there are fewer than ``min_jobs`` jobs. Workers are
    forked where the platform can, so they inherit what the parent loaded
    (compiled kernels, models). ``bar`` (a tqdm bar) is advanced per result;
    ``on_result(i, result)`` is called here as each result arrives (job ``i``;
    in order when serial, as chunks finish on workers). Workers end with the
    parent: on any exception here (Ctrl-C included) they are killed, and on
    Linux a worker is killed when its parent dies. A worker that dies ends the
    map within a moment with :class:`WorkerLostError` (the results handed to
    ``on_result`` so far stand).
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
    before = {p.pid for p in multiprocessing.active_children()}
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context(method),
                               initializer=_worker_start,
                               initargs=(os.getpid(), initializer, initargs))
    parts: dict[int, list[Any]] = {}
    try:
        # The first submit forks the workers: a signal handled there would be lost.
        with signals_deferred():
            first = {pool.submit(_run_chunk, fn, jobs[k:k + chunk]): k
                     for k in range(0, len(jobs), chunk)}
        pending = set(first)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in sorted(done, key=first.__getitem__):
                k = first[future]
                parts[k] = future.result()
                for j, result in enumerate(parts[k]):
                    if on_result is not None:
                        on_result(k + j, result)
                    if bar is not None:
                        bar.update()
    except BaseException as exc:
        # A second Ctrl-C inside the teardown would leave live workers behind.
        with sigint_ignored():
            for child in multiprocessing.active_children():
                if child.pid not in before:
                    child.kill()
            pool.shutdown(wait=True, cancel_futures=True)
        if isinstance(exc, BrokenProcessPool):
            raise WorkerLostError(
                f"a worker process died (killed, or out of memory) after {len(parts)} of "
                f"{-(-len(jobs) // chunk)} chunks of work; run the command again (a "
                "leaderboard resumes from its finished batches)") from None
        raise
    pool.shutdown(wait=True)
    for k in sorted(parts):
        out.extend(parts[k])
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
