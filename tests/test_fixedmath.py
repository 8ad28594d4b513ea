"""fixedmath: the CPU-independent numerics agree with the C library, LAPACK, filterpy
and torch to a few units in the last place, and give the same bits whatever the
batch. (That they give the same bits on every CPU: tests/test_cpu_determinism.py.)"""

from __future__ import annotations

import math

import numpy as np
import pytest

from stepdamp_env import fixedmath as fm
from stepdamp_env import fixednet as fn


def _ulps(a, b) -> np.ndarray:
    a = np.asarray(a, dtype=float).view(np.int64)
    b = np.asarray(b, dtype=float).view(np.int64)
    a = np.where(a < 0, np.int64(-2 ** 63) - a, a)
    b = np.where(b < 0, np.int64(-2 ** 63) - b, b)
    return np.abs(a - b)


RNG = np.random.default_rng(7733051)


@pytest.mark.parametrize("name, ours, libm, xs, max_ulp", [
    ("exp", fm.exp, math.exp, RNG.uniform(-700, 700, 4000), 1),
    ("exp near 0", fm.exp, math.exp, RNG.uniform(-1, 1, 4000), 1),
    ("expm1", fm.expm1, math.expm1, RNG.uniform(-3, 3, 4000), 2),
    ("expm1 tiny", fm.expm1, math.expm1, RNG.uniform(-1e-7, 1e-7, 4000), 1),
    ("log", fm.log, math.log, np.exp(RNG.uniform(-700, 700, 4000)), 1),
    ("log near 1", fm.log, math.log, RNG.uniform(0.9, 1.1, 4000), 1),
    ("cos", fm.cos, math.cos, RNG.uniform(-10, 10, 4000), 1),
    ("sin", fm.sin, math.sin, RNG.uniform(-1.5, 1.5, 4000), 1),
    ("sin of large x", fm.sin, math.sin, RNG.uniform(-1e5, 1e5, 4000), 2),
    ("cos of large x", fm.cos, math.cos, RNG.uniform(-1e5, 1e5, 4000), 2),
    ("atan", fm.atan, math.atan, RNG.uniform(-50, 50, 4000) * RNG.uniform(0, 1, 4000) ** 4, 1),
    ("tanh", fm.tanh, math.tanh, RNG.uniform(-5, 5, 4000), 3),
])
def test_elementary_functions_are_within_a_few_ulp_of_libm(name, ours, libm, xs, max_ulp):
    got = [ours(float(x)) for x in xs]
    want = [libm(float(x)) for x in xs]
    assert _ulps(got, want).max() <= max_ulp, name


def test_sine_of_large_arguments_has_a_small_absolute_error():
    xs = RNG.uniform(-1e5, 1e5, 2000)
    assert max(abs(fm.sin(float(x)) - math.sin(x)) for x in xs) < 1e-11
    assert max(abs(fm.cos(float(x)) - math.cos(x)) for x in xs) < 1e-11
    # Beyond 1e6 rad: reduced exactly by fmod(x, 2*pi_double): deterministic, bounded.
    s, c = fm.sincos(3.0e9)
    assert abs(s * s + c * c - 1.0) < 1e-15


def test_atan2_hypot_and_cexp():
    ys, xs = RNG.normal(size=3000), RNG.normal(size=3000)
    assert _ulps([fm.atan2(float(y), float(x)) for y, x in zip(ys, xs)],
                 [math.atan2(y, x) for y, x in zip(ys, xs)]).max() <= 1
    assert _ulps([fm.hypot(float(y), float(x)) for y, x in zip(ys, xs)],
                 [math.hypot(y, x) for y, x in zip(ys, xs)]).max() <= 1
    for y, x in [(0.0, 1.0), (-0.0, 1.0), (0.0, -1.0), (-0.0, -1.0), (1.0, 0.0), (-1.0, 0.0),
                 (1.0, -0.0), (math.inf, 1.0), (1.0, -math.inf), (-1.0, math.inf)]:
        assert fm.atan2(y, x) == math.atan2(y, x) and \
            math.copysign(1, fm.atan2(y, x)) == math.copysign(1, math.atan2(y, x)), (y, x)
    assert fm.hypot(1e200, 1e200) == pytest.approx(math.hypot(1e200, 1e200), rel=1e-15)
    assert fm.hypot(3e-200, 4e-200) == pytest.approx(5e-200, rel=1e-15)
    z = complex(0.3, -2.1)
    assert abs(fm.cexp(z) - complex(np.exp(z))) < 1e-15


def test_special_values():
    assert fm.exp(0.0) == 1.0 and fm.exp(1000.0) == math.inf and fm.exp(-1000.0) == 0.0
    assert math.isnan(fm.exp(math.nan)) and math.isnan(fm.log(-1.0))
    assert fm.log(0.0) == -math.inf and fm.log(1.0) == 0.0 and fm.log(math.inf) == math.inf
    assert fm.log(5e-324) == math.log(5e-324)
    assert fm.expm1(0.0) == 0.0 and fm.tanh(30.0) == 1.0 and fm.tanh(-30.0) == -1.0
    assert all(math.isnan(v) for v in fm.sincos(math.nan))
    for f in (fm.sin, fm.tanh, fm.atan, fm.expm1):
        assert math.copysign(1.0, f(-0.0)) == -1.0, f


def test_least_squares_and_solve_agree_with_lapack():
    a = RNG.normal(size=(5000, 7))
    b = a @ RNG.normal(size=7) + 0.1 * RNG.normal(size=5000)
    x = fm.lstsq(a, b)
    ref = np.linalg.lstsq(a, b, rcond=None)[0]
    assert np.abs(x - ref).max() <= 1e-13 * np.abs(ref).max()
    rank_deficient = np.column_stack([a[:, 0], a[:, 0]])
    assert np.all(np.isnan(fm.lstsq(rank_deficient, b)))
    m = RNG.normal(size=(5, 5))
    v = RNG.normal(size=5)
    assert np.allclose(fm.solve(m, v), np.linalg.solve(m, v), rtol=1e-12, atol=1e-12)
    assert np.all(np.isnan(fm.solve(np.zeros((2, 2)), np.ones(2))))


def test_dot_and_weighted_rows_sum_in_index_order():
    x = RNG.normal(size=101)
    w = RNG.normal(size=101)
    s = 0.0
    for a, b in zip(x, w):
        s += a * b
    assert fm.dot(x, w) == s
    rows = RNG.normal(size=(7, 101))
    assert np.array_equal(fm.weighted_rows(rows, w), [fm.dot(r, w) for r in rows])


def test_random_walk_kalman_is_filterpys_recursion():
    from filterpy.kalman import KalmanFilter

    kf = KalmanFilter(dim_x=6, dim_z=1)
    kf.x = np.zeros((6, 1))
    kf.P = np.eye(6) * 4.0
    kf.Q = np.eye(6) * 1e-4
    kf.R = np.array([[0.09]])
    kf.F = np.eye(6)
    x, p = np.zeros((1, 6)), (np.eye(6) * 4.0)[None].copy()
    for _ in range(300):
        h = RNG.normal(size=(1, 6))
        z = float(RNG.normal())
        kf.predict()
        kf.update(np.array([[z]]), H=h)
        fm.random_walk_kalman_update(x, p, h, np.array([z]), 1e-4, 0.09)
    assert np.allclose(x[0], kf.x[:, 0], rtol=1e-10, atol=1e-12)
    assert np.allclose(p[0], kf.P, rtol=1e-10, atol=1e-14)


def test_servo_kalman_gains_are_filterpys():
    from stepdamp_env.estimators import kalman_velocity_filter, kalman_velocity_gains

    dt, count = 5e-5, 2 * math.pi / 4000
    for accel in (3e2, 1e4):
        k = kalman_velocity_gains(dt, count, accel)
        kf = kalman_velocity_filter(dt, count, accel)
        for _ in range(20000):
            kf.predict()
            kf.update(np.array([0.0]))
        assert np.allclose(k, kf.K[:, 0], rtol=1e-9)


def test_mlp_forward_is_the_network_and_independent_of_the_batch():
    sizes = np.array([5, 8, 8, 3])
    ws = [RNG.normal(size=(8, 5)), RNG.normal(size=(8, 8)), RNG.normal(size=(3, 8))]
    bs = [RNG.normal(size=8), RNG.normal(size=8), RNG.normal(size=3)]
    acts = np.array([fn.ACTIVATION.TANH, fn.ACTIVATION.RELU, fn.ACTIVATION.IDENTITY])
    x = RNG.normal(size=(9, 5)).astype(np.float32)
    got = fn.mlp_forward(x, np.concatenate([w.ravel() for w in ws]), np.concatenate(bs),
                         sizes, acts)
    h = np.tanh(x.astype(float) @ ws[0].T + bs[0])
    h = np.maximum(h @ ws[1].T + bs[1], 0.0)
    want = h @ ws[2].T + bs[2]
    assert np.allclose(got, want, rtol=1e-13, atol=1e-13)
    one = np.concatenate([fn.mlp_forward(x[k:k + 1], np.concatenate([w.ravel() for w in ws]),
                                         np.concatenate(bs), sizes, acts) for k in range(9)])
    assert np.array_equal(got, one)


def _mlp_row_by_row(x, weights, biases, sizes, acts):
    """mlp_forward's contract written plainly: one row at a time, each sum in
    input order from the bias (Python floats: no reassociation, no FMA)."""
    out = []
    for row in np.asarray(x, dtype=float):
        a = list(row)
        w_at = b_at = 0
        for layer, act in enumerate(acts):
            n_in, n_out = int(sizes[layer]), int(sizes[layer + 1])
            z = []
            for o in range(n_out):
                s = float(biases[b_at + o])
                for i in range(n_in):
                    s += float(weights[w_at + o * n_in + i]) * a[i]
                if act == fn.ACTIVATION.RELU:
                    s = s if s > 0.0 else 0.0
                elif act == fn.ACTIVATION.TANH:
                    s = fm.tanh(s)
                z.append(s)
            a = z
            w_at += n_in * n_out
            b_at += n_out
        out.append(a)
    return np.array(out)


@pytest.mark.parametrize("n", [1, 31, 32, 33, 103])      # mlp_forward computes 32 rows at a time
def test_mlp_forward_in_blocks_of_rows_has_each_rows_bits(n):
    # Widths that are not multiples of the four inputs per pass; a NaN row.
    rng = np.random.default_rng(n)
    sizes = np.array([7, 13, 6, 2])
    acts = np.array([fn.ACTIVATION.RELU, fn.ACTIVATION.TANH, fn.ACTIVATION.IDENTITY])
    weights = rng.normal(0.0, 1.0, 7 * 13 + 13 * 6 + 6 * 2)
    biases = rng.normal(0.0, 1.0, 13 + 6 + 2)
    x = rng.normal(0.0, 3.0, (n, 7)).astype(np.float32)
    x[n // 2, 3] = np.nan
    got = fn.mlp_forward(x, weights, biases, sizes, acts)
    assert np.array_equal(got.view(np.uint64), _mlp_row_by_row(x, weights, biases, sizes,
                                                               acts).view(np.uint64))


def test_lstm_step_is_the_lstm_cell_and_keeps_each_runs_memory():
    """Gates i, f, g, o in torch's order: c' = f c + i g, h' = o tanh(c'), against a
    numpy cell; the rows given move on, the others keep their memory."""
    rng = np.random.default_rng(5)
    d, hidden, runs = 3, 4, 3
    w_ih = rng.normal(0, 0.5, (4 * hidden, d))
    w_hh = rng.normal(0, 0.5, (4 * hidden, hidden))
    bias = rng.normal(0, 0.5, 4 * hidden)
    h, c = rng.normal(0, 0.5, (runs, hidden)), rng.normal(0, 0.5, (runs, hidden))
    x = rng.normal(0, 1.0, (2, d))
    rows = np.array([2, 0])
    want_h, want_c = h.copy(), c.copy()
    for k, r in enumerate(rows):
        z = w_ih @ x[k] + w_hh @ h[r] + bias
        i, f, g, o = (1 / (1 + np.exp(-z[:hidden])), 1 / (1 + np.exp(-z[hidden:2 * hidden])),
                      np.tanh(z[2 * hidden:3 * hidden]), 1 / (1 + np.exp(-z[3 * hidden:])))
        want_c[r] = f * c[r] + i * g
        want_h[r] = o * np.tanh(want_c[r])
    fn.lstm_step(x, rows, h, c, w_ih.ravel(), w_hh.ravel(), bias)
    assert np.allclose(h, want_h, rtol=1e-13, atol=1e-15)
    assert np.allclose(c, want_c, rtol=1e-13, atol=1e-15)
    assert np.array_equal(h[1], want_h[1]) and np.array_equal(c[1], want_c[1])
