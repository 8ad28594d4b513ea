"""The uncertainty of a detent model identified from drive logs
(:mod:`.logfit`; docs/drivelogs.md, "Uncertainty"): least-squares covariances
in fixed-order arithmetic (the same bits on any CPU), their propagation to the
detent's amplitudes and phases, and the warnings about what the logs cannot
say."""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from . import fixedmath as fm
from .params import FeedforwardModel, SystemParams

__all__ = ["AMPLITUDES", "J_DISAGREES", "MAX_UNCERTAINTY", "PHASES", "PRIOR_J_UNCERTAINTY",
           "balance_uncertainty", "coefficient_uncertainty", "covariance", "gram", "inverse",
           "is_servo_log", "judgements", "noise_inflation", "quadratic", "root",
           "servo_logs_warning", "wrap"]


#: A detent amplitude (Kd1, Kd2, Kd4) whose stated uncertainty exceeds this
#: fraction of its value is warned of.
MAX_UNCERTAINTY = 0.05


#: Relative uncertainty assumed for the prior's J where the logs do not give J
#: (a datasheet's rotor inertia, a load's often only guessed): it enters the
#: harmonics' uncertainty through their sensitivity to J.
PRIOR_J_UNCERTAINTY = 0.5


#: The logs' J and the prior's disagree (a note) beyond this ratio (either way) and
#: three uncertainties.
J_DISAGREES = 0.2


#: The detent amplitudes and phases, in the order of their coefficients.
AMPLITUDES = ("Kd1", "Kd2", "Kd4")
PHASES = ("phi1", "phi2")



def gram(a: np.ndarray) -> np.ndarray:
    """a'a with every sum in row order (no BLAS: the same bits on any CPU)."""
    cols = [np.ascontiguousarray(a[:, i]) for i in range(a.shape[1])]
    g = np.empty((len(cols), len(cols)))
    for i, ci in enumerate(cols):
        for j in range(i, len(cols)):
            g[i, j] = g[j, i] = fm.dot(ci, cols[j])
    return g


def noise_inflation(width: int) -> float:
    """How much the fit's low-pass inflates a least-squares variance computed as
    if its output samples were independent: (sum h)^2 / sum h^2 for its kernel h
    (four ``width``-sample moving means), the factor for white noise before the
    low-pass. It is exact for the constant column and conservative for the
    harmonics (by 1/|H(f)|, up to 2.1x for the 4th: the low-pass passes less of
    the noise there)."""
    box = np.ones(width)
    kernel = box
    for _ in range(3):
        kernel = np.convolve(kernel, box)   # whole numbers below 2**53: exact
    return float(width) ** 8 / fm.dot(kernel, kernel)


def inverse(g: np.ndarray) -> np.ndarray:
    """g^-1 of a symmetric positive matrix, its rows and columns scaled to a unit
    diagonal first (the columns of a torque balance span orders of magnitude)."""
    d = np.sqrt(np.diag(g))
    scaled = g / np.outer(d, d)
    inv = np.column_stack([fm.solve(scaled, e) for e in np.eye(len(g))])
    return inv / np.outer(d, d)


def covariance(a: np.ndarray, y: np.ndarray, x: np.ndarray, inflation: float,
                g_inv: np.ndarray | None = None) -> np.ndarray:
    """The least-squares solution x's covariance: the residual's variance times
    (a'a)^-1 (``g_inv`` if given), times ``inflation`` (correlated residual samples)."""
    n, p = a.shape
    r = y - fm.weighted_rows(a, x)
    if g_inv is None:
        g_inv = inverse(gram(a))
    return (fm.dot(r, r) / max(n - p, 1)) * inflation * g_inv


def coefficient_uncertainty(coef: np.ndarray, cov: np.ndarray, per_log: list[np.ndarray],
                             fs: float, fs_var: float) -> dict[str, float]:
    """Standard uncertainties of Kd1, Kd2, Kd4 (relative to the raw amplitude,
    as the sinc correction scales both), phi1, phi2 (rad) and Fs (N*m), from the
    coefficients' covariance (s1, c1, s2, c2, s4, c4) and the logs' own
    coefficients (Fs first, then the six) if there are several."""
    out: dict[str, float] = {}
    for i, name in enumerate(AMPLITUDES):
        s, c = coef[2 * i], coef[2 * i + 1]
        amp = fm.hypot(s, c)
        block = cov[2 * i:2 * i + 2, 2 * i:2 * i + 2]
        if not amp > 0:
            out[name] = math.inf
            if i < len(PHASES):
                out[PHASES[i]] = math.inf
            continue
        var_amp = quadratic((s / amp, c / amp), block)
        var_phase = quadratic((-c / (amp * amp), s / (amp * amp)), block)
        if per_log:
            var_amp += float(np.mean([(fm.hypot(x[1 + 2 * i], x[2 + 2 * i]) - amp) ** 2
                                      for x in per_log]))
            var_phase += float(np.mean([wrap(fm.atan2(x[2 + 2 * i], x[1 + 2 * i])
                                              - fm.atan2(c, s)) ** 2 for x in per_log]))
        out[name] = root(var_amp) / amp
        if i < len(PHASES):
            out[PHASES[i]] = root(var_phase)
    if per_log:
        fs_var += float(np.mean([(x[0] - fs) ** 2 for x in per_log]))
    out["Fs"] = root(fs_var)
    return out


def quadratic(u: tuple[float, float], b: np.ndarray) -> float:
    """u' b u of a 2-vector, in a fixed order (no BLAS: the same bits on any CPU)."""
    return float(u[0] * b[0, 0] * u[0] + u[0] * b[0, 1] * u[1]
                 + u[1] * b[1, 0] * u[0] + u[1] * b[1, 1] * u[1])


def root(variance: float) -> float:
    """The standard uncertainty of a variance (inf where it is not a finite
    number >= 0: the fit cannot say)."""
    return math.sqrt(variance) if math.isfinite(variance) and variance >= 0.0 else math.inf


def wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def balance_uncertainty(a: np.ndarray, y: np.ndarray, rows: Sequence[np.ndarray],
                        targets: Sequence[np.ndarray], sol: np.ndarray, free: Sequence[bool],
                        inflation: float, prior_j: float) -> dict[str, float]:
    """The torque balance's uncertainties (:func:`coefficient_uncertainty`'s, and J,
    D in kg*m^2 and N*m*s/rad): its covariance over the columns it solved for
    (``a``'s first two are J's and D's, ``free`` where fitted; then Fs and the six
    harmonics), the prior's J (``prior_j``, where J is not fitted) carried through
    the harmonics' sensitivity to it, and each log's own fit (``rows``,
    ``targets``) about the joint one ``sol``."""
    keep = [i for i in range(a.shape[1]) if i >= 2 or free[i]]
    a_keep = np.ascontiguousarray(a[:, keep])
    y_keep = y - sum((sol[i] * a[:, i] for i in range(2) if not free[i]), np.zeros(len(y)))
    g_inv = inverse(gram(a_keep))
    cov = np.zeros((a.shape[1], a.shape[1]))
    cov[np.ix_(keep, keep)] = covariance(a_keep, y_keep, sol[keep], inflation, g_inv)
    if not free[0]:
        rhs = np.array([fm.dot(np.ascontiguousarray(a_keep[:, k]), np.ascontiguousarray(a[:, 0]))
                        for k in range(len(keep))])
        sens = np.zeros(a.shape[1])
        sens[keep] = -fm.weighted_rows(g_inv, rhs)
        cov += np.outer(sens, sens) * (PRIOR_J_UNCERTAINTY * prior_j) ** 2
    per_log = []
    if len(rows) > 1:
        for r, t in zip(rows, targets):
            own = fm.lstsq(np.ascontiguousarray(r[:, 2:]), t - sol[0] * r[:, 0] - sol[1] * r[:, 1])
            if np.all(np.isfinite(own)):
                per_log.append(own)
    unc = coefficient_uncertainty(sol[3:], cov[3:, 3:], per_log, float(sol[2]), cov[2, 2])
    unc["J"] = root(cov[0, 0]) if free[0] else PRIOR_J_UNCERTAINTY * prior_j
    if free[1]:
        unc["D"] = root(cov[1, 1])
    return unc


def judgements(nominal: SystemParams, speeds_rps: Sequence[float], model: FeedforwardModel,
               j: float, fitted: tuple[str, ...], uncertainty: Mapping[str, float]) -> list[str]:
    """One-line warnings about the identified values: an amplitude uncertain by
    more than :data:`MAX_UNCERTAINTY`, J fitted from logs above the h=4
    resonance, and where the prior disagrees with the logs."""
    out = []
    doubtful = [f"{n} {getattr(model, n):.4g} +- {uncertainty[n] / getattr(model, n):.1%}"
                if getattr(model, n) > 0 else f"{n} 0 (+- {uncertainty[n]:.3g} N*m; a negative "
                "fit clipped)"
                for n in AMPLITUDES
                if not uncertainty[n] <= MAX_UNCERTAINTY * getattr(model, n)]
    if doubtful:
        out.append(f"uncertain: {', '.join(doubtful)} (above {MAX_UNCERTAINTY:.0%}); the "
                   "feedforward is only as good as these: log the speeds `stepdamp identify "
                   "--plan` gives")
    # The resonance by the prior's J, or by the logs' where that is heavier (a
    # prior without its load puts the resonance too high).
    f4 = nominal.predicted_resonances_rps()[4] * math.sqrt(min(1.0, nominal.motor.J / j))
    fast = [v for v in speeds_rps if abs(v) > f4]
    if "J" in fitted and fast:
        out.append(f"J fitted from logs above the h=4 resonance ({f4:.3g} rev/s): "
                   "there the rotor's inertia carries the detent ripple and J trades against "
                   "the harmonics (J 2-70 % low in the measurements of docs/drivelogs.md, "
                   "beyond the stated uncertainty); log below it (stepdamp identify --plan)")
    m = nominal.motor
    if "J" in fitted and abs(j - m.J) > 3.0 * uncertainty["J"] \
            and max(j / m.J, m.J / j) > 1.0 + J_DISAGREES:
        hint = "; a load's inertia missing from the prior?" if j > m.J else ""
        out.append(f"the prior disagrees with the logs: J {m.J:.4g} kg*m^2 against the logs' "
                   f"{j:.4g} ({j / m.J - 1.0:+.0%}{hint}); the identified motor has the logs' J")
    differ = [f"{n} {getattr(m, n):.4g} N*m against the logs' {getattr(model, n):.4g}"
              + (f" ({getattr(model, n) / getattr(m, n) - 1.0:+.0%})" if getattr(m, n) else "")
              for n in AMPLITUDES
              if abs(getattr(model, n) - getattr(m, n))
              > max(3.0 * uncertainty[n], 0.3 * getattr(m, n))]
    if differ:
        out.append(f"the prior disagrees with the logs: {'; '.join(differ)}; the identified "
                   "motor has the logs' detent model")
    return out


def is_servo_log(theta: np.ndarray, ia: np.ndarray, ib: np.ndarray, nr: int) -> bool:
    """Whether a log's currents (A) have no mean d part at its encoder angles
    ``theta`` (rad): a servo commands none, open loop its holding current."""
    s1, c1 = fm.sincos_array(np.ascontiguousarray(nr * theta))
    d, q = ia * c1 + ib * s1, -ia * s1 + ib * c1
    # Fixed-order sums: the same verdict on any CPU.
    return abs(fm.dot(d, np.ones_like(d))) / len(d) <= 0.1 * math.sqrt(fm.dot(q, q) / len(q)) \
        + 1e-3


def servo_logs_warning(servo: Sequence[str], logs: int) -> list[str]:
    """The warning for torque-balance fits of the servo logs ``servo`` (labels) of
    ``logs`` logs, measured by benchmarks/identify_plan_catalogue.py."""
    if not servo:
        return []
    which = "" if len(servo) == logs else ", ".join(servo) + ": "
    return [f"{which}servo log{'s' if len(servo) > 1 else ''}: on 3 of 81 simulated catalogue "
            "identifications servo logs came out 6-8 % off with every stated uncertainty "
            "under 5 %; open-loop logs, as `stepdamp identify --plan` asks, within 2.7 %"]
