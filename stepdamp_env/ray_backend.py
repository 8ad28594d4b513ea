"""Ray as the backend of ``leaderboard``, ``sweep`` and multi-seed ``train`` (extra ``[ray]``).

:func:`ray_map` gives a drop-in for :func:`stepdamp_env.parallel.pool_map` that
sends the jobs, in chunks, to the Ray cluster at ``address`` (a running cluster:
``"auto"`` or ``"HOST:PORT"``), or to a local Ray started on this machine's cores
and the loopback interface when ``address`` is None. Every job computes what it
computes locally (the runs are deterministic), so the numbers are those of the
local backend, provided the nodes share the driver's CPU instruction set (the
kernel is compiled on each host, with fused multiply-adds where the CPU has
them). The worker processes need this package installed (the same version) and
the files that commands name by path (``--motors``, models, ``--out`` of
``train``) at the same paths, e.g. on a shared file system; they run in the
driver's working directory when it exists on their machine. A local Ray gets
``workers`` CPUs.
"""

from __future__ import annotations

import os
import sys
import uuid
from typing import Any, Callable, Sequence

from .parallel import sigint_ignored
from .params import ParameterError

__all__ = ["ray_map", "BACKENDS", "backend_map", "BY_VALUE"]

BACKENDS = ("local", "ray")
# A module with this attribute set true is sent to Ray's workers by value (the
# registry marks the policy files it imports by path).
BY_VALUE = "__stepdamp_by_value__"

# Per worker process: the key of the initializer last run there.
_WORKER_KEY: dict[str, str] = {}


def _start(address: str | None, workers: int) -> Any:
    try:
        import ray
    except ImportError:
        raise ParameterError("--backend ray needs Ray: pip install 'stepdamp-env[ray]'") from None
    if address is not None:
        _check_reachable(address)
    if not ray.is_initialized():
        options: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                   "configure_logging": False}
        if address is None:
            ray.init(num_cpus=max(1, int(workers)), _node_ip_address="127.0.0.1",
                     object_store_memory=200 * 1024 ** 2, **options)
        else:
            try:
                ray.init(address=address, **options)
            except ConnectionError:
                raise ParameterError(f"--ray-address {address!r}: no running Ray cluster "
                                     "found (start one with `ray start --head`, or give "
                                     "its HOST:PORT)") from None
            except (ValueError, RuntimeError) as exc:
                raise ParameterError(f"--ray-address {address!r}: cannot connect "
                                     f"({type(exc).__name__}: {exc})") from None
    return ray


def _check_reachable(address: str) -> None:
    """A HOST:PORT that does not answer is a one-line error at once (Ray itself
    would keep retrying for minutes)."""
    import socket

    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not port.isdigit():
        return                          # "auto" and Ray's other forms: Ray decides
    try:
        with socket.create_connection((host, int(port)), timeout=5.0):
            pass
    except OSError as exc:
        raise ParameterError(f"--ray-address {address!r}: no Ray cluster answers there "
                             f"({exc.strerror or type(exc).__name__}); start one with "
                             "`ray start --head` or give its HOST:PORT") from None


def _run_chunk(fn: Callable[[Any], Any], init: tuple, jobs: Sequence[Any]) -> list[Any]:
    initializer, initargs, key, cwd = init
    if _WORKER_KEY.get("key") != key:
        if os.path.isdir(cwd):
            os.chdir(cwd)
        if initializer is not None:
            initializer(*initargs)
        _WORKER_KEY["key"] = key
    return [fn(job) for job in jobs]


def ray_map(address: str | None = None) -> Callable[..., list[Any]]:
    """A :func:`~stepdamp_env.parallel.pool_map` that runs on Ray (see the module docstring)."""

    def run(fn: Callable[[Any], Any], jobs: Sequence[Any], workers: int, *,
            initializer: Callable[..., None] | None = None, initargs: tuple = (),
            min_jobs: int = 2, max_chunk: int | None = None, bar: Any = None,
            on_result: Callable[[int, Any], None] | None = None) -> list[Any]:
        jobs = list(jobs)
        if not jobs:
            return []
        ray = _start(address, workers)
        # Policy files loaded by path (``file.py:attr``) are modules the workers
        # cannot import by name: they travel by value.
        for module in list(sys.modules.values()):
            if getattr(module, BY_VALUE, False):
                ray.cloudpickle.register_pickle_by_value(module)
        cpus = max(1, int(ray.cluster_resources().get("CPU", workers)))
        chunk = max(1, len(jobs) // (cpus * 8))
        if max_chunk is not None:
            chunk = min(chunk, max_chunk)
        init = ray.put((initializer, initargs, uuid.uuid4().hex, os.getcwd()))
        task = ray.remote(num_cpus=1, max_retries=0)(_run_chunk)
        starts = list(range(0, len(jobs), chunk))
        refs = [task.remote(fn, init, jobs[k:k + chunk]) for k in starts]
        first = dict(zip(refs, starts))
        pending = list(refs)
        try:
            while pending:
                ready, pending = ray.wait(pending, num_returns=1)
                part = ray.get(ready[0])
                if on_result is not None:       # here, in the driver, as chunks arrive
                    for j, result in enumerate(part):
                        on_result(first[ready[0]] + j, result)
                if bar is not None:
                    bar.update(len(part))
            out: list[Any] = []
            for part in ray.get(refs):
                out.extend(part)
            return out
        except BaseException as exc:
            for ref in pending:
                ray.cancel(ref, force=True)
            if isinstance(exc, KeyboardInterrupt):
                # Shut Ray down here, undisturbed by a second Ctrl-C: left to the
                # interpreter's exit it prints its own crash report.
                with sigint_ignored():
                    ray.shutdown()
            if isinstance(exc, ray.exceptions.RayTaskError) and exc.cause is not None:
                raise exc.cause from None       # the job's own error, as the local pool gives it
            if isinstance(exc, ray.exceptions.RayError):
                first = (str(exc).strip().splitlines() or [""])[0]
                raise ParameterError(f"--backend ray: {type(exc).__name__}: {first}") from None
            raise

    return run


def backend_map(backend: str, address: str | None) -> Callable[..., list[Any]] | None:
    """None for the local process pool, else :func:`ray_map` of ``address``."""
    if backend not in BACKENDS:
        raise ParameterError(f"--backend {backend!r} is not one of {list(BACKENDS)}")
    if backend == "local":
        if address is not None:
            raise ParameterError("--ray-address needs --backend ray")
        return None
    return ray_map(address)
