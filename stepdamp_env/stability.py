"""Stability of a system's sampled current loop and of its plant's integration.

:mod:`.params` validates every system it builds with these (its current loop's
pole radius), and :func:`.simulation.check_integrable` every run (the RK4 steps
its fastest plant mode needs): a training episode draws a new motor, so they
run once per episode. The eigenvalues (numpy, tens of microseconds a call)
decide; a closed-form certificate first accepts what is stable with a margin,
so the common case skips them. A certificate only accepts: whatever it cannot
settle goes to the eigenvalues, so every decision is the eigenvalues'
(tests/test_stability.py). The first half works on numbers, the second on a
:class:`~.params.SystemParams` (which re-exports it).
"""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING

import numpy as np

from . import fixedmath as fm

if TYPE_CHECKING:
    from .params import SystemParams

__all__ = ["RK4_STABLE_RADIUS", "delayed_loop_gain", "current_loop_poles", "loop_radius",
           "loop_surely_stable", "plant_rate", "plant_rate_bound", "current_loop_radius",
           "current_loop_terms", "fastest_plant_mode", "fastest_plant_mode_bound", "plant_terms",
           "required_substeps"]

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
    """The fastest |lambda| (rad/s) of the plant's Jacobians (:func:`fastest_plant_mode`)
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


# -- a system's (params.SystemParams) -------------------------------------------
def current_loop_radius(system: "SystemParams") -> float:
    """Largest pole radius of the sampled current loop (stable below 1).

    The winding over one PWM period dt (exact: i' = a*i + (1 - a)/R * v, a =
    exp(-R*dt/L)), the voltage computed from this period's sample applied in
    the next, and the PI integrator I' = I + Ki*dt*e: state (i, v, I),
    closed loop [[a, (1 - a)/R, 0], [-Kp, 0, 1], [-Ki*dt, 0, 1]].
    """
    return loop_radius(*current_loop_terms(system))


def current_loop_terms(system: "SystemParams") -> tuple[float, float, float, float]:
    """(a, b, kp, ki*dt) of a system's current loop (:func:`current_loop_radius`)."""
    m = system.motor
    dt = 1.0 / system.drive.pwm_hz
    x = m.R * dt / m.L
    a = fm.exp(-x)
    b = -fm.expm1(-x) / m.R if x > 0 else dt / m.L
    kp, ki = system.current_gains()
    return a, b, kp, ki * dt


def fastest_plant_mode(system: "SystemParams", speed_rps: float = 0.0) -> tuple[float, str]:
    """(|lambda| in rad/s, the fields that set it) of the plant's fastest mode,
    or of the windings' back-EMF rotation Nr*omega at ``speed_rps`` if faster
    (the stator-frame currents oscillate at it).

    The Jacobian of (theta, omega, ia, ib) (docs/model.md, "The plant"), written
    in currents along and across the rotor's electrical angle x: the current
    along x has the pole -R/L and feeds nothing back (so the speed, which only
    drives it, moves no eigenvalue); the current across x, omega and theta form
    [[0, 1, 0], [k/J, -D/J, Km/J], [0, -Km/L, -R/L]] with the stiffness k
    (N*m/rad) anywhere in +-Nr*(Km*holding_current + Kd1 + 2*Kd2 + 4*Kd4).
    """
    m = system.motor
    terms = plant_terms(system)
    k_max, rate = terms[0], plant_rate(*terms)
    parts = {"R, L": m.R / m.L, "D, J": m.D / m.J,
             "Km, holding_current, Kd1/2/4, J": math.sqrt(k_max / m.J),
             "Km, L, J": m.Km / math.sqrt(m.L * m.J)}
    rotation = 2.0 * math.pi * abs(speed_rps) * m.Nr
    if rotation > rate:
        return rotation, "the speed command with Nr"
    return rate, max(parts, key=parts.get)


def fastest_plant_mode_bound(system: "SystemParams", speed_rps: float = 0.0) -> float:
    """An upper bound (rad/s) of :func:`fastest_plant_mode`'s rate without its
    eigenvalues (:func:`plant_rate_bound`); inf where it has none."""
    return max(plant_rate_bound(*plant_terms(system)),
               2.0 * math.pi * abs(speed_rps) * system.motor.Nr)


def plant_terms(system: "SystemParams") -> tuple[float, float, float, float, float, float]:
    """(k_max, J, D, Km, L, R) of the plant's Jacobians (:func:`fastest_plant_mode`)."""
    m = system.motor
    k_max = m.Nr * (m.Km * system.drive.holding_current + m.Kd1 + 2 * m.Kd2 + 4 * m.Kd4)
    return k_max, m.J, m.D, m.Km, m.L, m.R


def required_substeps(system: "SystemParams", speed_rps: float = 0.0) -> int:
    """Fewest RK4 steps per PWM period that integrate the fastest plant mode stably,
    and the windings' back-EMF rotation Nr*omega at ``speed_rps``."""
    rate, _ = fastest_plant_mode(system, speed_rps)
    if not math.isfinite(rate):
        return 2 ** 62
    return max(1, math.ceil(rate / (RK4_STABLE_RADIUS * system.drive.pwm_hz) - 1e-12))
