"""numba's inliner made to copy a callee's blocks with one memo: a compile-time
fix, the compiled code is the same.

At every call site of an ``inline="always"`` function (the kernel's pieces,
:mod:`.kernel`) numba copies the callee's IR block by block, each block with a
deep-copy memo of its own, so the callee's whole scope (every variable) is
copied once per block, and a nest of inlined functions multiplies that
(numba/numba#8989 and #9204; numba 0.68 still does it). Here the blocks of one
copy share one memo: one scope for all of them, as in the callee itself. The
kernels and SIMD lanes compiled in 150.5 s instead of 565.8 s on two processes
(AVX2 machine; ``benchmarks/bench_cold_start.py``, docs/performance.md).

:func:`apply` runs when the package is imported. It changes how numba copies
IR in this process, not what it compiles (``tests/test_numba_inline.py``
compiles a nest of inlined functions both ways and compares the instructions;
the fingerprint tests compare the bits). It applies
only where numba's inliner still has the shape it relies on; elsewhere it
leaves numba alone and the compile is only slower. ``STEPDAMP_NUMBA_INLINER=numba``
in the environment leaves numba's inliner as it is (``benchmarks/bench_cold_start.py``
compares the two).
"""

from __future__ import annotations

import copy
import functools
import os
import sys
import types
from typing import Any

__all__ = ["ENV", "CHOICES", "apply", "restore", "applied"]

# Inside an inlining (numba compiles under its global lock): the memo of the
# copy under way and the scope of the blocks it copies.
_current: dict[str, Any] = {"inside": False, "scope": None, "memo": {}}
_original: dict[str, Any] = {}


def _deepcopy(x: Any, memo: dict | None = None) -> Any:
    """copy.deepcopy, except that inside ``inline_ir`` the blocks of one callee
    (one scope), copied one after the other by its copy_ir, share a memo. A
    block seen again starts a new copy (the same IR copied twice), as does
    another scope."""
    from numba.core import ir

    if _current["inside"] and memo is None and isinstance(x, ir.Block):
        if _current["scope"] is not x.scope or id(x) in _current["memo"]:
            _current["scope"], _current["memo"] = x.scope, {}
        return copy.deepcopy(x, _current["memo"])
    return copy.deepcopy(x, memo)


def _fits(icc: types.ModuleType) -> bool:
    """numba's inliner as this relies on: ``InlineWorker.inline_ir`` copies with
    a nested ``copy_ir`` through the module's ``copy``."""
    inline_ir = getattr(getattr(icc, "InlineWorker", None), "inline_ir", None)
    consts = getattr(getattr(inline_ir, "__code__", None), "co_consts", ())
    return (getattr(icc, "copy", None) is copy
            and any(getattr(c, "co_name", "") == "copy_ir" for c in consts))


#: The environment variable and its values ("patched", the default, or "numba").
ENV = "STEPDAMP_NUMBA_INLINER"
CHOICES = ("patched", "numba")


def apply() -> bool:
    """Patch numba's inliner (idempotent) unless ``STEPDAMP_NUMBA_INLINER=numba``.
    Returns whether it is patched."""
    from numba.core import inline_closurecall as icc

    if _original:
        return True
    choice = os.environ.get(ENV, "") or CHOICES[0]
    if choice not in CHOICES:
        print(f"{ENV}: {choice!r} is not one of {', '.join(CHOICES)}; using {CHOICES[0]}",
              file=sys.stderr)
    if choice == "numba" or not _fits(icc):
        return False
    shim = types.ModuleType("copy")
    shim.__dict__.update(copy.__dict__)
    shim.deepcopy = _deepcopy
    inline_ir = icc.InlineWorker.inline_ir

    @functools.wraps(inline_ir)
    def fresh_memo_inline_ir(self, *args, **kwargs):
        # Each inlining copies from scratch: no object outlives it in the memo.
        outer = dict(_current)
        _current.update(inside=True, scope=None, memo={})
        try:
            return inline_ir(self, *args, **kwargs)
        finally:
            _current.update(outer)

    _original.update(copy=icc.copy, inline_ir=inline_ir)
    icc.copy = shim
    icc.InlineWorker.inline_ir = fresh_memo_inline_ir
    return True


def restore() -> None:
    """Undo :func:`apply` (the tests compare both)."""
    from numba.core import inline_closurecall as icc

    if _original:
        icc.copy = _original["copy"]
        icc.InlineWorker.inline_ir = _original["inline_ir"]
        _original.clear()


def applied() -> bool:
    """Whether numba's inliner is patched in this process."""
    return bool(_original)
