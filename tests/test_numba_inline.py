"""numba's inliner with one copy memo per callee (``stepdamp_env.numba_inline``):
applied on import, and the machine code it compiles is numba's own."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import numba
import numpy as np
import pytest

from stepdamp_env import numba_inline


@numba.njit(inline="always")
def _leaf(x, k):
    # Branches and a loop: a callee of several blocks.
    acc = 0.0
    for i in range(k):
        if x > i:
            acc += x * 0.5 - i
        else:
            acc -= x * 0.25
    return acc


@numba.njit(inline="always")
def _middle(x, k):
    # The same callee inlined twice in one function: the copies must not share objects.
    a = _leaf(x, k)
    b = _leaf(x + 1.0, k + 1)
    return a * b if a > b else a - b


def _outer(xs):
    out = np.empty_like(xs)
    for i in range(xs.size):
        out[i] = _middle(xs[i], 3) + _leaf(xs[i] * 2.0, 2)
    return out


def _machine_code(dispatcher, xs):
    dispatcher(xs)
    asm = "".join(dispatcher.inspect_asm().values())
    # The instructions alone (symbols and labels carry each compile's unique names).
    return [re.sub(r"[_.\w]*outer[\w.$]*", "F", line.split("#")[0].strip())
            for line in asm.splitlines() if line.startswith("\t") and not line.startswith("\t.")]


def test_the_package_patches_numbas_inliner():
    # Fails on a numba whose inliner changed shape: the kernels then compile unpatched (slower).
    import stepdamp_env  # noqa: F401 - applies it

    assert numba_inline.applied() == (os.environ.get(numba_inline.ENV) != "numba")


def test_the_environment_variable_leaves_numbas_inliner_or_names_its_values():
    code = "import stepdamp_env.numba_inline as n; print(n.applied())"
    for value, applied, said in (("numba", "False", ""), ("patched", "True", ""),
                                 ("fast", "True", "STEPDAMP_NUMBA_INLINER: 'fast' is not one of "
                                  "patched, numba; using patched")):
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             env={**os.environ, numba_inline.ENV: value}, check=True)
        assert out.stdout.strip() == applied
        assert (said in out.stderr) if said else (numba_inline.ENV not in out.stderr)


def _compiled(xs):
    """A fresh compile of _outer: its result, machine code and the number of
    numba IR variables deep-copied while compiling it."""
    from numba.core import ir

    copies = [0]
    var_copy = ir.Var.__deepcopy__

    def counted(self, memo):
        copies[0] += 1
        return var_copy(self, memo)

    ir.Var.__deepcopy__ = counted
    try:
        fn = numba.njit(_outer)
        return fn(xs), _machine_code(fn, xs), copies[0]
    finally:
        ir.Var.__deepcopy__ = var_copy


def test_the_patched_inliner_compiles_the_same_code_copying_less():
    if os.environ.get(numba_inline.ENV) == "numba":
        pytest.skip(f"{numba_inline.ENV}=numba: the patch is off")
    xs = np.random.default_rng(3).normal(size=64) * 4.0
    numba_inline.restore()
    try:
        want, want_code, want_copies = _compiled(xs)
    finally:
        assert numba_inline.apply()
    got, got_code, got_copies = _compiled(xs)
    assert np.array_equal(got.view(np.int64), want.view(np.int64))
    assert got_code == want_code
    assert len(got_code) > 50
    # The patch engaged: each variable copied once per inlining, not once per block.
    assert got_copies < want_copies / 2, (got_copies, want_copies)
