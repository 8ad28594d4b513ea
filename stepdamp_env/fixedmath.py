"""Fixed-order floating point: the same bits on every x86-64 CPU.

What a CPU-dispatched library computes depends on the CPU it runs on: glibc's
``exp``, ``log``, ``sin``, ``cos``, ``atan``, ``pow`` and ``tanh`` have variants
with fused multiply-adds that it picks on CPUs with FMA (about one result in
1,500 differs in its last bit from the plain variant a CPU without FMA gets);
OpenBLAS and LAPACK pick kernels per core type and thread count; numpy's loops
per instruction set; torch's per instruction set; LLVM fuses a*b + c into one
FMA where the CPU has it and contraction is allowed. Every number the
benchmark scores is computed through this module instead: only +, -, *, / and
sqrt (exactly rounded by IEEE 754), in a fixed order, compiled by numba without
fastmath, so the result depends on the inputs alone.

The elementary functions are the classic fdlibm algorithms (argument reduction,
then a fixed polynomial), within about one ulp of the exact result; they are
tested against the C library to a few ulp and for identity across emulated
CPUs (``tests/test_fixedmath.py``, ``tests/test_cpu_determinism.py``). The
learned policies' networks, in the same arithmetic: :mod:`.fixednet`.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic


__all__ = ["exp", "expm1", "log", "sin", "cos", "sincos", "sincos_shifted", "sincos_rotated",
           "sincos_lane", "log_lane", "sincos_in", "sincos_shifted_in", "log_in", "float_bits", "bits_float", "atan", "atan2", "hypot", "tanh", "cexp", "cmul", "exp_array",
           "sincos_array", "dot", "weighted_rows", "lstsq", "solve", "random_walk_kalman_update"]

# numba without fastmath: no reassociation, no contraction into FMA.
_jit = njit(cache=True, error_model="numpy")
_inline = njit(cache=True, error_model="numpy", inline="always")

# --- exp, expm1, log (fdlibm e_exp.c, e_log.c) --------------------------------
_LN2_HI = 6.93147180369123816490e-01     # trailing zeros: k*_LN2_HI is exact
_LN2_LO = 1.90821492927058770002e-10
_INV_LN2 = 1.44269504088896338700e+00
_P1, _P2 = 1.66666666666666019037e-01, -2.77777777770155933842e-03
_P3, _P4 = 6.61375632143793436117e-05, -1.65339022054652515390e-06
_P5 = 4.13813679705723846039e-08
_EXP_MAX = 7.09782712893383973096e+02
_EXP_MIN = -7.45133219101941108420e+02
_LG1, _LG2 = 6.666666666666735130e-01, 3.999999999940941908e-01
_LG3, _LG4 = 2.857142874366239149e-01, 2.222219843214978396e-01
_LG5, _LG6 = 1.818357216161805012e-01, 1.531383769920937332e-01
_LG7 = 1.479819860511658591e-01
_SQRT_HALF = 0.70710678118654752440


@_inline
def exp(x):
    """e**x."""
    if x != x:
        return x
    if x > _EXP_MAX:
        return math.inf
    if x < _EXP_MIN:
        return 0.0
    k = math.floor(x * _INV_LN2 + 0.5)
    hi = x - k * _LN2_HI
    lo = k * _LN2_LO
    r = hi - lo
    t = r * r
    c = r - t * (_P1 + t * (_P2 + t * (_P3 + t * (_P4 + t * _P5))))
    if k == 0.0:
        return 1.0 - ((r * c) / (c - 2.0) - r)
    y = 1.0 - ((lo - (r * c) / (2.0 - c)) - hi)
    return math.ldexp(y, int(k))


@_inline
def expm1(x):
    """e**x - 1, accurate near 0 (a Taylor series below 1/2, where exp(x) - 1 would
    cancel)."""
    if not abs(x) < 0.5:
        return exp(x) - 1.0
    # x (1 + x/2 (1 + x/3 (1 + ... x/17))): terms below 1e-19 relative are left out.
    s = 1.0
    for n in range(17, 1, -1):
        s = 1.0 + x / n * s
    return x * s


@_inline
def log(x):
    """Natural logarithm (NaN below 0, -inf at 0)."""
    if x != x or x == math.inf:
        return x
    if x < 0.0:
        return math.nan
    if x == 0.0:
        return -math.inf
    m, e = math.frexp(x)                 # x = m 2**e, m in [0.5, 1)
    if m < _SQRT_HALF:
        m = 2.0 * m
        e -= 1
    return _log_reduced(m, e)


@_inline
def _log_reduced(m, e):
    """log(m 2**e) for m in [sqrt(1/2), sqrt(2)): fdlibm's polynomial."""
    f = m - 1.0
    k = float(e)
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    t1 = w * (_LG2 + w * (_LG4 + w * _LG6))
    t2 = z * (_LG1 + w * (_LG3 + w * (_LG5 + w * _LG7)))
    r = t2 + t1
    hfsq = 0.5 * f * f
    return k * _LN2_HI - ((hfsq - (s * (hfsq + r) + k * _LN2_LO)) - f)


@intrinsic
def float_bits(typingctx, x):
    """The IEEE 754 bits of a float64, as a uint64 (a bit cast; no call, so it vectorises)."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))
    return types.uint64(types.float64), codegen


@intrinsic
def bits_float(typingctx, b):
    """The float64 whose IEEE 754 bits are the uint64 ``b``."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())
    return types.float64(types.uint64), codegen


_MANTISSA = np.uint64(0x000FFFFFFFFFFFFF)
_HALF_EXPONENT = np.uint64(1022 << 52)          # the exponent field of [0.5, 1)


@_inline
def log_lane(x):
    """:func:`log` without branches or calls, for positive normal finite x: the
    same bits there. ``frexp`` is read from the bits of x (numba calls the C
    library's), so a loop over lanes of it vectorises."""
    b = float_bits(x)
    e = np.int64(b >> np.uint64(52)) - 1022
    m = bits_float((b & _MANTISSA) | _HALF_EXPONENT)
    small = m < _SQRT_HALF
    m = 2.0 * m if small else m
    e = e - 1 if small else e
    return _log_reduced(m, e)


# --- sin, cos (Cody-Waite reduction to [-pi/4, pi/4], Taylor polynomials) ----
_TWO_OVER_PI = 0.63661977236758134308
# fdlibm's pio2_1, pio2_2 (33 bits each: k * them is exact for |k| < 2**20) and
# pio2_2t, the rest of pi/2 after them. (Up to 0.9.0 the kernel took pio2_1t, the
# rest after pio2_1 alone, for the middle part, counting the last part twice.)
_PIO2_HI = 1.57079632673412561417e+00
_PIO2_MID = 6.07710050630396597660e-11
_PIO2_LO = 2.02226624879595063154e-21
_TWO_PI = 6.283185307179586
_S3, _S5, _S7, _S9 = -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0, 1.0 / 362880.0
_S11, _S13, _S15 = -1.0 / 39916800.0, 1.0 / 6227020800.0, -1.0 / 1307674368000.0
_C2, _C4, _C6, _C8 = -0.5, 1.0 / 24.0, -1.0 / 720.0, 1.0 / 40320.0
_C10, _C12, _C14 = -1.0 / 3628800.0, 1.0 / 479001600.0, -1.0 / 87178291200.0
_C16 = 1.0 / 20922789888000.0


@_inline
def sincos(x):
    """(sin x, cos x) in one call, within a few ulp for |x| < 1e6; beyond, x is
    first reduced by an exact ``fmod(x, 2*pi_double)`` (deterministic, though no
    longer close to the exact sine of such a large x)."""
    if not abs(x) < 1e6:
        if x != x or abs(x) == math.inf:
            return math.nan, math.nan
        x = np.fmod(x, _TWO_PI)
    if x == 0.0:                         # sin(-0) = -0
        return x, 1.0
    k = math.floor(x * _TWO_OVER_PI + 0.5)
    sp, cp = _sincos_reduced(x, k)
    quadrant = int(k) & 3
    if quadrant == 0:
        return sp, cp
    if quadrant == 1:
        return cp, -sp
    if quadrant == 2:
        return -sp, -cp
    return -cp, sp


@_inline
def _sincos_reduced(x, k):
    """sin and cos of r = x - k pi/2 (|r| <= pi/4): Cody-Waite, then the polynomials."""
    r = ((x - k * _PIO2_HI) - k * _PIO2_MID) - k * _PIO2_LO
    r2 = r * r
    sp = r + r * r2 * (_S3 + r2 * (_S5 + r2 * (_S7 + r2 * (_S9 + r2 * (_S11 + r2 * (
        _S13 + r2 * _S15))))))
    cp = 1.0 + r2 * (_C2 + r2 * (_C4 + r2 * (_C6 + r2 * (_C8 + r2 * (_C10 + r2 * (
        _C12 + r2 * (_C14 + r2 * _C16)))))))
    return sp, cp


@_inline
def sincos_shifted(x0, s0, c0, delta):
    """sin and cos of x0 + delta given those of x0, to a few ulp.

    For the small shifts of the RK4 stages a rotation by delta with its
    sin/cos from Taylor series (truncation error below 3e-18 for |delta| <= 1/8)
    replaces two further reductions; larger shifts reduce x0 + delta.
    """
    if abs(delta) > 0.125:
        return sincos(x0 + delta)
    return sincos_rotated(s0, c0, delta)


@_inline
def sincos_rotated(s0, c0, delta):
    """sin and cos of x0 + delta from those of x0 (s0, c0), for |delta| <= 1/8:
    :func:`sincos_shifted` without its branch."""
    d2 = delta * delta
    d4 = d2 * d2
    d8 = d4 * d4
    # Estrin's scheme: the terms evaluate in parallel, shortening the chain.
    sd = delta * ((1.0 + _S3 * d2) + d4 * (_S5 + _S7 * d2) + d8 * _S9)
    cd = (1.0 + _C2 * d2) + d4 * (_C4 + _C6 * d2) + d8 * (_C8 + _C10 * d2)
    return s0 * cd + c0 * sd, c0 * cd - s0 * sd


@_inline
def sincos_lane(x):
    """:func:`sincos` without branches, for |x| < 1e6: the same bits there.

    The quadrant is chosen by selects and k stays a float, so a loop over
    lanes of it vectorises (:mod:`stepdamp_env.lanes`); beyond 1e6, or for a
    NaN, the caller must use :func:`sincos`.
    """
    k = np.floor(x * _TWO_OVER_PI + 0.5)
    sp, cp = _sincos_reduced(x, k)
    quadrant = k - 4.0 * np.floor(k * 0.25)
    s = sp if quadrant == 0.0 else (cp if quadrant == 1.0 else (-sp if quadrant == 2.0 else -cp))
    c = cp if quadrant == 0.0 else (-sp if quadrant == 1.0 else (-cp if quadrant == 2.0 else sp))
    # sin(-0) = -0: the polynomial gives it too, the select makes it plain.
    return (x if x == 0.0 else s), (1.0 if x == 0.0 else c)


@_inline
def sincos_in(x, lanes):
    """:func:`sincos`, or :func:`sincos_lane` where ``lanes`` is not None (code
    compiled for SIMD lanes: the choice is made when compiled)."""
    if lanes is None:
        return sincos(x)
    return sincos_lane(x)


@_inline
def sincos_shifted_in(x0, s0, c0, delta, lanes, wide):
    """:func:`sincos_shifted`, or where ``lanes`` is not None :func:`sincos_rotated`
    (``wide`` None: |delta| <= 1/8 only) or, ``wide`` not None, both it and
    :func:`sincos_lane` of x0 + delta with :func:`sincos_shifted`'s choice
    selected (its bits for |x0 + delta| < 1e6; the choices are made when compiled)."""
    if lanes is None:
        return sincos_shifted(x0, s0, c0, delta)
    if wide is None:
        return sincos_rotated(s0, c0, delta)
    s_near, c_near = sincos_rotated(s0, c0, delta)
    s_far, c_far = sincos_lane(x0 + delta)
    big = abs(delta) > 0.125
    return (s_far if big else s_near), (c_far if big else c_near)


@_inline
def log_in(x, lanes):
    """:func:`log`, or :func:`log_lane` where ``lanes`` is not None."""
    if lanes is None:
        return log(x)
    return log_lane(x)


@_inline
def sin(x):
    return sincos(x)[0]


@_inline
def cos(x):
    return sincos(x)[1]


# --- atan, atan2 (fdlibm s_atan.c, e_atan2.c) --------------------------------
_ATAN_HI = (4.63647609000806093515e-01, 7.85398163397448278999e-01,
            9.82793723247329054082e-01, 1.57079632679489655800e+00)
_ATAN_LO = (2.26987774529616870924e-17, 3.06161699786838301793e-17,
            1.39033110312309984516e-17, 6.12323399573676603587e-17)
_AT0, _AT1 = 3.33333333333329318027e-01, -1.99999999998764832476e-01
_AT2, _AT3 = 1.42857142725034663711e-01, -1.11111104054623557880e-01
_AT4, _AT5 = 9.09088713343650656196e-02, -7.69187620504482999495e-02
_AT6, _AT7 = 6.66107313738753120669e-02, -5.83357013379057348645e-02
_AT8, _AT9 = 4.97687799461593236017e-02, -3.65315727442169155270e-02
_AT10 = 1.62858201153657823623e-02
_PI = 3.1415926535897931160e+00
_PI_LO = 1.2246467991473531772e-16


@_inline
def atan(x):
    """Arc tangent (rad)."""
    if x != x:
        return x
    ax = abs(x)
    if ax >= 7.378697629483821e+19:                  # 2**66
        z = _ATAN_HI[3] + _ATAN_LO[3]
        return z if x > 0.0 else -z
    i = -1
    t = ax
    if ax < 0.4375:
        if ax < 7.450580596923828e-09:               # 2**-27
            return x
    elif ax < 1.1875:
        if ax < 0.6875:
            i, t = 0, (2.0 * ax - 1.0) / (2.0 + ax)
        else:
            i, t = 1, (ax - 1.0) / (ax + 1.0)
    elif ax < 2.4375:
        i, t = 2, (ax - 1.5) / (1.0 + 1.5 * ax)
    else:
        i, t = 3, -1.0 / ax
    z = t * t
    w = z * z
    s1 = z * (_AT0 + w * (_AT2 + w * (_AT4 + w * (_AT6 + w * (_AT8 + w * _AT10)))))
    s2 = w * (_AT1 + w * (_AT3 + w * (_AT5 + w * (_AT7 + w * _AT9))))
    if i < 0:
        r = t - t * (s1 + s2)
    else:
        r = _ATAN_HI[i] - ((t * (s1 + s2) - _ATAN_LO[i]) - t)
    return r if x >= 0.0 else -r


@_inline
def atan2(y, x):
    """The angle of (x, y) in (-pi, pi] (rad), with C's sign rules for zeros."""
    if x != x or y != y:
        return x + y
    if y == 0.0:
        if math.copysign(1.0, x) > 0.0:
            return y
        return math.copysign(_PI, y)
    if x == 0.0:
        return math.copysign(0.5 * _PI, y)
    if abs(x) == math.inf or abs(y) == math.inf:
        if abs(x) == math.inf and abs(y) == math.inf:
            z = 0.25 * _PI if x > 0.0 else 0.75 * _PI
        elif abs(x) == math.inf:
            z = 0.0 if x > 0.0 else _PI
        else:
            z = 0.5 * _PI
        return math.copysign(z, y)
    q = abs(y / x)
    if q > 1.152921504606847e+18:                    # 2**60: |y/x| huge
        z = 0.5 * _PI + 0.5 * _PI_LO
    elif x < 0.0 and q < 8.673617379884035e-19:      # 2**-60
        z = 0.0
    else:
        z = atan(q)
    if x > 0.0:
        return z if y > 0.0 else -z
    if y > 0.0:
        return _PI - (z - _PI_LO)
    return (z - _PI_LO) - _PI


@_inline
def hypot(x, y):
    """sqrt(x**2 + y**2), scaled where the squares would overflow or underflow."""
    ax, ay = abs(x), abs(y)
    if ax == math.inf or ay == math.inf:
        return math.inf
    a, b = (ax, ay) if ax >= ay else (ay, ax)
    if a == 0.0 or a != a or b != b:
        return a + b
    if 1e-150 < a < 1e150 and (b == 0.0 or b > 1e-150):
        return math.sqrt(a * a + b * b)
    r = b / a
    return a * math.sqrt(1.0 + r * r)


@_inline
def tanh(x):
    """Hyperbolic tangent (fdlibm's s_tanh.c)."""
    if x != x or x == 0.0:
        return x
    ax = abs(x)
    if ax >= 22.0:
        t = 1.0
    elif ax >= 1.0:
        t = 1.0 - 2.0 / (expm1(2.0 * ax) + 2.0)
    else:
        e = expm1(-2.0 * ax)
        t = -e / (e + 2.0)
    return math.copysign(t, x)


@_inline
def cexp(z):
    """e**z of a complex z."""
    s, c = sincos(z.imag)
    m = exp(z.real)
    return complex(m * c, m * s)


# --- arrays -----------------------------------------------------------------
def cmul(a, b):
    """a * b of complex arrays (broadcast) in real arithmetic: numpy's complex
    product fuses multiply-adds on CPUs with FMA and rounds twice on others."""
    a = np.asarray(a, dtype=complex)
    b = np.asarray(b, dtype=complex)
    out = np.empty(np.broadcast(a, b).shape, dtype=complex)
    out.real = a.real * b.real - a.imag * b.imag
    out.imag = a.real * b.imag + a.imag * b.real
    return out



@_jit
def exp_array(x):
    """:func:`exp` of each element (a new float64 array of x's shape)."""
    flat = np.ascontiguousarray(x).ravel()
    out = np.empty(flat.size)
    for i in range(flat.size):
        out[i] = exp(flat[i])
    return out.reshape(x.shape)


@_jit
def sincos_array(x):
    """(:func:`sin`, :func:`cos`) of each element (two arrays of x's shape)."""
    flat = np.ascontiguousarray(x).ravel()
    s = np.empty(flat.size)
    c = np.empty(flat.size)
    for i in range(flat.size):
        s[i], c[i] = sincos(flat[i])
    return s.reshape(x.shape), c.reshape(x.shape)


@_jit
def dot(x, w):
    """sum(x[i] * w[i]) in index order (1-D float64)."""
    s = 0.0
    for i in range(x.size):
        s += x[i] * w[i]
    return s


@_jit
def weighted_rows(a, w):
    """a @ w for a 2-D a and 1-D w, each row summed in index order."""
    out = np.empty(a.shape[0])
    for r in range(a.shape[0]):
        s = 0.0
        for i in range(a.shape[1]):
            s += a[r, i] * w[i]
        out[r] = s
    return out


# --- linear algebra ----------------------------------------------------------
@_inline
def _back_substitute(u, y, m):
    """x with u[:m, :m] x = y[:m] for an upper triangular u, sums in index order."""
    x = np.empty(m)
    for j in range(m - 1, -1, -1):
        s = y[j]
        for k in range(j + 1, m):
            s -= u[j, k] * x[k]
        x[j] = s / u[j, j]
    return x


@_jit
def lstsq(a, b):
    """The least-squares solution x of a x = b (a: n x m, n >= m, full column
    rank), by Householder QR with every sum in index order. NaNs if a is rank
    deficient to working precision."""
    n, m = a.shape
    r = np.ascontiguousarray(a).astype(np.float64).copy()
    y = np.ascontiguousarray(b).astype(np.float64).copy()
    v = np.empty(n)
    scale_ref = 0.0
    for j in range(m):
        for i in range(n):
            scale_ref = max(scale_ref, abs(r[i, j]))
    for j in range(m):
        # Householder vector of column j below the diagonal.
        norm2 = 0.0
        for i in range(j, n):
            norm2 += r[i, j] * r[i, j]
        norm = math.sqrt(norm2)
        if not norm > 1e-13 * scale_ref * math.sqrt(n):
            return np.full(m, np.nan)
        alpha = -norm if r[j, j] >= 0.0 else norm
        for i in range(j, n):
            v[i] = r[i, j]
        v[j] -= alpha
        vnorm2 = norm2 - r[j, j] * r[j, j] + v[j] * v[j]
        # Apply H = I - 2 v v' / (v'v) to the remaining columns and to y.
        for k in range(j, m):
            s = 0.0
            for i in range(j, n):
                s += v[i] * r[i, k]
            f = 2.0 * s / vnorm2
            for i in range(j, n):
                r[i, k] -= f * v[i]
        s = 0.0
        for i in range(j, n):
            s += v[i] * y[i]
        f = 2.0 * s / vnorm2
        for i in range(j, n):
            y[i] -= f * v[i]
    return _back_substitute(r, y, m)


@_jit
def solve(a, b):
    """x with a x = b for a square a (Gaussian elimination with partial pivoting,
    sums in index order); NaNs if a is singular."""
    n = a.shape[0]
    m = np.ascontiguousarray(a).astype(np.float64).copy()
    x = np.ascontiguousarray(b).astype(np.float64).copy()
    for j in range(n):
        p = j
        for i in range(j + 1, n):
            if abs(m[i, j]) > abs(m[p, j]):
                p = i
        if m[p, j] == 0.0:
            return np.full(n, np.nan)
        if p != j:
            for k in range(n):
                m[j, k], m[p, k] = m[p, k], m[j, k]
            x[j], x[p] = x[p], x[j]
        for i in range(j + 1, n):
            f = m[i, j] / m[j, j]
            for k in range(j, n):
                m[i, k] -= f * m[j, k]
            x[i] -= f * x[j]
    return _back_substitute(m, x, n)


@_jit
def random_walk_kalman_update(x, p, h, z, q, r):
    """One predict-and-update of a Kalman filter per row, in place: state
    x[i] (k) a random walk (F = I, Q = q*I), scalar measurement z[i] = h[i] . x[i]
    plus noise of variance r; P updated in Joseph form (filterpy's
    ``KalmanFilter.predict`` and ``update``, the sums in index order)."""
    n, k = x.shape
    ph = np.empty(k)
    gain = np.empty(k)
    m = np.empty((k, k))
    mp = np.empty((k, k))
    for row in range(n):
        for a in range(k):
            p[row, a, a] += q
        y = z[row]
        for a in range(k):
            y -= h[row, a] * x[row, a]
        s = r
        for a in range(k):
            acc = 0.0
            for b in range(k):
                acc += p[row, a, b] * h[row, b]
            ph[a] = acc
        for a in range(k):
            s += h[row, a] * ph[a]
        for a in range(k):
            gain[a] = ph[a] / s
            x[row, a] += gain[a] * y
        for a in range(k):                   # M = I - K h
            for b in range(k):
                m[a, b] = (1.0 if a == b else 0.0) - gain[a] * h[row, b]
        for a in range(k):                   # M P
            for b in range(k):
                acc = 0.0
                for c in range(k):
                    acc += m[a, c] * p[row, c, b]
                mp[a, b] = acc
        for a in range(k):                   # M P M' + K r K'
            for b in range(k):
                acc = 0.0
                for c in range(k):
                    acc += mp[a, c] * m[b, c]
                p[row, a, b] = acc + gain[a] * r * gain[b]
