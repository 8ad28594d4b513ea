"""The detent model identified from constant-speed drive logs
(docs/drivelogs.md), with a nominal motor as the prior (its Km, Nr and encoder;
its J and D where the logs do not give them; its servo for the effort method).
:mod:`.drivelog` reads and writes the logs.

Two methods:

* ``"torque-balance"`` (the default): the rigid rotor's torque balance, sample
  by sample, Km*i_q = J*theta'' + D*theta' + Fs*sign(w) + the detent
  harmonics at the encoder angle, i_q from the phase currents. Every term is
  put through one low-pass (four moving means, a cubic B-spline window whose
  first zero is at 3 times the 4th harmonic's frequency: it passes the
  harmonics and removes the encoder's quantisation from theta''), and one
  linear least-squares fit over all logs gives the harmonics, Fs, J and D.
  No model of the servo enters, so the servo's imperfect rejection and the
  rotor's large ripple at low speed (which bias the next method) do not.
* ``"effort"``: patent claim 1 as :func:`stepdamp_env.identify.identify` does
  it in one least-squares round: the servo's effort Km*i_q_cmd (from the
  command currents) fitted onto the harmonics, each harmonic divided by the
  loop's response :func:`~stepdamp_env.identify.effort_response` of the
  nominal drive; the harmonics from the slowest log, Fs and D from the mean
  efforts of all. With no feedforward round to shrink the rotor's ripple it
  is biased by 5-20 % on light axes (docs/drivelogs.md).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any, Mapping, NamedTuple, Sequence

import numpy as np

from . import fixedmath as fm
from .drivelog import read_trace
from .identify import effort_response, model_from_coefficients
from .logstats import (AMPLITUDES, MAX_UNCERTAINTY, PHASES, PRIOR_J_UNCERTAINTY,
                       balance_uncertainty, coefficient_uncertainty, covariance, is_servo_log,
                       judgements, noise_inflation, root, servo_logs_warning)
from .motorfile import load_system
from .params import DETENT_HARMONICS, FeedforwardModel, ParameterError, SystemParams

# The fit's low-pass: first zero at this multiple of the 4th harmonic's frequency.
FILTER_ZERO_PER_H4 = 3.0

__all__ = ["DEFAULT_SETTLE_S", "DISTINCT_SPEEDS", "LogFit", "LogIdentification",
           "MAX_RESIDUAL_FRACTION", "MAX_UNCERTAINTY", "METHODS", "MIN_ELECTRICAL_PERIODS",
           "MIN_FIT_PERIODS", "PRIOR_J_UNCERTAINTY", "SPEED_DRIFT", "identify_from_logs",
           "identify_from_tables"]


METHODS = ("torque-balance", "effort")


#: A log with fewer electrical periods 1/(Nr*|v|) in its fit window is warned of.
MIN_ELECTRICAL_PERIODS = 10.0


#: A log whose fit leaves more than this fraction of its current's RMS (both
#: through the fit's low-pass) is warned of: past it the weaker harmonics err
#: by 10 % or more.
MAX_RESIDUAL_FRACTION = 0.3


#: Time skipped after a log first reaches its speed (s): the servo's transient.
DEFAULT_SETTLE_S = 0.1


# Speeds whose halves of the fit window differ by more than this are not constant.
SPEED_DRIFT = 0.05


# Fewer electrical periods than this cannot be fitted at all (the harmonics alias).
MIN_FIT_PERIODS = 1.0


# Speeds closer than this fraction of the fastest count as one speed.
DISTINCT_SPEEDS = 0.2


_COMMAND = ("command_current_a_A", "command_current_b_A")


_PHASE = ("phase_current_a_A", "phase_current_b_A")


_NEEDED = {"torque-balance": ("time_s", "position_rad") + _PHASE,
           "effort": ("time_s", "position_rad") + _COMMAND}


# --------------------------------------------------------------------------- identification
@dataclass(frozen=True)
class LogFit:
    """What one log contributed to an identification.

    Attributes:
        label: the log's name (its path).
        speed_rps: its speed over the fit window, from the encoder (rev/s, signed).
        start_s, end_s: the fit window (s, the log's time).
        electrical_periods: electrical periods 1/(Nr*|speed|) in the window.
        samples: samples in the window.
        residual_rms_a: RMS of what the fitted model leaves of the log's q
            current (A), both through the torque balance's low-pass (the
            harmonics' band; the encoder's quantisation noise is above it).
        residual_fraction: that RMS over the RMS of the current's variation
            about its mean (the same current, the same low-pass).
        warnings: one-line warnings about this log.
    """

    label: str
    speed_rps: float
    start_s: float
    end_s: float
    electrical_periods: float
    samples: int
    residual_rms_a: float
    residual_fraction: float
    warnings: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {"label": self.label, "speed_rps": self.speed_rps, "start_s": self.start_s,
                "end_s": self.end_s, "electrical_periods": self.electrical_periods,
                "samples": self.samples, "residual_rms_a": self.residual_rms_a,
                "residual_fraction": self.residual_fraction, "warnings": list(self.warnings)}


@dataclass(frozen=True)
class LogIdentification:
    """A detent model identified from drive logs.

    Attributes:
        model: the identified model (Km is the nominal motor's: the amplitudes
            are in N*m as that Km converts the logged currents).
        J: inertia (kg*m^2): fitted (torque-balance) or the nominal's.
        D: viscous damping (N*m*s/rad): fitted, or the nominal's if the logs
            hold one speed only or ``fit_mechanics=False``.
        method: ``"torque-balance"`` or ``"effort"``.
        fitted: which of ``"J"``, ``"D"`` come from the logs (the others
            are the nominal motor's).
        logs: per-log details (:class:`LogFit`), in the order given.
        residual_rms_a: RMS of the residual current over all logs (A).
        residual_fraction: residual RMS over the signal RMS, over all logs.
        warnings: every warning, one line each (the logs' and the fit's).
        uncertainty: one standard uncertainty per identified value, in its
            unit (Kd1, Kd2, Kd4, Fs: N*m; phi1, phi2: rad; J: kg*m^2; D:
            N*m*s/rad where fitted): the fit's covariance (its residual as
            noise, the low-pass's correlation counted), the spread between
            the logs' own fits where there are several, and, where J is the
            prior's, :data:`PRIOR_J_UNCERTAINTY` of J carried through.
    """

    model: FeedforwardModel
    J: float
    D: float
    method: str
    fitted: tuple[str, ...]
    logs: tuple[LogFit, ...]
    residual_rms_a: float
    residual_fraction: float
    warnings: tuple[str, ...] = field(default=())
    uncertainty: Mapping[str, float] = field(default_factory=dict, hash=False)

    def relative_uncertainty(self, name: str) -> float:
        """``uncertainty[name]`` over the value (Kd1, Kd2, Kd4, Fs, J, D)."""
        value = getattr(self, name) if name in ("J", "D") else getattr(self.model, name)
        return self.uncertainty[name] / abs(value) if value else math.inf

    @property
    def speeds_rps(self) -> tuple[float, ...]:
        """The logs' detected speeds (rev/s)."""
        return tuple(log.speed_rps for log in self.logs)

    def apply_to(self, nominal: SystemParams, *, mechanics: bool = False) -> SystemParams:
        """``nominal`` with the identified Kd1, Kd2, Kd4, phi1, phi2, Fs (and
        those of J, D that were fitted, if ``mechanics``)."""
        m = self.model
        values: dict[str, Any] = {"Kd1": m.Kd1, "Kd2": m.Kd2, "Kd4": m.Kd4, "phi1": m.phi1,
                                  "phi2": m.phi2, "Fs": m.Fs}
        if mechanics:
            values.update({name: getattr(self, name) for name in self.fitted})
        return nominal.replace(**values)

    def to_dict(self) -> dict[str, Any]:
        return {"method": self.method, "model": dict(self.model.__dict__), "J": self.J,
                "D": self.D, "fitted": list(self.fitted),
                "speeds_rps": list(self.speeds_rps), "residual_rms_a": self.residual_rms_a,
                "residual_fraction": self.residual_fraction,
                "uncertainty": dict(self.uncertainty),
                "relative_uncertainty": {k: self.relative_uncertainty(k)
                                         for k in self.uncertainty if k not in PHASES},
                "logs": [log.to_dict() for log in self.logs], "warnings": list(self.warnings)}


class _Log(NamedTuple):
    """One log's fit window and what the methods need of it."""

    label: str
    dt: float
    t: np.ndarray              # the window's times (s)
    theta: np.ndarray          # encoder angle at the centre of its count (rad)
    ia: np.ndarray             # the method's currents (A): phase or command
    ib: np.ndarray
    omega: float               # mean speed (rad/s, signed)
    warnings: list[str]


def _line_slope(t: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope of y against t."""
    tc = t - fm.dot(t, np.ones_like(t)) / len(t)
    return fm.dot(tc, y) / fm.dot(tc, tc)


def _prepare(nominal: SystemParams, table: Mapping[str, np.ndarray], label: str,
             method: str, settle_s: float) -> _Log:
    """Check one log, find its constant-speed window, warn of what is doubtful."""
    missing = [k for k in _NEEDED[method] if k not in table]
    if missing:
        raise ParameterError(f"{label}: missing column {missing[0]!r} (method {method!r} "
                             f"needs {list(_NEEDED[method])})")
    t = np.asarray(table["time_s"], dtype=float)
    theta = np.asarray(table["position_rad"], dtype=float)
    n = len(t)
    if n < 8:
        raise ParameterError(f"{label} has {n} rows; a fit needs thousands")
    step = np.diff(t)
    dt = float(np.median(step))
    if not (dt > 0 and np.max(np.abs(step - dt)) <= 0.01 * dt):
        raise ParameterError(f"{label}: time_s is not evenly sampled (steps from "
                             f"{np.min(step):.6g} to {np.max(step):.6g} s); the fit needs "
                             "one sampling period")
    nr = nominal.motor.Nr
    half = n // 2
    omega_end = _line_slope(t[half:], theta[half:])
    if not abs(omega_end) >= 2.0 * math.pi * 0.01:
        raise ParameterError(f"{label}: the rotor turns at {omega_end / (2 * math.pi):.3g} "
                             "rev/s over the log's second half; allowed |speed| >= 0.01 rev/s "
                             "(constant-speed logs)")
    # Speed averaged over a full step (the 4th harmonic's ripple averages out):
    # the window opens settle_s after it first reaches 90 % of the final speed.
    w = max(1, int(round(2.0 * math.pi / (4.0 * nr * abs(omega_end)) / dt)))
    warnings: list[str] = []
    if w < n:
        avg = (theta[w:] - theta[:-w]) / (w * dt) * math.copysign(1.0, omega_end)
        reached = np.flatnonzero(avg >= 0.9 * abs(omega_end))
        first = int(reached[0]) + w // 2 if len(reached) else n
    else:
        first = 0
    i0 = int(np.searchsorted(t, t[min(first, n - 1)] + settle_s))
    window = slice(i0, n)
    tw, thw = t[window], theta[window]
    omega = _line_slope(tw, thw) if len(tw) >= 8 else omega_end
    span = float(tw[-1] - tw[0]) if len(tw) >= 2 else 0.0
    periods = nr * abs(omega) * span / (2.0 * math.pi)
    if periods < MIN_FIT_PERIODS:
        raise ParameterError(
            f"{label}: {periods:.2f} electrical period(s) at constant speed after the "
            f"{settle_s:g} s settle; at least {MIN_FIT_PERIODS:g} needed to fit, "
            f"{MIN_ELECTRICAL_PERIODS:g} for a trustworthy fit (log longer or faster)")
    speed = omega / (2.0 * math.pi)
    if periods < MIN_ELECTRICAL_PERIODS:
        warnings.append(f"{label}: too short: {periods:.1f} electrical periods at "
                        f"{speed:.3g} rev/s (fewer than {MIN_ELECTRICAL_PERIODS:g}); the "
                        "harmonics are poorly averaged (log longer or faster)")
    mid = len(tw) // 2
    v1, v2 = _line_slope(tw[:mid], thw[:mid]), _line_slope(tw[mid:], thw[mid:])
    if abs(v2 - v1) > SPEED_DRIFT * abs(omega):
        warnings.append(f"{label}: the speed drifts from {v1 / (2 * math.pi):.4g} to "
                        f"{v2 / (2 * math.pi):.4g} rev/s within the fit window (more than "
                        f"{SPEED_DRIFT:.0%}); the fit assumes a constant speed")
    backward = int(np.count_nonzero(np.diff(thw) * math.copysign(1.0, omega) < 0))
    if backward:
        warnings.append(f"{label}: the encoder steps backwards {backward} time(s) at "
                        f"{speed:.3g} rev/s: the rotor stalls and reverses (stick-slip), where "
                        "friction is not Fs*sign(speed); log faster")
    q = 2.0 * math.pi / nominal.servo.encoder_cpr
    counts = thw / q
    if np.max(np.abs(counts - np.round(counts))) > 1e-6:
        warnings.append(f"{label}: position_rad is not whole counts of the nominal "
                        f"encoder_cpr={nominal.servo.encoder_cpr} (2*pi/{nominal.servo.encoder_cpr}"
                        " rad); set the motor's encoder_cpr to the log's encoder")
    names = _PHASE if method == "torque-balance" else _COMMAND
    return _Log(label, dt, tw, thw + 0.5 * q,
                np.asarray(table[names[0]], dtype=float)[window],
                np.asarray(table[names[1]], dtype=float)[window], omega, warnings)


def _harmonic_columns(x: np.ndarray) -> list[np.ndarray]:
    """sin and cos of h*x for h = 1, 2, 4 (fixed-order trigonometry)."""
    cols: list[np.ndarray] = []
    for h in DETENT_HARMONICS:
        cols += list(fm.sincos_array(np.ascontiguousarray(h * x)))
    return cols


def _q_current(log: _Log, nr: int) -> np.ndarray:
    """The log's currents along the q axis of the encoder angle (A)."""
    s, c = fm.sincos_array(np.ascontiguousarray(nr * log.theta))
    return -log.ia * s + log.ib * c


def _moving_mean(x: np.ndarray, m: int) -> np.ndarray:
    """Mean over m samples, 'valid' part (sequential cumulative sums: no BLAS)."""
    c = np.concatenate(([0.0], np.cumsum(x)))
    return (c[m:] - c[:-m]) * (1.0 / m)


def _filter_width(log: _Log, nr: int) -> int:
    """Samples per moving mean of the fit's low-pass: 1/(3*f4) s, f4 = 4*Nr*|v|."""
    f4 = 4.0 * nr * abs(log.omega) / (2.0 * math.pi)
    samples = 1.0 / (FILTER_ZERO_PER_H4 * f4 * log.dt)
    width = int(round(samples))
    if samples < 2.0:
        raise ParameterError(
            f"{log.label}: sampled at {1 / log.dt:.4g} Hz, too slow for the 4th harmonic at "
            f"{f4:.4g} Hz; allowed sampling >= {2 * FILTER_ZERO_PER_H4 * f4:.4g} Hz")
    if len(log.t) <= 4 * width + 8:
        raise ParameterError(f"{log.label}: the fit window is shorter than the fit's low-pass "
                             f"({4 * width * log.dt:.3g} s); log longer")
    return width


def _lowpass(x: np.ndarray, m: int) -> np.ndarray:
    """The fit's low-pass: four m-sample moving means (a cubic B-spline window,
    zeros at multiples of 1/(m*dt), side lobes falling as 1/f^4)."""
    for _ in range(4):
        x = _moving_mean(x, m)
    return x


def _sinc_corrected(coef: np.ndarray, nominal: SystemParams) -> np.ndarray:
    """Detent coefficients (s1, c1, s2, c2, s4, c4) fitted at the centre of the
    encoder count, with the count's averaging, sinc(h*Nr*q/2), divided out."""
    m = nominal.motor
    q = 2.0 * math.pi / nominal.servo.encoder_cpr
    out = np.array(coef, dtype=float)
    for i, h in enumerate(DETENT_HARMONICS):
        arg = 0.5 * h * m.Nr * q
        out[2 * i:2 * i + 2] *= arg / fm.sin(arg)
    if not np.all(np.isfinite(out)):
        raise ParameterError("the logs do not determine the detent harmonics (the fit is "
                             "rank deficient): give longer logs at distinct speeds")
    return out


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x))) if len(x) else math.nan


def _torque_balance(nominal: SystemParams, logs: list[_Log], fit_mechanics: bool
                    ) -> tuple[np.ndarray, float, float, float, tuple[str, ...],
                               list[tuple[np.ndarray, np.ndarray]], list[str], dict[str, float]]:
    """(detent coefficients, Fs, J, D, the names of J, D fitted, per-log (signal,
    residual) in N*m, notes, uncertainties: Kd1, Kd2, Kd4 relative, the others
    in their units)."""
    m = nominal.motor
    rows, targets, notes, inflation = [], [], [], 1.0
    for log in logs:
        width = _filter_width(log, m.Nr)
        inflation = max(inflation, noise_inflation(width))
        th = log.theta
        torque = m.Km * _q_current(log, m.Nr)
        # Central differences at the inner samples: theta'' and theta'.
        acc = (th[2:] - 2.0 * th[1:-1] + th[:-2]) * (1.0 / (log.dt * log.dt))
        vel = (th[2:] - th[:-2]) * (0.5 / log.dt)
        cols = [acc, vel, np.full(len(acc), math.copysign(1.0, log.omega))]
        cols += _harmonic_columns(m.Nr * th[1:-1])
        rows.append(np.column_stack([_lowpass(c, width) for c in cols]))
        targets.append(_lowpass(torque[1:-1], width))
    a, y = np.vstack(rows), np.concatenate(targets)
    # J and D are fitted unless told not to, from distinct speeds: with one speed
    # D*w and Fs are one constant, and the rotor's acceleration is (nearly) a
    # sum of the detent harmonics, so that J trades against them.
    speeds = [abs(log.omega) for log in logs]
    free = [fit_mechanics, fit_mechanics]
    if fit_mechanics and max(speeds) - min(speeds) < DISTINCT_SPEEDS * max(speeds):
        free = [False, False]
        notes.append(f"the logs hold one speed (within {DISTINCT_SPEEDS:.0%}): J and D are the "
                     "prior's, and the harmonics only as right as its J (their uncertainty "
                     f"assumes +-{PRIOR_J_UNCERTAINTY:.0%}; Fs holds any error of D*w); log "
                     "three distinct speeds to fit them (stepdamp identify --plan)")
    sol = _fit_with_known(a, y, free, (m.J, m.D))
    if any(free) and not (np.all(np.isfinite(sol)) and sol[0] > 0 and sol[1] >= 0):
        notes.append(f"the logs give J={sol[0]:.4g} kg*m^2, D={sol[1]:.4g} N*m*s/rad (not "
                     "positive): J and D taken from the nominal motor instead")
        free = [False, False]
        sol = _fit_with_known(a, y, free, (m.J, m.D))
    if not np.all(np.isfinite(sol)):
        raise ParameterError("the logs do not determine the detent harmonics (the fit is "
                             "rank deficient): give longer logs at distinct speeds")
    fitted = [(t, t - fm.weighted_rows(r, sol)) for r, t in zip(rows, targets)]
    fitted_names = tuple(n for n, f in zip(("J", "D"), free) if f)
    unc = balance_uncertainty(a, y, rows, targets, sol, free, inflation, m.J)
    return (sol[3:], float(sol[2]), float(sol[0]), float(sol[1]), fitted_names, fitted, notes,
            unc)


def _fit_with_known(a: np.ndarray, y: np.ndarray, free: list[bool],
                    known: tuple[float, float]) -> np.ndarray:
    """Least squares of y on the columns of a, the first two (J, D) fixed at
    ``known`` where not ``free``: their torque moves to the signal side."""
    y = y.copy()
    keep = [i for i in range(a.shape[1]) if i >= 2 or free[i]]
    for i in range(2):
        if not free[i]:
            y -= known[i] * a[:, i]
    part = fm.lstsq(np.ascontiguousarray(a[:, keep]), y)
    sol = np.array([known[0], known[1]] + [0.0] * (a.shape[1] - 2))
    sol[keep] = part
    return sol


def _effort(nominal: SystemParams, logs: list[_Log]
            ) -> tuple[np.ndarray, float, float, list[tuple[np.ndarray, np.ndarray]], list[str],
                       dict[str, float]]:
    """(detent coefficients, Fs, D, per-log (signal, residual) in N*m, notes,
    uncertainties as :func:`_torque_balance` gives them: the slowest log's fit
    covariance, its residual taken as white, and the other logs' harmonics).

    The harmonics come from the slowest log, where the servo's ripple and so
    the bias are least (as :func:`stepdamp_env.identify.identify` does); Fs and
    D from the mean efforts of all.
    """
    m = nominal.motor
    slowest = min(range(len(logs)), key=lambda k: abs(logs[k].omega))
    coef = np.zeros(2 * len(DETENT_HARMONICS))
    intercepts, fitted, notes, own, var_intercepts = [], [], [], [], []
    cov = np.zeros((len(coef), len(coef)))
    for k, log in enumerate(logs):
        s1, c1 = fm.sincos_array(np.ascontiguousarray(m.Nr * log.theta))
        effort = m.Km * (-log.ia * s1 + log.ib * c1)
        if not is_servo_log(log.theta, log.ia, log.ib, m.Nr):
            raise ParameterError(f"{log.label}: the command current has a mean d-axis part at "
                                 "the encoder angle: not a servo log; the effort method needs "
                                 "servo logs (use torque-balance)")
        a = np.column_stack([np.ones_like(effort)] + _harmonic_columns(m.Nr * log.theta))
        sol = fm.lstsq(a, effort)
        if not np.all(np.isfinite(sol)):
            raise ParameterError(f"{log.label}: the harmonics are not determined (rank "
                                 "deficient fit); log longer")
        mine = np.zeros(1 + len(coef))
        mine[0] = float(sol[0]) * math.copysign(1.0, log.omega)
        gains = []
        for i, h in enumerate(DETENT_HARMONICS):
            # The servo passes h*Nr*w to its effort as L/(1 + L): divide it out.
            g = 1.0 / effort_response(nominal, h * m.Nr * log.omega)
            z = complex(sol[1 + 2 * i], sol[2 + 2 * i]) * g
            mine[1 + 2 * i], mine[2 + 2 * i] = z.real, z.imag
            gains.append(np.array([[g.real, -g.imag], [g.imag, g.real]]))
        own.append(mine)
        raw = covariance(a, effort, sol, 1.0)
        var_intercepts.append(float(raw[0, 0]))
        raw = raw[1:, 1:]
        if k == slowest:
            coef[:] = mine[1:]
            for i, gi in enumerate(gains):
                for j, gj in enumerate(gains):
                    block = raw[2 * i:2 * i + 2, 2 * j:2 * j + 2]
                    for r in range(2):
                        for q in range(2):
                            cov[2 * i + r, 2 * j + q] = sum(
                                gi[r, k] * block[k, l] * gj[q, l]
                                for k in range(2) for l in range(2))
        intercepts.append(float(sol[0]) * math.copysign(1.0, log.omega))
        # Reported after the torque-balance's low-pass: the noise in the harmonics' band.
        width = _filter_width(log, m.Nr)
        residual = effort - fm.weighted_rows(a, sol)
        fitted.append((_lowpass(effort, width), _lowpass(residual, width)))
    speeds = np.array([abs(log.omega) for log in logs])
    n = len(logs)
    if np.ptp(speeds) >= DISTINCT_SPEEDS * np.max(speeds):
        fs, damping = fm.lstsq(np.column_stack([np.ones_like(speeds), speeds]),
                               np.array(intercepts))
        # The line's (Fs, D) = M y, M = (X'X)^-1 X': each log's intercept variance through it.
        s1, s2 = float(np.sum(speeds)), fm.dot(speeds, speeds)
        det = n * s2 - s1 * s1
        rows_m = [[(s2 - s1 * v) / det for v in speeds], [(n * v - s1) / det for v in speeds]]
        var_fs = sum(mk * mk * vk for mk, vk in zip(rows_m[0], var_intercepts))
        var_d: float | None = sum(mk * mk * vk for mk, vk in zip(rows_m[1], var_intercepts))
    else:
        damping = m.D
        fs = float(np.mean(np.array(intercepts) - m.D * speeds))
        var_fs, var_d = sum(var_intercepts) / (n * n), None
        notes.append(f"the logs hold one speed (within {DISTINCT_SPEEDS:.0%}): D taken from "
                     "the nominal motor, Fs from the mean effort less D*w")
    if n == 1:
        notes.append("one log: the effort method's bias on a light axis (5-20 %, docs/"
                     "drivelogs.md) is not in its stated uncertainty; log the speeds "
                     "`stepdamp identify --plan` gives, whose disagreement shows it")
    for x, v in zip(own, speeds):
        x[0] -= damping * v                     # each log's Fs, as the line gives it
    unc = coefficient_uncertainty(coef, cov, own if n > 1 else [], float(fs), var_fs)
    unc["J"] = PRIOR_J_UNCERTAINTY * m.J
    if var_d is not None:
        unc["D"] = root(var_d)
    return coef, float(fs), float(damping), fitted, notes, unc


def identify_from_tables(nominal: SystemParams | str, tables: Sequence[Mapping[str, np.ndarray]],
                         labels: Sequence[str] | None = None, *, method: str = "torque-balance",
                         settle_s: float = DEFAULT_SETTLE_S, fit_mechanics: bool = True
                         ) -> LogIdentification:
    """:func:`identify_from_logs` on drive logs already in memory (tables of
    :data:`TRACE_COLUMNS`, as :func:`read_trace` returns them); ``labels`` name
    them in the warnings (default ``log 1``, ``log 2``, ...)."""
    if not isinstance(nominal, SystemParams):
        nominal = load_system(nominal)
    if method not in METHODS:
        raise ParameterError(f"method={method!r} is not one of {list(METHODS)}")
    if isinstance(settle_s, bool) or not isinstance(settle_s, (int, float)) \
            or not (math.isfinite(settle_s) and settle_s >= 0):
        raise ParameterError(f"settle_s={settle_s!r} is outside its allowed range [0, inf) s")
    if not tables:
        raise ParameterError("no drive log given; give one or more constant-speed servo logs")
    labels = [f"log {i + 1}" for i in range(len(tables))] if labels is None else list(labels)
    if len(labels) != len(tables):
        raise ParameterError(f"{len(labels)} label(s) for {len(tables)} log(s)")
    logs = [_prepare(nominal, table, label, method, float(settle_s))
            for table, label in zip(tables, labels)]
    if method == "torque-balance":
        coef, fs, j, damping, mechanics, fitted, notes, unc = _torque_balance(nominal, logs,
                                                                              fit_mechanics)
    else:
        coef, fs, damping, fitted, notes, unc = _effort(nominal, logs)
        j, mechanics = nominal.motor.J, ("D",) if not notes else ()
    corrected = _sinc_corrected(coef, nominal)
    model = model_from_coefficients(nominal, corrected, fs)
    # Relative uncertainties times the amplitudes before the clip of a negative
    # Kd4 to 0 (the sinc correction scales an amplitude and its uncertainty alike).
    amplitudes = {name: fm.hypot(corrected[2 * i], corrected[2 * i + 1])
                  for i, name in enumerate(AMPLITUDES)}
    uncertainty = {name: unc[name] * amplitudes[name] if name in AMPLITUDES else unc[name]
                   for name in unc}
    notes = notes + judgements(nominal, [log.omega / (2.0 * math.pi) for log in logs], model,
                               float(j), mechanics, uncertainty)
    km = nominal.motor.Km
    fits, warnings = [], []
    for log, (signal, residual) in zip(logs, fitted):
        rms = _rms(residual) / km
        variation = _rms(signal - np.mean(signal)) / km
        fraction = rms / variation if variation > 0 else math.inf
        log_warnings = list(log.warnings)
        if fraction > MAX_RESIDUAL_FRACTION:
            log_warnings.append(f"{log.label}: too noisy: the fit leaves {fraction:.0%} of the "
                                f"current's RMS ({rms:.3g} of {variation:.3g} A; above "
                                f"{MAX_RESIDUAL_FRACTION:.0%})")
        fits.append(LogFit(label=log.label, speed_rps=log.omega / (2.0 * math.pi),
                           start_s=float(log.t[0]), end_s=float(log.t[-1]),
                           electrical_periods=nominal.motor.Nr * abs(log.omega)
                           * float(log.t[-1] - log.t[0]) / (2.0 * math.pi),
                           samples=len(log.t), residual_rms_a=rms, residual_fraction=fraction,
                           warnings=tuple(log_warnings)))
        warnings += log_warnings
    warnings += servo_logs_warning([log.label for log in logs if method == "torque-balance"
                                    and is_servo_log(log.theta, log.ia, log.ib,
                                                     nominal.motor.Nr)], len(logs))
    all_res = np.concatenate([r for _, r in fitted])
    all_sig = np.concatenate([s - np.mean(s) for s, _ in fitted])
    total = _rms(all_res) / km
    signal_rms = _rms(all_sig) / km
    return LogIdentification(model=model, J=float(j), D=float(damping), method=method,
                             fitted=mechanics, logs=tuple(fits),
                             residual_rms_a=total,
                             residual_fraction=total / signal_rms if signal_rms > 0 else math.inf,
                             warnings=tuple(warnings + notes), uncertainty=uncertainty)


def identify_from_logs(nominal: SystemParams | str, paths: Sequence[str | os.PathLike[str]], *,
                       method: str = "torque-balance", settle_s: float = DEFAULT_SETTLE_S,
                       fit_mechanics: bool = True) -> LogIdentification:
    """Identify Kd1, phi1, Kd2, phi2, Kd4, Fs (and J, D) from CSV drive logs.

    Args:
        nominal: the prior motor and drive (a preset name, a motor file or a
            :class:`SystemParams`): its Km, Nr and encoder_cpr are used as
            they are; its J and D where the logs do not give them; for
            ``"effort"`` its servo gains, current loop and J too.
        paths: constant-speed logs (:func:`write_trace`'s CSV), ideally at two
            or more distinct speeds; each one's speed is read from its encoder.
        method: ``"torque-balance"`` (phase currents; default) or ``"effort"``
            (command currents, claim 1); see the module docstring.
        settle_s: time skipped after a log first reaches its speed (s, >= 0).
        fit_mechanics: torque-balance: fit J and D too (default); False takes
            the nominal's.

    A log with fewer than :data:`MIN_ELECTRICAL_PERIODS` electrical periods
    in its window, or whose fit leaves more than :data:`MAX_RESIDUAL_FRACTION`
    of its current, gets a one-line warning in ``warnings``; a log that cannot
    be fitted at all raises ``ParameterError``.
    """
    if method not in METHODS:
        raise ParameterError(f"method={method!r} is not one of {list(METHODS)}")
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    names = [os.fspath(p) for p in paths]
    tables = [read_trace(p, required=_NEEDED[method]) for p in names]
    return identify_from_tables(nominal, tables, names, method=method, settle_s=settle_s,
                                fit_mechanics=fit_mechanics)


