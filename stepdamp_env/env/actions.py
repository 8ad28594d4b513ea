"""Action coercion and its one-line error, shared by the scalar and the vector env."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["as_action", "action_error"]


def action_error(action: Any, shape: tuple[int, ...]) -> ValueError:
    try:
        arr = np.asarray(action, dtype=np.float64)
        got = f"shape {arr.shape}"
        if arr.shape == shape:
            got += (", non-finite values" if not np.all(np.isfinite(arr))
                    else f", values in [{arr.min():.6g}, {arr.max():.6g}]")
    except (TypeError, ValueError):
        got = f"{type(action).__name__} {action!r}"
    return ValueError(f"action must be finite with shape {shape} and every entry in "
                      f"[-1, 1]; got {got}")


def as_action(action: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``action`` as a float array of ``shape`` (values are checked by the compiled step)."""
    if type(action) is np.ndarray and action.shape == shape and \
            (action.dtype == np.float32 or action.dtype == np.float64):
        return action
    try:
        arr = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError):
        raise action_error(action, shape) from None
    if arr.shape != shape:
        raise action_error(action, shape)
    return np.ascontiguousarray(arr)
