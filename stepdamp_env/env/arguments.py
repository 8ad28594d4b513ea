"""Checks of the arguments every StepperDamp env version takes alike (render mode,
vector size, autoreset, reset seeds), so that v0 and v1 refuse them in the same words."""

from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode

from ..params import ParameterError

__all__ = ["check_render_mode", "check_vector_args", "reseed", "check_batch_envs"]


def check_render_mode(render_mode: str | None, allowed: Sequence[str]) -> str | None:
    """``render_mode`` if None or one of ``allowed``, else a one-line error."""
    if render_mode is not None and render_mode not in allowed:
        raise ParameterError(f"render_mode={render_mode!r} is not one of "
                             f"{[None] + list(allowed)}")
    return render_mode


def check_vector_args(num_envs: Any, autoreset_mode: Any, render_mode: Any) -> AutoresetMode:
    """Check a native vector env's own arguments; returns the autoreset mode."""
    if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) \
            or not 1 <= num_envs <= 1_000_000:
        raise ParameterError(f"num_envs={num_envs!r} is outside its allowed range "
                             "[1, 1000000] (integer)")
    try:
        mode = AutoresetMode(autoreset_mode)
    except ValueError:
        raise ParameterError(f"autoreset_mode={autoreset_mode!r} is not one of "
                             f"{[m.value for m in AutoresetMode]}") from None
    if mode == AutoresetMode.DISABLED:
        raise ParameterError("autoreset_mode='Disabled' is not supported; allowed: "
                             "NextStep, SameStep")
    if render_mode is not None:
        raise ParameterError(f"render_mode={render_mode!r}: the vector environment does "
                             "not render; allowed: None (render a scalar env instead)")
    return mode


def check_num_threads(num_threads: Any) -> int:
    """Check a vector env's ``num_threads``: 1 up to numba's thread count (the cores,
    or ``NUMBA_NUM_THREADS``)."""
    import numba

    top = int(numba.config.NUMBA_NUM_THREADS)
    if isinstance(num_threads, bool) or not isinstance(num_threads, (int, np.integer)) \
            or not 1 <= num_threads <= top:
        raise ParameterError(f"num_threads={num_threads!r}: allowed are the integers in "
                             f"[1, {top}] ({top} = numba's threads, NUMBA_NUM_THREADS)")
    return int(num_threads)


def check_simd(simd: Any, num_envs: int) -> bool:
    """Check a vector env's ``simd``: True, False or None (``lanes.simd_by_default``)."""
    from ..lanes import LANES, simd_by_default

    if simd is None:
        return simd_by_default(num_envs)
    if not isinstance(simd, (bool, np.bool_)):
        raise ParameterError(f"simd={simd!r}: allowed are True, False and None (on from {LANES} "
                             "drives up on CPUs with AVX2)")
    return bool(simd)


def reseed(rngs: list[np.random.Generator | None], seed: Any, options: dict[str, Any] | None,
           first: bool) -> np.ndarray:
    """Seed the generators of a vector reset in place; returns the mask of drives to reset.

    Gymnasium's convention: an int seeds drive i with ``seed + i``, a list one seed per
    drive; None draws fresh entropy only where no generator exists yet (or on the
    ``first`` reset). ``options["reset_mask"]`` limits the reset to some drives.
    """
    n = len(rngs)
    if seed is None:
        seeds: list[int | None] = [None] * n
    elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
        seeds = [int(seed) + i for i in range(n)]
    else:
        seeds = list(seed)
        if len(seeds) != n:
            raise ParameterError(f"seed: a list of seeds must have num_envs={n} entries, "
                                 f"got {len(seeds)}")
    mask = np.ones(n, dtype=bool)
    if options and "reset_mask" in options:
        mask = np.asarray(options["reset_mask"], dtype=bool)
        if mask.shape != (n,):
            raise ParameterError(f"options['reset_mask'] must have shape ({n},), got "
                                 f"{mask.shape}")
    if seed is not None or first:
        for i, sd in enumerate(seeds):
            if mask[i] and (sd is not None or rngs[i] is None):
                rngs[i], _ = seeding.np_random(sd)
    return mask


def check_batch_envs(envs: Sequence[Any], layout_of: Callable[[Any], tuple], kind: str) -> None:
    """Envs stepped together: at least one, each reset with ``measure_from_s`` set, all
    of one layout (``layout_of``); else a ValueError naming ``kind``."""
    if not envs:
        raise ValueError(f"{kind} needs at least one env")
    layout = layout_of(envs[0])
    for env in envs:
        if env.system is None or env.options.measure_from_s is None:
            raise ValueError(f"{kind} needs envs reset with measure_from_s set")
        if layout_of(env) != layout:
            raise ValueError(f"{kind} needs envs of one layout (action mode, agent rate, "
                             "observation)")
