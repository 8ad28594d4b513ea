"""Identification of the detent model (claim 1 of US 7,733,051).

The drive runs in servo mode at low constant speeds. Its control effort
``Km * iq_cmd`` then has to supply the detent torque and the friction, so the
periodic part of the effort against the encoder angle carries Kd1, Kd2, Kd4,
phi1, phi2, and its mean carries Fs (plus D*w; two speeds separate them).
Only what a drive sees is used: the encoder angle and the commanded current,
with the current sensors' noise and offset in the loop; Km is the datasheet's.

Two methods:

* ``"least-squares"``: one run per speed without feedforward; a linear
  least-squares fit of the feedback effort onto 1, sin/cos of h*Nr*theta_fb for
  h = 1, 2, 4. The servo does not reject a disturbance perfectly: the effort's
  harmonic is the detent's times the loop's rejection ratio L/(1 + L) at that
  frequency, which the drive computes from its own controller (gains, velocity
  filter, current loop, delays) and the datasheet inertia, and divides out.
* ``"iterative"``: the patent's tuning, automated: run with the feedforward of
  the current estimate, fit what is left of the feedback effort, add it to the
  estimate, and repeat until the effort is flat (its harmonic part no longer
  shrinks) or ``max_iterations`` is reached. What is left shrinks each round,
  so errors of the inertia model fade out.

The harmonics come from the lowest speed, the friction from the mean efforts
at all speeds (a line Fs + D*w). Below about 0.1 rev/s a 4000 count/rev
encoder makes the servo stick and slip, which biases both, so the default
speeds are 0.1 and 0.2 rev/s. The regressor angle is the centre of the encoder
count; averaging a harmonic over a count attenuates it by sinc(h*Nr*q/2),
which is divided out too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from . import fixedmath as fm
from . import kernel as K
from .params import DETENT_HARMONICS, FeedforwardModel, ParameterError, SystemParams
from .motorfile import load_system
from .response import servo_loop
from .simulation import RunSettings, SpeedProfile, build_config, initial_state, new_accumulators

__all__ = ["IdentificationResult", "identify", "METHODS", "model_from_coefficients"]

METHODS = ("least-squares", "iterative")
HARMONICS = DETENT_HARMONICS


@dataclass(frozen=True)
class IdentificationResult:
    """An identified detent model and how it was obtained.

    Attributes:
        model: the identified model (Km is the datasheet value the drive uses).
        D: identified viscous damping (N*m*s/rad), from the two speeds.
        method: "least-squares" or "iterative".
        speeds_rps: the identification speeds (rev/s).
        iterations: runs per speed that were needed.
        residual_harmonic_nm: RMS of the harmonic part left in the effort by
            the final model (N*m; iterative method), else of the fit residual.
        errors: estimate minus truth: relative amplitude errors (Kd1, Kd2,
            Kd4, Fs), phase errors (phi1, phi2, rad, wrapped to [-pi, pi]).
    """

    model: FeedforwardModel
    D: float
    method: str
    speeds_rps: tuple[float, ...]
    iterations: int
    residual_harmonic_nm: float
    errors: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"method": self.method, "speeds_rps": list(self.speeds_rps),
                "iterations": self.iterations, "D": self.D,
                "residual_harmonic_nm": self.residual_harmonic_nm,
                "model": dict(self.model.__dict__), "errors": dict(self.errors)}


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def _servo_run(system: SystemParams, speed_rps: float, estimate: FeedforwardModel | None,
               noise_seed: int, settle_s: float, measure_s: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Encoder angle (rad) and control effort Km*iq_cmd (N*m) over the window."""
    base = "none" if estimate is None else "patent-ff"
    settings = RunSettings(mode="servo", base_controller=base, estimate=estimate,
                           noise_seed=noise_seed)
    profile = SpeedProfile(speed_rps=speed_rps, accel_rps2=5.0)
    config = build_config(system, profile, settings, window_start_s=math.inf)
    # Harmonic feedforward but no Fs term: the effort's mean must keep carrying Fs.
    config[K.CONFIG.FS_EST] = 0.0
    state = initial_state(config)
    acc = new_accumulators()
    u = np.zeros(len(K.INPUT))
    empty = np.zeros((0, len(K.TRACE)))
    pwm = system.drive.pwm_hz
    n_skip = int(round((profile.duration_s() + settle_s) * pwm))
    K.run_periods(config, state, acc, u, n_skip, empty, 1)
    every = 1                                   # every control period: no aliasing
    n = int(round(measure_s * pwm))
    trace = np.zeros((-(-n // every), len(K.TRACE)))
    rows = K.run_periods(config, state, acc, u, n, trace, every)
    trace = trace[:rows]
    if acc[K.ACC.MAX_LAG] > system.motor.full_step_rad:
        raise RuntimeError(f"identification run at {speed_rps} rev/s lost steps")
    # Feedback part of the effort: the drive knows the feedforward it injected.
    effort = system.motor.Km * (trace[:, K.TRACE.IQ_CMD] - trace[:, K.TRACE.IQ_FF])
    return trace[:, K.TRACE.THETA_FB], effort


def effort_response(system: SystemParams, frequency_rad_s: float) -> complex:
    """Ratio of the servo's effort to a torque disturbance at ``frequency_rad_s``.

    L/(1 + L), L the servo's loop gain (:func:`stepdamp_env.response.servo_loop`:
    P velocity on the low-passed differenced encoder, PI position, the sampled
    current loop with its delays, the datasheet inertia).
    """
    loop = servo_loop(system, frequency_rad_s)
    return loop / (1.0 + loop)


def _regress(system: SystemParams, speed_rps: float, theta: np.ndarray, effort: np.ndarray,
             correct_rejection: bool) -> tuple[float, np.ndarray, float]:
    """Least squares of one run: intercept and (a_h, b_h) for h = 1, 2, 4.

    Returns (intercept (N*m), detent coefficients s1, c1, s2, c2, s4, c4 (N*m),
    RMS of the fitted harmonic part of the effort (N*m)).
    """
    nr = system.motor.Nr
    q = 2.0 * math.pi / system.servo.encoder_cpr
    x = nr * (theta + 0.5 * q)
    cols = [np.ones_like(x)]
    for h in HARMONICS:
        cols += list(fm.sincos_array(h * x))
    a = np.column_stack(cols)
    # Fixed-order QR, not LAPACK: the model must not depend on the CPU (fixedmath).
    sol = fm.lstsq(a, effort)
    if not np.all(np.isfinite(sol)):
        raise RuntimeError(f"identification run at {speed_rps} rev/s: the regressors are "
                           "rank deficient")
    fitted = fm.weighted_rows(np.ascontiguousarray(a[:, 1:]), np.ascontiguousarray(sol[1:]))
    harmonic_rms = float(np.sqrt(np.mean(fitted * fitted)))
    coef = sol[1:].copy()
    for i, h in enumerate(HARMONICS):
        arg = 0.5 * h * nr * q
        phasor = complex(coef[2 * i], coef[2 * i + 1]) / (fm.sin(arg) / arg)
        if correct_rejection:
            phasor /= effort_response(system, h * nr * 2.0 * math.pi * speed_rps)
        coef[2 * i], coef[2 * i + 1] = phasor.real, phasor.imag
    return float(sol[0]), coef, harmonic_rms


def model_from_coefficients(system: SystemParams, coef: np.ndarray, fs: float
                            ) -> FeedforwardModel:
    """The detent model of sin/cos coefficients (s1, c1, s2, c2, s4, c4) in N*m and
    a friction Fs (N*m), with ``system``'s Km; Kd4 and Fs clipped at 0."""
    s1, c1, s2, c2, s4, c4 = coef
    kd4 = fm.hypot(s4, c4) * (1.0 if s4 >= 0 else -1.0)
    return FeedforwardModel(Km=system.motor.Km, Kd1=fm.hypot(s1, c1), Kd2=fm.hypot(s2, c2),
                            Kd4=max(kd4, 0.0), phi1=fm.atan2(c1, s1), phi2=fm.atan2(c2, s2),
                            Fs=max(fs, 0.0))


def _friction(speeds_rps: Sequence[float], intercepts: np.ndarray,
              nominal_damping: float) -> tuple[float, float]:
    """(Fs, D) from the mean efforts: a line through them when two speeds differ,
    else Fs with the datasheet D."""
    w = 2.0 * math.pi * np.asarray(speeds_rps, dtype=float)
    if len(w) >= 2 and np.ptp(w) > 0:
        fs, d = fm.lstsq(np.column_stack([np.ones_like(w), w]),
                         np.asarray(intercepts, dtype=float))
        return float(fs), float(d)
    return float(intercepts[0] - nominal_damping * w[0]), nominal_damping


def _errors(model: FeedforwardModel, truth: SystemParams) -> dict[str, float]:
    m = truth.motor
    out = {}
    for name in ("Kd1", "Kd2", "Kd4", "Fs"):
        true = getattr(m, name)
        out[name] = (getattr(model, name) - true) / true if true > 0 else math.nan
    out["phi1"] = _wrap(model.phi1 - m.phi1)
    out["phi2"] = _wrap(model.phi2 - m.phi2)
    return out


def identify(system: SystemParams | str, *, method: str = "iterative",
             speeds_rps: Sequence[float] = (0.1, 0.2), settle_s: float = 0.5,
             measure_s: float = 2.0, noise_seed: int = 0, max_iterations: int = 6,
             tolerance: float = 0.02) -> IdentificationResult:
    """Identify Kd1, Kd2, Kd4, phi1, phi2 and Fs of ``system`` from servo runs.

    Args:
        system: the drive to identify (its sensor noise and offsets apply).
        method: "least-squares" or "iterative" (module docstring).
        speeds_rps: low constant speeds (rev/s, > 0); two or more distinct ones
            separate Fs from D*w.
        settle_s, measure_s: settling time after the ramp and measured time
            per run (s); measure at least a few electrical periods 1/(Nr*v).
        noise_seed: seed of the current-sensor noise.
        max_iterations: iterative method: at most this many rounds.
        tolerance: iterative method: stop when a round shrinks the effort's
            harmonic RMS by less than this fraction of the first round's.

    ``errors`` in the result compare with the simulated truth.
    """
    if not isinstance(system, SystemParams):
        system = load_system(system)
    if method not in METHODS:
        raise ParameterError(f"method={method!r} is not one of {list(METHODS)}")
    speeds = tuple(float(v) for v in speeds_rps)
    if not speeds or any(not (0.0 < v <= 1.0) for v in speeds):
        raise ParameterError(f"speeds_rps={speeds_rps!r}: each must be in (0, 1] rev/s")
    for name, value in (("settle_s", settle_s), ("measure_s", measure_s)):
        if not (math.isfinite(value) and value > 0):
            raise ParameterError(f"{name}={value!r} is outside its allowed range (0, inf) s")
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, int) \
            or not 1 <= max_iterations <= 50:
        raise ParameterError(f"max_iterations={max_iterations!r} is outside [1, 50]")

    lowest = int(np.argmin(speeds))

    def measure(estimate: FeedforwardModel | None) -> tuple[np.ndarray, np.ndarray, float]:
        """Intercepts at every speed; harmonics and their RMS at the lowest."""
        intercepts = np.zeros(len(speeds))
        coef, rms = np.zeros(6), 0.0
        for k, v in enumerate(speeds):
            theta, effort = _servo_run(system, v, estimate, noise_seed, settle_s, measure_s)
            intercepts[k], c, r = _regress(system, v, theta, effort, correct_rejection=True)
            if k == lowest:
                coef, rms = c, r
        return intercepts, coef, rms

    intercepts, coef, residual = measure(None)
    iterations = 1
    if method == "iterative":
        first = residual
        total = coef.copy()
        previous = residual
        while iterations < max_iterations:
            fs, _ = _friction(speeds, intercepts, system.motor.D)
            estimate = model_from_coefficients(system, total, fs)
            intercepts, coef, residual = measure(estimate)
            iterations += 1
            total = total + coef
            if previous - residual < tolerance * first:
                break
            previous = residual
        coef = total
    fs, damping = _friction(speeds, intercepts, system.motor.D)
    model = model_from_coefficients(system, coef, fs)
    return IdentificationResult(model=model, D=damping, method=method,
                                speeds_rps=speeds, iterations=iterations,
                                residual_harmonic_nm=residual, errors=_errors(model, system))
