"""Stability of the sampled current loop and of the plant's integration, on numbers.

:mod:`.params` validates every system it builds with these, and
:func:`.simulation.check_integrable` every run: a training episode draws a new
motor, so they run once per episode. The eigenvalues (numpy, tens of
microseconds a call) decide; a closed-form certificate first accepts what is
stable with a margin, so the common case skips them. A certificate only
accepts: whatever it cannot settle goes to the eigenvalues, so every decision
is the eigenvalues' (tests/test_stability.py).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from . import fixedmath as fm

__all__ = ["RK4_STABLE_RADIUS", "delayed_loop_gain", "current_loop_poles", "loop_radius",
           "loop_surely_stable", "plant_rate", "plant_rate_bound"]

#: RK4's stability region holds the left half-disc |h*lambda| <= 2.5 (|R(z)| <= 0.873 there).
RK4_STABLE_RADIUS = 2.5

# The certificate's pole radius: within it the eigenvalues' rounding cannot reach 1.
_CERTAIN_RADIUS = 1.0 - 1e-6


def delayed_loop_gain(bandwidth_per_sample: float) -> float:
    """Loop gain g for which g/(z^2 - z + g) is -3 dB at ``bandwidth_per_sample``.

    The argument is the bandwidth over the sample rate (f_c/f_s). From
    |z^2 - z + g|^2 = 2 g^2 at z = exp(j*2*pi*f_c/f_s): with A = z^2 - z,
    g^2 - 2 Re(A) g - |A|^2 = 0.
    """
    theta = 2.0 * math.pi * bandwidth_per_sample
    a = complex(fm.cos(2 * theta), fm.sin(2 * theta)) - complex(fm.cos(theta),
                                                                    fm.sin(theta))
    # |A|^2 written out: abs() and ** go through the C library's hypot and pow.
    return a.real + math.sqrt(2.0 * a.real * a.real + a.imag * a.imag)


def current_loop_poles(a: float, b: float, kp: float, ki_dt: float) -> np.ndarray:
    """The closed sampled current loop's matrix, state (i, v, I):
    [[a, b, 0], [-kp, 0, 1], [-ki_dt, 0, 1]] (winding pole a, input gain b in A/V,
    the PI's kp in V/A and ki*dt in V/A)."""
    return np.array([[a, b, 0.0], [-kp, 0.0, 1.0], [-ki_dt, 0.0, 1.0]])


def loop_radius(a: float, b: float, kp: float, ki_dt: float) -> float:
    """Largest pole radius of :func:`current_loop_poles`'s matrix (inf if not finite)."""
    if not (math.isfinite(kp) and math.isfinite(ki_dt)):
        return math.inf
    with np.errstate(all="ignore"):
        poles = np.linalg.eigvals(current_loop_poles(a, b, kp, ki_dt))
    radius = float(np.max(np.abs(poles)))
    return radius if math.isfinite(radius) else math.inf


def loop_surely_stable(a: float, b: float, kp: float, ki_dt: float) -> bool:
    """True if every pole of the current loop lies within radius 1 - 1e-6 (Jury's
    test of the characteristic polynomial); False if it cannot tell.

    det(zI - M) = z^3 - (1 + a) z^2 + (a + b kp) z + b (ki_dt - kp). Scaled to
    the radius r (roots z/r): coefficients c2/r, c1/r^2, c0/r^3. A monic cubic
    z^3 + c2 z^2 + c1 z + c0 has every root inside the unit circle iff p(1) > 0,
    p(-1) < 0, |c0| < 1 and |c0^2 - 1| > |c0 c2 - c1|.
    """
    r = _CERTAIN_RADIUS
    c2 = -(1.0 + a) / r
    c1 = (a + b * kp) / (r * r)
    c0 = b * (ki_dt - kp) / (r * r * r)
    # NaN fails every comparison: not certain.
    return bool(1.0 + c2 + c1 + c0 > 0.0 and -1.0 + c2 - c1 + c0 < 0.0 and abs(c0) < 1.0
                and abs(c0 * c0 - 1.0) > abs(c0 * c2 - c1))


@functools.lru_cache(maxsize=4096)
def plant_rate(k_max: float, J: float, D: float, Km: float, L: float, R: float) -> float:
    """The fastest |lambda| (rad/s) of the plant's Jacobians (:func:`.params.fastest_plant_mode`)
    with the stiffness k at -k_max, 0 and k_max, at least R/L; kept per value set,
    as a board builds the same motor's run many times."""
    jac = np.zeros((3, 3, 3))
    jac[:, 0, 1] = 1.0
    jac[:, 1, 0] = np.array([-k_max, 0.0, k_max]) / J
    jac[:, 1, 1] = -D / J
    jac[:, 1, 2] = Km / J
    jac[:, 2, 1] = -Km / L
    jac[:, 2, 2] = -R / L
    with np.errstate(all="ignore"):
        return max(R / L, float(np.max(np.abs(np.linalg.eigvals(jac))))) \
            if np.all(np.isfinite(jac)) else math.inf


def plant_rate_bound(k_max: float, J: float, D: float, Km: float, L: float, R: float) -> float:
    """An upper bound of :func:`plant_rate` without eigenvalues (inf where it has none).

    Scaling the states (theta, omega/w, i*sqrt(L/J)/w) with w = sqrt(|k_max|/J)
    balances the Jacobian; its largest row sum bounds every eigenvalue:
    max(w + D/J + c, c + R/L) with c = Km/sqrt(J*L), for every |k| <= |k_max|.
    """
    w = math.sqrt(abs(k_max) / J)
    c = Km / math.sqrt(J * L)
    bound = max(w + D / J + c, c + R / L)
    return bound if w > 0.0 and math.isfinite(bound) else math.inf
