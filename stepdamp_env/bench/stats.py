"""Statistics of the leaderboard: interquartile mean and its stratified bootstrap interval."""

from __future__ import annotations

import math
from typing import Any, Iterable, Sequence

import numpy as np

__all__ = ["iqm", "stratified_bootstrap_ci", "summary"]


def _iqm_weights(n: int) -> np.ndarray:
    """Weights of the sorted samples: each covers [i/n, (i+1)/n] of the
    distribution; its weight is its overlap with [0.25, 0.75], over 0.5."""
    edges = np.arange(n + 1) / n
    overlap = np.clip(np.minimum(edges[1:], 0.75) - np.maximum(edges[:-1], 0.25), 0.0, None)
    return overlap / 0.5


def iqm(values: Iterable[float]) -> float:
    """Interquartile mean: the mean of the middle 50 % (fractional at the quartiles)."""
    x = np.sort(np.asarray(list(values), dtype=float))
    if x.size == 0:
        return math.nan
    return float(x @ _iqm_weights(x.size))


def stratified_bootstrap_ci(values: Sequence[float], strata: Sequence[Any], *,
                            resamples: int = 2000, seed: int = 2000,
                            confidence: float = 0.95) -> tuple[float, float]:
    """Percentile interval of the IQM under a bootstrap that resamples within strata.

    Each resample draws, in every stratum, as many values as it holds, with
    replacement, from that stratum only; strata are visited in sorted order so
    the result does not depend on the input order of the strata.
    """
    x = np.asarray(values, dtype=float)
    keys = list(strata)
    if x.size == 0:
        return (math.nan, math.nan)
    if len(keys) != x.size:
        raise ValueError(f"strata has {len(keys)} labels for {x.size} values")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence={confidence!r} is outside (0, 1)")
    rng = np.random.default_rng(seed)
    groups = {}
    for i, k in enumerate(keys):
        groups.setdefault(k, []).append(i)
    parts = []
    for k in sorted(groups, key=str):
        idx = np.asarray(groups[k])
        parts.append(x[idx[rng.integers(0, idx.size, size=(resamples, idx.size))]])
    sample = np.sort(np.concatenate(parts, axis=1), axis=1)
    stats = sample @ _iqm_weights(sample.shape[1])
    alpha = (1.0 - confidence) / 2.0
    low, high = np.quantile(stats, [alpha, 1.0 - alpha])
    return (float(low), float(high))


def summary(values: Sequence[float], strata: Sequence[Any], *, resamples: int = 2000,
            seed: int = 2000, confidence: float = 0.95) -> dict[str, Any]:
    """IQM, its stratified bootstrap interval and the count of the finite values."""
    x = np.asarray(values, dtype=float)
    keep = np.isfinite(x)
    x, s = x[keep], [k for k, ok in zip(strata, keep) if ok]
    low, high = stratified_bootstrap_ci(x, s, resamples=resamples, seed=seed,
                                        confidence=confidence)
    return {"iqm": iqm(x), "ci95": [low, high], "n": int(x.size)}
