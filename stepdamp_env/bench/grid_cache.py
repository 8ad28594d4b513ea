"""A protocol's speed grids per motor, kept on disk: computed once on every core
(the same values on any number of workers), then read back by system, protocol
settings and code, checksummed as identifications are."""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
from typing import Any, Sequence

from ..io import cache_dir, read_checked_json, write_checked_json
from ..parallel import default_workers, pool_map
from ..params import SystemParams
from ..simulation import RunSettings, simulate
from .provenance import code_fingerprint

__all__ = ["Grids", "grids_cached"]


_PACKAGE = __name__.split(".")[0]

Grids = tuple[tuple[str, tuple[float, ...], tuple[str, ...]], ...]


def _motor_grids(job: tuple[Any, SystemParams]) -> Grids:
    protocol, system = job
    return protocol.suite_grids(system)


def _grids_from_json(kept: Any) -> Grids | None:
    """A kept entry as grids, or None if it is not one (then computed again)."""
    try:
        out = tuple((str(suite), tuple(float(v) for v in speeds), tuple(str(x) for x in labels))
                    for suite, speeds, labels in kept)
    except (TypeError, ValueError):
        return None
    if not out or any(len(speeds) != len(labels) for _, speeds, labels in out):
        return None
    return out


def grids_cached(protocol: Any, systems: Sequence[SystemParams]) -> list[Grids]:
    """``protocol.suite_grids(system)`` of each system (``protocol``: any with
    ``suite_grids`` and ``to_dict``, v3's and later), those not kept on disk
    computed on every core (the same values on any number of workers) and kept
    (:func:`..io.cache_dir` "grids"), per system, protocol settings and code
    (:func:`.provenance.code_fingerprint`), as identifications are: the grids
    are deterministic, so a kept grid is the one it would compute. The key
    names the protocol's class; a class defined outside this package (its code
    is not in the fingerprint) is never cached."""
    kind = type(protocol)
    where = cache_dir("grids") if kind.__module__.startswith(_PACKAGE + ".") else None
    paths: list[str | None] = [None] * len(systems)
    keys: list[str] = [""] * len(systems)
    out: list[Grids | None] = [None] * len(systems)
    if where is not None and systems:
        settings = {k: v for k, v in protocol.to_dict().items() if k != "splits"}
        code = code_fingerprint()
        for i, system in enumerate(systems):
            key = json.dumps({"system": system.to_dict(), "protocol": settings, "code": code,
                              "class": f"{kind.__module__}.{kind.__qualname__}"},
                             sort_keys=True, default=str)
            keys[i] = hashlib.sha256(key.encode()).hexdigest()
            paths[i] = os.path.join(where, keys[i][:32] + ".json")
            out[i] = _grids_from_json(read_checked_json(paths[i], keys[i], "grid cache entry"))
    todo = [i for i, g in enumerate(out) if g is None]
    workers = 1 if multiprocessing.current_process().daemon else default_workers()
    workers = min(workers, len(todo))
    if workers > 1:                     # the compiled kernel loaded once, inherited by the fork
        simulate(systems[todo[0]], speed_rps=0.5,
                 settings=RunSettings(settle_s=0.0, window_s=0.001))
    done = pool_map(_motor_grids, [(protocol, systems[i]) for i in todo], max(workers, 1),
                    max_chunk=1)
    for i, g in zip(todo, done):
        out[i] = g
        if paths[i] is not None:
            try:
                write_checked_json(paths[i], keys[i], [[suite, list(speeds), list(labels)]
                                                       for suite, speeds, labels in g])
            except OSError:             # a full or read-only cache: computed anyway
                pass
    if any(g is None for g in out):
        raise RuntimeError("grids_cached: a motor's grids were neither kept nor computed")
    return [g for g in out if g is not None]
