"""Statistics of the leaderboard: interquartile mean, stratified (v0) and two-level
(v1) bootstrap intervals, probability of improvement, and ranks from paired
comparisons over motors (:func:`paired_ranks`)."""

from __future__ import annotations

import functools
import math
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from .. import fixedmath as fm

__all__ = ["iqm", "stratified_bootstrap_ci", "summary", "two_level_bootstrap",
           "probability_of_improvement", "cell_summary", "normal_quantile",
           "student_t_quantile", "widening_factor", "motor_mean_bootstrap",
           "median_difference", "rank_groups", "paired_difference", "paired_ranks"]


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
    return float(fm.dot(x, _iqm_weights(x.size)))


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
    stats = fm.weighted_rows(np.ascontiguousarray(sample), _iqm_weights(sample.shape[1]))
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


# ---------------------------------------------------------------------------
# stepdamp-bench v1: cells grouped by motor, motors grouped in strata.
# ---------------------------------------------------------------------------
def _cell_table(values: Sequence[float], motors: Sequence[Any]
                ) -> tuple[list[Any], np.ndarray, np.ndarray]:
    """(motor keys in sorted order, values padded to (motors, max cells), counts)."""
    x = np.asarray(values, dtype=float)
    keys = list(motors)
    if len(keys) != x.size:
        raise ValueError(f"motors has {len(keys)} labels for {x.size} values")
    groups: dict[Any, list[float]] = {}
    for k, v in zip(keys, x):
        groups.setdefault(k, []).append(float(v))
    order = sorted(groups, key=str)
    width = max((len(groups[k]) for k in order), default=0)
    table = np.full((len(order), width), np.nan)
    for i, k in enumerate(order):
        table[i, :len(groups[k])] = groups[k]
    return order, table, np.array([len(groups[k]) for k in order])


def _strata_groups(order: Sequence[Any], strata: Mapping[Any, Any] | None
                   ) -> tuple[tuple[int, ...], ...]:
    """The indices into ``order`` of each stratum's motors, strata in sorted order."""
    by: dict[Any, list[int]] = {}
    for i, k in enumerate(order):
        by.setdefault(None if strata is None else strata[k], []).append(i)
    return tuple(tuple(by[s]) for s in sorted(by, key=str))


def _draws_of_groups(groups: tuple[tuple[int, ...], ...], rng: np.random.Generator,
                     resamples: int) -> np.ndarray:
    cols = []
    for group in groups:
        idx = np.asarray(group)
        cols.append(idx[rng.integers(0, idx.size, size=(resamples, idx.size))])
    return np.concatenate(cols, axis=1)


def _motor_draws(order: Sequence[Any], strata: Mapping[Any, Any] | None,
                 rng: np.random.Generator, resamples: int) -> np.ndarray:
    """Level 1: (resamples, motors) indices, motors drawn with replacement within
    their stratum (each stratum keeps its size); strata in sorted order."""
    return _draws_of_groups(_strata_groups(order, strata), rng, resamples)


@functools.lru_cache(maxsize=16)
def _seeded_draws(groups: tuple[tuple[int, ...], ...], seed: int, resamples: int
                  ) -> np.ndarray:
    draws = _draws_of_groups(groups, np.random.default_rng(seed), resamples)
    draws.setflags(write=False)
    return draws


def _fresh_motor_draws(order: Sequence[Any], strata: Mapping[Any, Any] | None, seed: int,
                       resamples: int) -> np.ndarray:
    """:func:`_motor_draws` from a new generator of ``seed`` (read-only). Kept for
    an integer seed and count: a board compares every pair of a table's
    entries on the same motors, so it draws the same indices again and again."""
    if not (isinstance(seed, (int, np.integer)) and isinstance(resamples, (int, np.integer))):
        return _motor_draws(order, strata, np.random.default_rng(seed), resamples)
    return _seeded_draws(_strata_groups(order, strata), int(seed), int(resamples))


def _cell_draws(counts: np.ndarray, motor_idx: np.ndarray, rng: np.random.Generator
                ) -> np.ndarray:
    """Level 2: for every drawn motor, as many of its cells as it has, with
    replacement: (resamples, motors, max cells) column indices (padding repeats)."""
    width = int(counts.max())
    u = rng.random(size=motor_idx.shape + (width,))
    return np.floor(u * counts[motor_idx][..., None]).astype(int)


def two_level_bootstrap(values: Sequence[float], motors: Sequence[Any],
                        strata: Mapping[Any, Any] | None = None, *, resamples: int = 2000,
                        seed: int = 2000, confidence: float = 0.95) -> tuple[float, float]:
    """Percentile interval of the IQM under a two-level bootstrap.

    Level 1 draws motors with replacement, within their stratum (``strata``:
    motor -> stratum; one stratum if None); level 2 draws, for every drawn
    motor, as many of its cells (evaluation seed x training seed) as it has,
    with replacement. The IQM of each resample is over all the drawn cells.
    With one cell per motor it is the ordinary bootstrap over motors.
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence={confidence!r} is outside (0, 1)")
    order, table, counts = _cell_table(values, motors)
    if not order:
        return (math.nan, math.nan)
    rng = np.random.default_rng(seed)
    m_idx = _motor_draws(order, strata, rng, resamples)
    c_idx = _cell_draws(counts, m_idx, rng)
    drawn = table[m_idx[..., None], c_idx]                 # (R, M, W)
    valid = np.arange(table.shape[1])[None, None, :] < counts[m_idx][..., None]
    if np.all(counts == counts[0]):                         # equal cells: one sort
        sample = np.sort(drawn[valid].reshape(resamples, -1), axis=1)
        stats = fm.weighted_rows(np.ascontiguousarray(sample), _iqm_weights(sample.shape[1]))
    else:
        stats = np.array([iqm(drawn[r][valid[r]]) for r in range(resamples)])
    alpha = (1.0 - confidence) / 2.0
    low, high = np.quantile(stats, [alpha, 1.0 - alpha])
    return (float(low), float(high))


def _mann_whitney(x: np.ndarray, y: np.ndarray, nx: np.ndarray, ny: np.ndarray) -> np.ndarray:
    """P(a cell of x < a cell of y), ties half, over the valid cells of the last
    axis (x: (..., W) with nx valid; y likewise); NaN padding never counts."""
    vx = np.arange(x.shape[-1]) < nx[..., None]
    vy = np.arange(y.shape[-1]) < ny[..., None]
    a, b = x[..., :, None], y[..., None, :]
    score = (a < b) + 0.5 * (a == b)
    pair = vx[..., :, None] & vy[..., None, :]
    return (score * pair).sum(axis=(-2, -1)) / (nx * ny)


def probability_of_improvement(x: Sequence[float], x_motors: Sequence[Any],
                               y: Sequence[float], y_motors: Sequence[Any], *,
                               strata: Mapping[Any, Any] | None = None,
                               resamples: int = 2000, seed: int = 2000,
                               confidence: float = 0.95,
                               resample_motors: bool = True,
                               interval: bool = True) -> dict[str, Any]:
    """P(X improves on Y) with lower scores better, and its two-level interval.

    Per motor, the probability that a cell of X scores lower than a cell of Y
    (every pair of their cells, ties half: the Mann-Whitney statistic); the
    mean over the motors both have. rliable's probability of improvement with
    motors as tasks and cells as runs (for scores where lower is better). The
    interval draws the same motors for X and Y and their cells independently
    (``resample_motors=False``: cells only, motors fixed, as rliable's
    stratified bootstrap does). An entry against itself gives exactly 0.5.
    ``interval=False`` leaves the interval out (NaN): P alone, the same value.
    """
    ox, tx, cx = _cell_table(x, x_motors)
    oy, ty, cy = _cell_table(y, y_motors)
    common = sorted(set(ox) & set(oy), key=str)
    if not common:
        return {"p": math.nan, "ci95": [math.nan, math.nan], "motors": 0}
    ix = np.array([ox.index(k) for k in common])
    iy = np.array([oy.index(k) for k in common])
    tx, cx, ty, cy = tx[ix], cx[ix], ty[iy], cy[iy]
    p = float(_mann_whitney(tx, ty, cx, cy).mean())
    if not interval:
        return {"p": p, "ci95": [math.nan, math.nan], "motors": len(common)}
    rng = np.random.default_rng(seed)
    m_idx = _motor_draws(common, strata, rng, resamples) if resample_motors else \
        np.tile(np.arange(len(common)), (resamples, 1))
    dx = np.take_along_axis(tx[m_idx], _cell_draws(cx, m_idx, rng), axis=-1)
    dy = np.take_along_axis(ty[m_idx], _cell_draws(cy, m_idx, rng), axis=-1)
    stats = _mann_whitney(dx, dy, cx[m_idx], cy[m_idx]).mean(axis=1)
    alpha = (1.0 - confidence) / 2.0
    low, high = np.quantile(stats, [alpha, 1.0 - alpha])
    return {"p": p, "ci95": [float(low), float(high)], "motors": len(common)}


def cell_summary(values: Sequence[float], motors: Sequence[Any],
                 strata: Mapping[Any, Any] | None = None, *, resamples: int = 2000,
                 seed: int = 2000, confidence: float = 0.95) -> dict[str, Any]:
    """IQM over the finite cells, its two-level interval, the count of cells and motors."""
    x = np.asarray(values, dtype=float)
    keep = np.isfinite(x)
    ms = [k for k, ok in zip(motors, keep) if ok]
    low, high = two_level_bootstrap(x[keep], ms, strata, resamples=resamples, seed=seed,
                                    confidence=confidence)
    return {"iqm": iqm(x[keep]), "ci95": [low, high], "n": int(keep.sum()),
            "motors": len(set(ms))}


# ---------------------------------------------------------------------------
# stepdamp-bench v3: per-motor scores, a widened interval, effect sizes, rank groups.
# ---------------------------------------------------------------------------
def _normal_cdf(x: float) -> float:
    """Phi(x) by Simpson's rule on the density with fixed-order exp (the same bits
    on every CPU; accurate to about 1e-12 for |x| <= 8)."""
    n = 2000
    t = np.linspace(0.0, abs(x), n + 1)
    f = fm.exp_array(-0.5 * t * t)
    w = np.ones(n + 1)
    w[1:-1:2], w[2:-1:2] = 4.0, 2.0
    area = fm.dot(f, w) * (abs(x) / n) / 3.0 / math.sqrt(2.0 * math.pi)
    return 0.5 + area if x >= 0 else 0.5 - area


@functools.lru_cache(maxsize=64)       # a few (p) per board, each 80 bisection steps
def normal_quantile(p: float) -> float:
    """The standard normal quantile of ``p`` in (0, 1), by bisection on :func:`_normal_cdf`."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"p={p!r} is outside (0, 1)")
    lo, hi = -9.0, 9.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if _normal_cdf(mid) < p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


# Student's t at p = 0.975 for 1-6 degrees of freedom (where Cornish-Fisher errs
# by more than 1e-3), to four decimals.
_T975 = (12.7062, 4.3027, 3.1824, 2.7764, 2.5706, 2.4469)


def student_t_quantile(p: float, dof: int) -> float:
    """Student's t quantile. At p = 0.975 and dof <= 6 from a table; otherwise from
    the normal quantile by Cornish-Fisher, four terms. That is within 1e-3 of
    the exact value for dof >= 7, and less accurate below that at other p.
    Products only, no ``pow``: the same bits on every CPU."""
    if p == 0.975 and 1 <= dof <= len(_T975):
        return _T975[dof - 1]
    z = normal_quantile(p)
    v = float(dof)
    z2 = z * z
    z3, z5, z7 = z2 * z, z2 * z2 * z, z2 * z2 * z2 * z
    return (z + (z3 + z) / (4.0 * v) + (5.0 * z5 + 16.0 * z3 + 3.0 * z) / (96.0 * v * v)
            + (3.0 * z7 + 19.0 * z5 + 17.0 * z3 - 15.0 * z) / (384.0 * v * v * v))


@functools.lru_cache(maxsize=256)      # called for every row and pair of a board
def widening_factor(n: int, confidence: float) -> float:
    """How much a percentile interval of ``n`` units is widened about its estimate:
    sqrt(n/(n-1)) * t(n-1)/z, the small-sample correction of Hesterberg's expanded
    percentile interval. A plain percentile interval over 16 motors covers about
    93 % at 95 % nominal; widened, 95-96 % (tests/test_bench_v3.py simulates it)."""
    if n < 2:
        return 1.0
    p = 0.5 + confidence / 2.0
    return math.sqrt(n / (n - 1.0)) * student_t_quantile(p, n - 1) / normal_quantile(p)


def motor_mean_bootstrap(values: Sequence[float], motors: Sequence[Any],
                         strata: Mapping[Any, Any] | None = None, *, resamples: int = 2000,
                         seed: int = 2000, confidence: float = 0.95,
                         positive: bool = False) -> dict[str, Any]:
    """IQM over motors of each motor's mean cell, and its interval.

    A cell is one training seed's score on a motor (already averaged over speeds
    and evaluation seeds), so every motor weighs the same whatever the number of
    training seeds. The interval: level 1 draws motors within their stratum,
    level 2 each drawn motor's cells, both with replacement; the percentile
    interval of the resampled IQMs is widened about the estimate by
    :func:`widening_factor` of the number of motors (``positive``: a positive
    quantity such as a ratio, widened by that factor in the logarithm, so the
    interval stays above 0)."""
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence={confidence!r} is outside (0, 1)")
    x = np.asarray(values, dtype=float)
    keep = np.isfinite(x)
    ms = [k for k, ok in zip(motors, keep) if ok]
    order, table, counts = _cell_table(x[keep], ms)
    if not order:
        return {"iqm": math.nan, "ci": [math.nan, math.nan], "motors": 0}
    means = np.array([fm.dot(table[i, :counts[i]], np.ones(counts[i])) / counts[i]
                      for i in range(len(order))])
    est = iqm(means)
    rng = np.random.default_rng(seed)
    m_idx = _motor_draws(order, strata, rng, resamples)
    c_idx = _cell_draws(counts, m_idx, rng)
    drawn = table[m_idx[..., None], c_idx]                          # (R, M, W)
    valid = np.arange(table.shape[1])[None, None, :] < counts[m_idx][..., None]
    total = np.zeros(m_idx.shape)
    for w in range(table.shape[1]):            # in index order: the same bits everywhere
        total = total + np.where(valid[..., w], drawn[..., w], 0.0)
    drawn_means = total / counts[m_idx]
    sample = np.sort(drawn_means, axis=1)
    stats = fm.weighted_rows(np.ascontiguousarray(sample), _iqm_weights(sample.shape[1]))
    alpha = (1.0 - confidence) / 2.0
    low, high = (float(q) for q in np.quantile(stats, [alpha, 1.0 - alpha]))
    c = widening_factor(len(order), confidence)
    if positive and est > 0.0 and low > 0.0:
        ci = [est * fm.exp(c * fm.log(low / est)), est * fm.exp(c * fm.log(high / est))]
    else:
        ci = [est - c * (est - low), est + c * (high - est)]
    return {"iqm": est, "ci": ci, "motors": len(order)}


def median_difference(x: Mapping[Any, float], y: Mapping[Any, float],
                      strata: Mapping[Any, Any] | None = None, *, resamples: int = 2000,
                      seed: int = 2000, confidence: float = 0.95) -> dict[str, Any]:
    """Effect size of X over Y: the median over their common motors of x - y (per-motor
    scores), with a bootstrap interval over motors (within strata), widened as in
    :func:`motor_mean_bootstrap`."""
    common = sorted((k for k in set(x) & set(y)
                     if math.isfinite(x[k]) and math.isfinite(y[k])), key=str)
    if not common:
        return {"median": math.nan, "ci": [math.nan, math.nan], "motors": 0}
    d = np.array([x[k] - y[k] for k in common], dtype=float)
    est = float(np.median(d))
    m_idx = _fresh_motor_draws(common, strata, seed, resamples)
    stats = np.median(d[m_idx], axis=1)
    alpha = (1.0 - confidence) / 2.0
    low, high = (float(q) for q in np.quantile(stats, [alpha, 1.0 - alpha]))
    c = widening_factor(len(common), confidence)
    return {"median": est, "ci": [est - c * (est - low), est + c * (high - est)],
            "motors": len(common)}


def rank_groups(estimates: Sequence[float], intervals: Sequence[Sequence[float]]
                ) -> list[int | None]:
    """Ranks where higher is better and overlapping intervals share: an entry's rank
    is 1 + the number of entries whose interval lies wholly above its own. An
    entry without a finite estimate and interval gets no rank (None)."""
    def finite(k: int) -> bool:
        return all(math.isfinite(v) for v in (estimates[k], *intervals[k]))

    out: list[int | None] = []
    for k, lo_hi in enumerate(intervals):
        out.append(1 + sum(1 for j, other in enumerate(intervals)
                           if finite(j) and other[0] > lo_hi[1]) if finite(k) else None)
    return out


def paired_difference(x: Mapping[Any, float], y: Mapping[Any, float],
                      strata: Mapping[Any, Any] | None = None, *, resamples: int = 2000,
                      seed: int = 2000, confidence: float = 0.95,
                      interval: bool = True) -> dict[str, Any]:
    """X against Y paired by motor (per-motor scores, higher better), on the motors
    both have a finite score for: the IQM over motors of x - y, the lower end
    of its two-sided ``confidence`` interval (motors drawn within their strata,
    widened as in :func:`motor_mean_bootstrap`; so two entries are told apart,
    in either direction, at level 1 - ``confidence``), and the share of motors
    where X scores higher (ties half; with one cell per motor, rliable's
    probability that X improves on Y). ``interval=False`` leaves the bootstrap
    out (``low`` NaN): the other values are the same."""
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence={confidence!r} is outside (0, 1)")
    common = sorted((k for k in set(x) & set(y)
                     if math.isfinite(x[k]) and math.isfinite(y[k])), key=str)
    if not common:
        return {"iqm": math.nan, "low": math.nan, "share": math.nan, "motors": 0}
    d = np.array([x[k] - y[k] for k in common], dtype=float)
    share = float(((d > 0).sum() + 0.5 * (d == 0).sum()) / d.size)
    est = iqm(d)
    if not interval:
        return {"iqm": est, "low": math.nan, "share": share, "motors": len(common)}
    m_idx = _fresh_motor_draws(common, strata, seed, resamples)
    sample = np.sort(d[m_idx], axis=1)
    stats = fm.weighted_rows(np.ascontiguousarray(sample), _iqm_weights(sample.shape[1]))
    q = float(np.quantile(stats, (1.0 - confidence) / 2.0))
    low = est - widening_factor(len(common), confidence) * (est - q)
    return {"iqm": est, "low": low, "share": share, "motors": len(common)}


def paired_ranks(estimates: Mapping[Any, float], per_motor: Mapping[Any, Mapping[Any, float]],
                 strata: Mapping[Any, Any] | None = None, *, confidence: float = 0.95,
                 decisive_share: float = 0.95, min_motors: int = 3, resamples: int = 2000,
                 seed: int = 2000, probability: Mapping[tuple[Any, Any], float] | None = None
                 ) -> dict[Any, int | None]:
    """Ranks (1 best, higher scores better) from paired comparisons over motors.

    Entry J beats entry K when, on their common motors (at least ``min_motors``),
    the IQM of J's per-motor score minus K's is above 0 and either its lower
    bound (:func:`paired_difference` at ``confidence``) is above 0 or J scores
    higher on at least ``decisive_share`` of the motors, or ``probability[(J,
    K)]`` (a board's P(J improves on K), if given) is at least
    ``decisive_share``. An entry's rank is 1 +
    the number of entries that beat it; ranks are then made monotone in
    ``estimates`` (the entries in decreasing order of their estimate; an entry
    never ranks above one with a higher estimate) and shifted so that the first
    is 1. So an entry shares rank 1 only if no entry beats it, the leader
    included, and a higher estimate never has a worse rank. An entry without a
    finite estimate gets None."""
    names = sorted((k for k in estimates if math.isfinite(estimates[k])),
                   key=lambda k: (-estimates[k], str(k)))

    def beats(j: Any, k: Any) -> bool:
        x, y = per_motor.get(j, {}), per_motor.get(k, {})
        stats = dict(resamples=resamples, seed=seed, confidence=confidence)
        t = paired_difference(x, y, strata, interval=False, **stats)
        if t["motors"] < min_motors:
            return False
        if (probability or {}).get((j, k), math.nan) >= decisive_share:
            return True
        if not t["iqm"] > 0.0:
            return False
        # The bootstrap only where the share does not decide.
        return t["share"] >= decisive_share or \
            paired_difference(x, y, strata, **stats)["low"] > 0.0

    raw = {k: 1 + sum(beats(j, k) for j in names if j != k) for k in names}
    out: dict[Any, int | None] = {k: None for k in estimates}
    best = 0
    for k in names:
        best = max(best, raw[k])
        out[k] = best
    if names:
        first = out[names[0]]
        for k in names:
            out[k] = int(out[k]) - int(first) + 1
    return out
