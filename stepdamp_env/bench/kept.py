"""Results of an entry's deterministic preparation, kept on disk.

Some entries prepare before they run: ``calibrated-table`` calibrates its table
on a rig, ``plant-bound`` rehearses its laws on the true plant. What they find
is a pure function of what they read (the motor, the seed, the run's setting)
and of the code that finds it, so it is kept like identifications and grids
(docs/caches.md): keyed by that input, this package's code fingerprint and the
sources of the entry's own package, read at each use; checksummed. A kept
result is the one the entry would compute, so a board's numbers do not depend
on whether the cache was warm.

    kept = KeptResults("plant-bound", code_root=os.path.dirname(__file__))
    content = kept.get(key)          # None: not kept (or the cache is off)
    ...
    kept.put(key, content)           # JSON content
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from typing import Any

from ..io import cache_dir, read_checked_json, tree_digest, write_checked_json
from .provenance import code_fingerprint

__all__ = ["KeptResults", "key_text"]


def _plain(value: Any) -> Any:
    """A key's parts as JSON: parameters by ``to_dict``, other dataclasses by
    their fields, numpy numbers as Python's."""
    to_dict = getattr(value, "to_dict", None)
    if callable(to_dict):
        return to_dict()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
    item = getattr(value, "item", None)
    if callable(item):
        return item()
    raise TypeError(f"a kept result's key cannot hold {type(value).__name__}")


def key_text(key: Any) -> str:
    """The JSON text a key is hashed from (floats exact: Python writes the
    shortest text that reads back to the same double)."""
    return json.dumps(key, sort_keys=True, default=_plain)


class KeptResults:
    """One kind of kept result (a folder of :func:`..io.cache_dir`).

    Args:
        kind: the folder's name (``~/.cache/stepdamp/KIND``).
        code_root: the folder of the package whose code computes the results
            (its ``.py`` sources join the key); None: this package's alone.

        code: this package's :func:`.provenance.code_fingerprint`, if the caller
            read it already (a board reads it once per worker); None: read now.

    The code is read when this object is made: make one per preparation (a
    batch), not one per process.
    """

    def __init__(self, kind: str, code_root: str | None = None, code: str | None = None) -> None:
        self.where = cache_dir(kind)
        self.kind = kind
        self.code = ""
        if self.where is not None:
            extra = "" if code_root is None else tree_digest(code_root, (".py",))
            self.code = (code_fingerprint() if code is None else code) + extra

    def _path(self, key: Any) -> tuple[str, str] | None:
        if self.where is None:
            return None
        digest = hashlib.sha256((self.code + key_text(key)).encode()).hexdigest()
        return os.path.join(self.where, digest[:32] + ".json"), digest

    def get(self, key: Any) -> Any:
        """The content kept under ``key``, or None (not kept, unreadable: one line
        on stderr, or the cache is off)."""
        at = self._path(key)
        if at is None:
            return None
        return read_checked_json(at[0], at[1], f"{self.kind} cache entry")

    def put(self, key: Any, content: Any) -> None:
        """Keep ``content`` (JSON) under ``key``; a full or read-only cache keeps nothing."""
        at = self._path(key)
        if at is None:
            return
        try:
            write_checked_json(at[0], at[1], content)
        except OSError:
            pass
