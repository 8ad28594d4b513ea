"""A protocol's speed grids per motor, kept on disk: computed once on every core
(the same values on any number of workers), then read back by system, protocol
settings and code, checksummed as identifications are."""

from __future__ import annotations

import multiprocessing
from typing import Any, Sequence

from ..parallel import default_workers, pool_map
from ..params import SystemParams
from ..simulation import RunSettings, simulate
from .kept import KeptResults

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
    (:class:`.kept.KeptResults` "grids"), per system, protocol settings and code
    (:func:`.provenance.code_fingerprint`), as identifications are: the grids
    are deterministic, so a kept grid is the one it would compute. The key
    names the protocol's class; a class defined outside this package (its code
    is not in the fingerprint) is never cached."""
    kind = type(protocol)
    kept = KeptResults("grids") if kind.__module__.startswith(_PACKAGE + ".") else None
    keys: list[dict] = [{} for _ in systems]
    out: list[Grids | None] = [None] * len(systems)
    if kept is not None and systems:
        settings = {k: v for k, v in protocol.to_dict().items() if k != "splits"}
        for i, system in enumerate(systems):
            keys[i] = {"system": system.to_dict(), "protocol": settings,
                       "class": f"{kind.__module__}.{kind.__qualname__}"}
            out[i] = _grids_from_json(kept.get(keys[i]))
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
        if kept is not None:
            kept.put(keys[i], [[suite, list(speeds), list(labels)] for suite, speeds, labels in g])
    if any(g is None for g in out):
        raise RuntimeError("grids_cached: a motor's grids were neither kept nor computed")
    return [g for g in out if g is not None]
