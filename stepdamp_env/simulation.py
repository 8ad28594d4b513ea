"""Python face of the kernel: build configuration and state, run, read metrics.

>>> from stepdamp_env import simulate
>>> result = simulate("patent", mode="open-loop", base_controller="patent-ff", speed_rps=1.0)
>>> result.metrics.rms_velocity_error_rad_s        # doctest: +SKIP
"""

from __future__ import annotations

import math
import numbers
import os
from dataclasses import InitVar, dataclass, field
from typing import Any, Mapping

import numpy as np

from . import fixedmath as fm
from . import kernel as K
from .estimators import kalman_velocity_gains
from .limits import LIMITS
from .metrics import (RunMetrics, merge_accumulator_rows, merge_accumulators,
                      metrics_from_accumulators, new_accumulators)
from .motorfile import load_system
from .params import (RK4_STABLE_RADIUS, FeedforwardModel, ParameterError, SystemParams,
                     detent_coefficients, fastest_plant_mode, fastest_plant_mode_bound,
                     required_substeps)

__all__ = ["check_converged", "MODES", "BASE_CONTROLLERS", "DEFAULT_ACCEL_RPS2", "MIN_ACCEL_RPS2",
           "MAX_DURATION_S", "PROFILE_KINDS", "RAMPS", "max_move_distance_rev", "ramps_distance_rev", "trace_memory_limit", "check_trace_memory",
           "run_length_error", "run_periods_chunked", "SpeedProfile", "RunSettings", "RunMetrics",
           "RunResult", "build_config", "check_integrable", "initial_state", "new_accumulators",
           "metrics_from_accumulators", "merge_accumulators", "merge_accumulator_rows", "simulate"]

MODES = {"open-loop": K.MODE.OPEN_LOOP, "servo": K.MODE.SERVO}
DRIVE_MODE_CODES = {"current": K.DRIVE.CURRENT, "voltage": K.DRIVE.VOLTAGE}
# The drive's own controller under any residual: nothing, or the patent's harmonic
# feedforward (eq. 8 in open loop, eq. 15 with its Fs term in servo).
BASE_CONTROLLERS = ("none", "patent-ff")
VELOCITY_ESTIMATORS = {"lowpass": K.VEL_EST.LOWPASS, "kalman": K.VEL_EST.KALMAN,
                       "back-emf": K.VEL_EST.BACK_EMF}
TWO_PI = 2.0 * math.pi
#: SpeedProfile kinds: a constant speed after a ramp, and the point-to-point moves.
PROFILE_KINDS = ("constant", "move")
#: A move's ramps: constant acceleration (a trapezoid of speed), or half cosines.
RAMPS = ("trapezoid", "s-curve")
PROFILE_CODES = {("constant", "trapezoid"): K.PROFILE.CONSTANT,
                 ("move", "trapezoid"): K.PROFILE.MOVE, ("move", "s-curve"): K.PROFILE.S_CURVE}
# Start-up ramp of a constant-speed profile (rev/s^2): fast, yet no open-loop step loss.
DEFAULT_ACCEL_RPS2 = 50.0
# Smallest command acceleration (rev/s^2) of `stepdamp ... --accel` and of the envs'
# accel_rps2: below it the ramp alone outlasts MAX_DURATION_S at a few rev/s.
MIN_ACCEL_RPS2 = 1e-3
# Longest simulated time of one run (s): `stepdamp simulate --duration`'s cap, and
# simulate()'s for a duration given or derived from the profile (a move's time, a ramp).
MAX_DURATION_S = 1e4
# RK4 plant steps (PWM periods x substeps) per compiled kernel call: about 0.05 s of a
# core (~0.2 us a step). Python runs its signal handlers (Ctrl-C, SIGTERM) only between
# compiled calls, so a run stops within a second of one. The chunks give the same bits
# as one call: every loop variable is carried in the state and accumulators.
CHUNK_PLANT_STEPS = 1 << 18


def _check_choice(name: str, value: str, choices) -> None:
    if not isinstance(value, str) or value not in choices:     # an array has no truth value
        raise ParameterError(f"{name}={value!r} is not one of {sorted(choices)}")


def _is_number(value: Any) -> bool:
    """A real number, not a bool (a float first: the abstract-class test costs more
    than the rest, and every run checks)."""
    return type(value) is float or not isinstance(value, (bool, np.bool_)) and \
        isinstance(value, numbers.Real)


def _check_positive(name: str, value: float, allow_zero: bool = False) -> None:
    if not _is_number(value) or not math.isfinite(value):
        raise ParameterError(f"{name} must be a finite number, got {value!r}")
    if value < 0 or (value == 0 and not allow_zero):
        bound = "[0, inf)" if allow_zero else "(0, inf)"
        raise ParameterError(f"{name}={value!r} is outside its allowed range {bound}")


@dataclass(frozen=True)
class SpeedProfile:
    """Command profile. Speeds in rev/s, accelerations in rev/s^2, distance in rev.

    ``kind="constant"``: from rest, accelerate at ``accel_rps2`` to ``speed_rps``
    (signed) and hold it; the ramp keeps an open-loop start-up from losing steps.
    ``kind="move"``: a trapezoidal point-to-point move of ``distance_rev``
    (signed) at up to ``speed_rps``, triangular if the distance is too short.
    ``ramp="s-curve"`` (a move only): its ramps are half cosines (bounded
    jerk) whose peak acceleration is ``accel_rps2``; each lasts
    ``pi*speed/(2*accel)`` and covers the distance a constant-acceleration ramp
    of that duration would.
    """

    speed_rps: float
    accel_rps2: float = DEFAULT_ACCEL_RPS2
    kind: str = "constant"
    distance_rev: float = 0.0
    ramp: str = "trapezoid"

    def __post_init__(self) -> None:
        _check_choice("kind", self.kind, PROFILE_KINDS)
        _check_choice("ramp", self.ramp, RAMPS)
        if self.kind == "constant" and self.ramp != "trapezoid":
            raise ParameterError(f"ramp={self.ramp!r} needs kind='move' (a constant speed ramps "
                                 "at a constant acceleration)")
        for name in ("speed_rps", "distance_rev"):
            value = getattr(self, name)
            if not _is_number(value):
                raise ParameterError(f"{name} must be a number, got {value!r}")
        if not math.isfinite(self.speed_rps) or abs(self.speed_rps) > 1e3 or \
                0.0 < abs(self.speed_rps) < 1e-6:
            raise ParameterError(
                f"speed_rps={self.speed_rps!r} is outside its allowed range: 0 (at rest) or "
                "1e-6 <= |speed_rps| <= 1000")
        _check_positive("accel_rps2", self.accel_rps2)
        if self.kind == "move":
            _check_positive("speed_rps (magnitude of a move)", abs(self.speed_rps))
        if not math.isfinite(self.distance_rev):
            raise ParameterError(f"distance_rev must be finite, got {self.distance_rev!r}")
        for name in ("speed_rps", "accel_rps2", "distance_rev"):    # numpy scalars: as float
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def ramp_s(self) -> float:
        """Time a ramp to the command speed takes (s)."""
        v, a = abs(self.speed_rps), self.accel_rps2
        return 0.5 * math.pi * v / a if self.ramp == "s-curve" else v / a

    def cruise(self) -> tuple[float, float]:
        """(start, length) in s of a move's cruise at its top speed (length 0 for
        a move too short to reach it); for ``constant``: (ramp_s, inf)."""
        if self.kind == "constant":
            return self.ramp_s, math.inf
        v, d = abs(self.speed_rps), abs(self.distance_rev)
        ramps = ramps_distance_rev(v, self.accel_rps2, self.ramp)
        if ramps >= d:
            return 0.5 * self.duration_s(), 0.0
        return self.ramp_s, (d - ramps) / v

    def duration_s(self) -> float:
        """Time the move takes (s); for ``constant`` the ramp time."""
        if self.kind == "constant":
            return self.ramp_s
        v, a, d = abs(self.speed_rps), self.accel_rps2, abs(self.distance_rev)
        short = ramps_distance_rev(v, a, self.ramp) > d
        if self.ramp == "s-curve":
            if short:
                return math.pi * math.sqrt(2.0 * a * d / math.pi) / a
            return d / v + 0.5 * math.pi * v / a
        if short:
            return 2.0 * math.sqrt(d / a)
        return d / v + v / a


def ramps_distance_rev(speed_rps: float, accel_rps2: float, ramp: str) -> float:
    """Distance (rev) a move's two ramps cover, up to |speed_rps| and down again,
    at (peak) acceleration ``accel_rps2`` (rev/s^2): v^2/a for the trapezoid,
    pi*v^2/(2a) for the S-curve's half-cosine ramps."""
    v = abs(speed_rps)
    return 0.5 * math.pi * v * v / accel_rps2 if ramp == "s-curve" else v * v / accel_rps2


def max_move_distance_rev(speed_rps: float, accel_rps2: float, time_s: float,
                          ramp: str = "trapezoid") -> float:
    """Longest move (rev) with ``ramp`` ("trapezoid" or "s-curve") at top speed
    ``|speed_rps|`` and ``accel_rps2`` that lasts at most ``time_s`` (the
    inverse of :meth:`SpeedProfile.duration_s`)."""
    v, a = abs(speed_rps), accel_rps2
    if not time_s > 0.0:
        return 0.0
    ramp_s = 0.5 * math.pi * v / a if ramp == "s-curve" else v / a
    if time_s >= 2.0 * ramp_s:          # reaches its top speed
        return v * (time_s - ramp_s)
    if ramp == "s-curve":               # peak speed a*time/pi
        return a * time_s * time_s / (2.0 * math.pi)
    return a * time_s * time_s / 4.0    # triangular


@dataclass(frozen=True)
class RunSettings:
    """How one run is simulated and measured (times in s).

    Attributes:
        mode: ``"open-loop"`` (eqs. 7-8) or ``"servo"`` (eqs. 14-15).
        base_controller: ``"none"`` or ``"patent-ff"``. In open loop the feedforward is
            the eq. 8 harmonic current; in servo it is eq. 15's harmonics plus
            its Fs term. ``"none"`` leaves out every model term.
        substeps: RK4 plant steps per PWM period (1 is accurate to about 1e-5
            relative on the metrics; the tests check it against 10).
        settle_s: time after the ramp before the measuring window opens;
            ``None`` means four decay times 1/(zeta*wn) of the open-loop
            resonance, clipped to [0.1, 0.6] s.
        window_s: length of the measuring window; rounded up to whole periods
            of the first detent harmonic so the lock-in amplitudes do not leak.
        estimate: the controller's own motor model for the feedforward;
            ``None`` takes the plant's exact values.
        velocity_estimator: ``"lowpass"`` (difference of encoder angles through
            a first-order low-pass, the patent's), ``"kalman"`` (steady-state
            Kalman filter, :mod:`stepdamp_env.estimators`) or ``"back-emf"``
            (no encoder: the winding's back-EMF from the applied voltages and
            the measured currents, with the winding's R and L, through the same
            low-pass; the servo still reads its position from the encoder).
        noise_seed: seed of the current-sensor noise (integer in [0, 2**53)).
    """

    mode: str = "open-loop"
    base_controller: str = "none"
    substeps: int = 1
    settle_s: float | None = None
    window_s: float = 0.5
    estimate: FeedforwardModel | None = None
    velocity_estimator: str = "lowpass"
    noise_seed: int = 0
    # The name of base_controller before 0.11, kept only because the frozen v0
    # fingerprint harness (tests/v0_fingerprints.py) passes it.
    damping: InitVar[str | None] = None

    def __post_init__(self, damping: str | None) -> None:
        if damping is not None:
            if self.base_controller != "none":
                raise ParameterError("give base_controller or its old name damping, not both")
            object.__setattr__(self, "base_controller", damping)
        _check_choice("mode", self.mode, MODES)
        _check_choice("velocity_estimator", self.velocity_estimator, VELOCITY_ESTIMATORS)
        if isinstance(self.noise_seed, bool) or not isinstance(self.noise_seed, (int, np.integer)) \
                or not 0 <= self.noise_seed < 2 ** 53:
            raise ParameterError(f"noise_seed={self.noise_seed!r} is outside its allowed range "
                                 "[0, 2**53) (integer)")
        _check_choice("base_controller", self.base_controller, BASE_CONTROLLERS)
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, (int, np.integer)) \
                or not 1 <= self.substeps <= 1000:
            raise ParameterError(f"substeps={self.substeps!r} is outside its allowed range "
                                 "[1, 1000] (integer)")
        if self.settle_s is not None:
            _check_positive("settle_s", self.settle_s, allow_zero=True)
        _check_positive("window_s", self.window_s)
        if self.estimate is not None and not isinstance(self.estimate, FeedforwardModel):
            raise ParameterError(f"estimate must be a FeedforwardModel or None (the exact model), "
                                 f"got {self.estimate!r}")
        object.__setattr__(self, "substeps", int(self.substeps))
        object.__setattr__(self, "noise_seed", int(self.noise_seed))
        object.__setattr__(self, "window_s", float(self.window_s))
        if self.settle_s is not None:
            object.__setattr__(self, "settle_s", float(self.settle_s))


def default_settle_s(system: SystemParams) -> float:
    """Four decay times of the lightly damped open-loop resonance, in [0.1, 0.6] s."""
    m = system.motor
    decay_rate = m.D / (2.0 * m.J)          # zeta * wn (1/s)
    if decay_rate <= 0:
        return 0.6
    return min(max(4.0 / decay_rate, 0.1), 0.6)


def measuring_window(system: SystemParams, profile: SpeedProfile, settings: RunSettings
                     ) -> tuple[float, float]:
    """(start, length) of the measuring window in s: after the ramp and the
    settling for a constant speed; from the start through the settling for a move."""
    settle = default_settle_s(system) if settings.settle_s is None else settings.settle_s
    if profile.kind == "move":
        # The whole move and its settling: after it the rotor rests, nothing to measure.
        return 0.0, profile.duration_s() + settle
    start = profile.duration_s() + settle
    length = settings.window_s
    if profile.kind == "constant" and profile.speed_rps != 0.0:
        period = 1.0 / (system.motor.Nr * abs(profile.speed_rps))
        length = math.ceil(length / period - 1e-9) * period
    return start, length


def build_config(system: SystemParams, profile: SpeedProfile, settings: RunSettings,
                 window_start_s: float = 0.0, window_end_s: float = math.inf) -> np.ndarray:
    """The kernel's configuration vector (see ``kernel.CONFIG``); the metrics
    window is ``[window_start_s, window_end_s)`` (s)."""
    m, d, sv = system.motor, system.drive, system.servo
    check_integrable(system, settings.substeps, profile.speed_rps)
    c = np.zeros(len(K.CONFIG))
    c[K.CONFIG.R] = m.R
    c[K.CONFIG.L] = m.L
    c[K.CONFIG.KM] = m.Km
    c[K.CONFIG.NR] = m.Nr
    c[K.CONFIG.J] = m.J
    c[K.CONFIG.D] = m.D
    c[K.CONFIG.DET_S1:K.CONFIG.DET_C4 + 1] = detent_coefficients(m)
    c[K.CONFIG.FS] = m.Fs
    c[K.CONFIG.LOAD] = m.load_torque
    c[K.CONFIG.VDC] = d.Vdc
    dt = 1.0 / d.pwm_hz
    c[K.CONFIG.DT] = dt
    c[K.CONFIG.HOLD] = d.holding_current
    c[K.CONFIG.MICROSTEP] = m.full_step_rad / d.microsteps
    kp_i, ki_i = system.current_gains()
    c[K.CONFIG.KP_I] = kp_i
    c[K.CONFIG.KI_I] = ki_i
    c[K.CONFIG.ENCODER] = TWO_PI / sv.encoder_cpr
    c[K.CONFIG.VEL_ALPHA] = 1.0 - fm.exp(-TWO_PI * sv.velocity_cutoff_hz * dt)
    c[K.CONFIG.KP_VEL], c[K.CONFIG.KP_POS], c[K.CONFIG.KI_POS] = system.servo_gains()
    c[K.CONFIG.MODE] = MODES[settings.mode]
    c[K.CONFIG.BASE_CONTROLLER] = 1.0 if settings.base_controller == "patent-ff" else 0.0
    est = settings.estimate if settings.estimate is not None else FeedforwardModel.from_motor(m)
    c[K.CONFIG.KM_EST] = est.Km
    c[K.CONFIG.FS_EST] = est.Fs
    c[K.CONFIG.FF_S1:K.CONFIG.FF_C4 + 1] = est.coefficients()
    c[K.CONFIG.SUBSTEPS] = settings.substeps
    # Stiction band: the speed friction alone removes in one plant step, so a
    # zero crossing within a step is caught at the next step's start.
    c[K.CONFIG.W_STICK] = m.Fs / m.J * dt / settings.substeps
    c[K.CONFIG.PROFILE] = PROFILE_CODES[(profile.kind, profile.ramp)]
    c[K.CONFIG.SPEED] = TWO_PI * profile.speed_rps
    c[K.CONFIG.ACCEL] = TWO_PI * profile.accel_rps2
    c[K.CONFIG.DISTANCE] = TWO_PI * profile.distance_rev
    c[K.CONFIG.WINDOW_START] = window_start_s
    c[K.CONFIG.WINDOW_END] = window_end_s
    c[K.CONFIG.REF_SPEED] = TWO_PI * abs(profile.speed_rps)
    c[K.CONFIG.I_NOISE] = d.current_noise_a
    c[K.CONFIG.I_OFFSET_A] = d.current_offset_a
    c[K.CONFIG.I_OFFSET_B] = d.current_offset_b
    c[K.CONFIG.NOISE_SEED] = settings.noise_seed
    c[K.CONFIG.VEL_EST] = VELOCITY_ESTIMATORS[settings.velocity_estimator]
    # Designed only when used: the design can be slow or fail for extreme encoders.
    if settings.velocity_estimator == "kalman":
        c[K.CONFIG.KF_K0], c[K.CONFIG.KF_K1] = kalman_velocity_gains(dt, c[K.CONFIG.ENCODER],
                                                         sv.kalman_accel_std)
    # The winding's R and L as the drive's standstill measurement gives them (the
    # current loop's tuning uses the same values).
    x = m.R * dt / m.L
    c[K.CONFIG.BEMF_G1] = m.L / dt * (x / -fm.expm1(-x) if x > 0.0 else 1.0)   # R/(1-a)
    c[K.CONFIG.BEMF_G2] = c[K.CONFIG.BEMF_G1] * fm.exp(-x)
    # Voltage mode: the winding model from the same standstill measurement.
    c[K.CONFIG.DRIVE_MODE] = DRIVE_MODE_CODES[d.drive_mode]
    c[K.CONFIG.R_EST] = m.R
    c[K.CONFIG.L_EST] = m.L
    return c


def check_integrable(system: SystemParams, substeps: int, speed_rps: float = 0.0) -> None:
    """Refuse, before a run, a system whose fastest plant mode ``substeps`` RK4
    steps per PWM period cannot integrate stably (it would end in NaN or 1e200).

    The back-EMF rotation Nr*omega at ``speed_rps`` counts as a mode too
    (:func:`~stepdamp_env.stability.fastest_plant_mode`).
    """
    # A bound settles the common case without the eigenvalues (a training episode's
    # reset); the margin keeps it inside their rounding, the floor to whole steps.
    whole = RK4_STABLE_RADIUS * system.drive.pwm_hz * math.floor(substeps)
    if fastest_plant_mode_bound(system, speed_rps) <= whole * (1.0 - 1e-6):
        return
    need = required_substeps(system, speed_rps)
    if substeps >= need:
        return
    rate, fields = fastest_plant_mode(system, speed_rps)
    limit = RK4_STABLE_RADIUS * system.drive.pwm_hz * substeps
    advice = (f"set substeps >= {need} (allowed up to 1000)" if need <= 1000
              else "no allowed substeps (at most 1000) integrates it; change those fields")
    raise ParameterError(
        f"{fields} give a plant mode of {rate:.4g} rad/s, above the {limit:.4g} rad/s that "
        f"substeps={substeps} RK4 step(s) per PWM period integrate stably "
        f"(2.5 * pwm_hz * substeps); {advice}")


def check_converged(system: SystemParams, substeps: int, state: np.ndarray,
                    metrics: "RunMetrics", speed_rps: float) -> None:
    """Refuse, after a run, a result the integration did not follow.

    The check before the run covers the command speed. A rotor that loses its
    steps under a load its torque cannot hold, with little damping (small D, R
    near 0: no back-EMF braking) and a light J, runs away to speeds no substeps
    chosen for the command integrate, and the run ends in 1e200 or NaN. That
    is a one-line ``ParameterError`` here, never NaN metrics. A final rotor speed
    up to twice the integrable one passes (the command's own ripple may pass it).
    """
    d = metrics.to_dict()
    values = [float(x) for key, v in d.items() if key != "step_loss" and not key.endswith("_norm")
              for x in np.ravel(list(v.values()) if isinstance(v, dict) else [v])]
    limit = RK4_STABLE_RADIUS * system.drive.pwm_hz * substeps / system.motor.Nr
    if np.all(np.isfinite(state)) and all(math.isfinite(x) for x in values) \
            and abs(state[K.STATE.OMEGA]) <= 2.0 * limit:
        return
    m = system.motor
    raise ParameterError(
        f"the run at speed_rps={speed_rps:.6g} diverged: the rotor ran away (J={m.J:.3g} kg*m^2, D={m.D:.3g} N*m*s/rad, "
        f"R={m.R:.3g} ohm, load_torque={m.load_torque:.3g} N*m against a holding torque "
        f"Km*holding_current={m.Km * system.drive.holding_current:.3g} N*m) past the "
        f"{limit:.4g} rad/s that substeps={substeps} integrate; damp or load the rotor less, "
        "or raise substeps")


def initial_state(config: np.ndarray, theta0: float = 0.0) -> np.ndarray:
    """Rotor at rest at ``theta0`` (rad), currents at their commanded steady values.

    In open loop the holding current already flows along the command angle
    (0 at t = 0) and the d integrator holds the R*i that sustains it, so a run
    starts without a current transient. In servo the windings start unenergised.
    """
    s = np.zeros(len(K.STATE))
    s[K.STATE.THETA] = theta0
    theta_fb = math.floor(theta0 / config[K.CONFIG.ENCODER]) * config[K.CONFIG.ENCODER]
    s[K.STATE.THETA_FB_PREV] = theta_fb
    s[K.STATE.THETA_FB] = theta_fb
    s[K.STATE.THETA_EST] = theta_fb + 0.5 * config[K.CONFIG.ENCODER]
    if config[K.CONFIG.MODE] == K.MODE.OPEN_LOOP:
        s[K.STATE.IA] = config[K.CONFIG.HOLD]
        s[K.STATE.INT_D] = config[K.CONFIG.R] * config[K.CONFIG.HOLD]
        s[K.STATE.VA_NEXT] = config[K.CONFIG.R] * config[K.CONFIG.HOLD]
        s[K.STATE.VA_OLD] = s[K.STATE.VA_NEXT]
        s[K.STATE.IA_PREV] = config[K.CONFIG.HOLD]
        s[K.STATE.ID_MEAS] = config[K.CONFIG.HOLD]
    return s


@dataclass
class RunResult:
    """Outcome of :func:`simulate`: metrics, and the trace if one was asked for."""

    system: SystemParams
    profile: SpeedProfile
    settings: RunSettings
    window_start_s: float
    duration_s: float
    metrics: RunMetrics
    trace: dict[str, np.ndarray] | None = None
    final_state: np.ndarray = field(default_factory=lambda: np.zeros(len(K.STATE)))
    accumulators: np.ndarray = field(default_factory=new_accumulators)


def trace_memory_limit() -> int:
    """Bytes a trace may take (estimated before anything is allocated):
    ``LIMITS.trace_bytes``, or a quarter of this machine's physical memory where
    that is less."""
    try:
        physical = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):       # no sysconf (Windows)
        return LIMITS.trace_bytes
    return min(LIMITS.trace_bytes, physical // 4) if physical > 0 else LIMITS.trace_bytes


#: Bytes of one trace row in the kernel's buffer (float64 channels).
TRACE_ROW_BYTES = 8 * len(K.TRACE)


def check_trace_memory(n_periods: int, trace_every: int, pwm_hz: float, *,
                       row_bytes: int = 2 * TRACE_ROW_BYTES, option: str = "trace",
                       duration: str = "duration_s", every: str | None = "trace_every"
                       ) -> None:
    """Refuse, before allocating, a trace of ``n_periods`` PWM periods (one row every
    ``trace_every``) whose ``row_bytes`` per row exceed :func:`trace_memory_limit`:
    a one-line ``ParameterError`` naming ``option`` and how to shorten it (the
    defaults: :func:`simulate`'s buffer and its per-channel copies)."""
    rows = -(-n_periods // trace_every)
    need = rows * row_bytes
    limit = trace_memory_limit()
    if need <= limit:
        return
    rows_max = max(1, limit // row_bytes)
    advice = f"give a shorter {duration} (at most {rows_max * trace_every / pwm_hz:.6g} s)"
    if every:
        advice += f" or raise {every} (to at least {-(-n_periods // rows_max)})"
    raise ParameterError(
        f"{option}: {rows} rows ({n_periods} PWM periods at {pwm_hz:g} Hz, about "
        f"{row_bytes} bytes a row) need about {need / 2 ** 30:.3g} GiB of memory, above the "
        f"{limit / 2 ** 30:.3g} GiB allowed; {advice}")


def run_length_error(system: SystemParams, profile: SpeedProfile, settings: RunSettings,
                     names: Mapping[str, str] | None = None) -> str:
    """Why the run of ``profile`` (its default duration, or its window's start)
    cannot fit in :data:`MAX_DURATION_S`, naming what to change; ``names``
    renames the parameters (the CLI's ``--move``, ``--speed``, ``--accel``)."""
    n = {"distance_rev": "distance_rev", "speed_rps": "speed_rps",
         "accel_rps2": "accel_rps2", "duration_s": "duration_s", **(names or {})}
    settle = default_settle_s(system) if settings.settle_s is None else settings.settle_s
    v, a = abs(profile.speed_rps), profile.accel_rps2
    cap = f"past the {MAX_DURATION_S:g} s a run may last"
    if profile.kind == "move":
        time_s = profile.duration_s()
        d_max = max_move_distance_rev(v, a, MAX_DURATION_S - settle, profile.ramp)
        return (f"{n['distance_rev']}={profile.distance_rev:g} is a move of {time_s:.6g} s at "
                f"{n['speed_rps']}={profile.speed_rps:g} and {n['accel_rps2']}={a:g}; with "
                f"{settle:.3g} s of settling it runs {time_s + settle:.6g} s, {cap}: allowed "
                f"|{n['distance_rev']}| <= {d_max:.6g} rev")
    start, length = measuring_window(system, profile, settings)
    opens = start < MAX_DURATION_S
    room = MAX_DURATION_S - settle - (length if opens else 0.0)
    fixes = [f"{n['accel_rps2']} >= {v / room:.6g} rev/s^2"] if room > 0.0 and v > 0.0 else []
    if opens:       # a shorter run: the window cut short
        fixes.append(f"a {n['duration_s']} in ({start:.6g}, {MAX_DURATION_S:g}] s")
    return (f"the ramp to {n['speed_rps']}={profile.speed_rps:g} at {n['accel_rps2']}={a:g} "
            f"takes {profile.ramp_s:.6g} s; with {settle:.3g} s of settling and a "
            f"{length:.3g} s window the run lasts {start + length:.6g} s, {cap}: allowed "
            + (" or ".join(fixes) or "a shorter settle_s"))


def run_periods_chunked(config: np.ndarray, state: np.ndarray, acc: np.ndarray,
                        inputs: np.ndarray, n_periods: int, trace: np.ndarray,
                        trace_every: int) -> int:
    """:func:`kernel.run_periods` over ``n_periods`` in calls of about
    :data:`CHUNK_PLANT_STEPS` plant steps each, so that signals are handled
    between them; the same bits as one call, the trace rows included (row ``r``
    holds period ``r * trace_every``). Returns the rows written."""
    chunk = max(1, CHUNK_PLANT_STEPS // max(1, int(config[K.CONFIG.SUBSTEPS])))
    empty = trace[:0]
    done = rows = 0
    while done < n_periods:
        n = min(chunk, n_periods - done)
        if done % trace_every == 0:
            # The kernel writes a row at each multiple of trace_every from its start.
            rows += K.run_periods(config, state, acc, inputs, n, trace[rows:], trace_every)
        else:
            # Up to the next period that has a row: no row to write.
            n = min(n, trace_every - done % trace_every)
            K.run_periods(config, state, acc, inputs, n, empty, trace_every)
        done += n
    return rows


def simulate(system: SystemParams | str | Mapping[str, Any], *,
             speed_rps: float | None = None,
             profile: SpeedProfile | None = None,
             mode: str = "open-loop", base_controller: str = "none",
             duration_s: float | None = None,
             settings: RunSettings | None = None,
             trace: bool = False, trace_every: int = 1,
             estimate: FeedforwardModel | None = None) -> RunResult:
    """Simulate one run and measure it.

    Give either ``speed_rps`` (a constant-speed profile with the default ramp)
    or a full ``profile``. ``duration_s`` defaults to the end of the measuring
    window (ramp + settle + window); a shorter duration raises. ``settings``
    overrides ``mode``, ``base_controller`` and ``estimate`` when given. With
    ``trace=True`` the result holds one sample every ``trace_every`` PWM periods
    of the channels in ``kernel.TRACE_NAMES`` (SI units; ``va``/``vb`` are the
    winding voltages applied during that period).
    """
    system = load_system(system) if not isinstance(system, SystemParams) else system
    if profile is None:
        if speed_rps is None:
            raise ParameterError("give speed_rps or profile")
        profile = SpeedProfile(speed_rps=float(speed_rps))
    elif speed_rps is not None:
        raise ParameterError("give speed_rps or profile, not both")
    if settings is None:
        settings = RunSettings(mode=mode, base_controller=base_controller, estimate=estimate)
    if isinstance(trace_every, bool) or not isinstance(trace_every, int) or trace_every < 1:
        raise ParameterError(f"trace_every={trace_every!r} is outside its allowed range "
                             "[1, inf) (integer)")
    start, length = measuring_window(system, profile, settings)
    end = start + length
    # Bounded work: the run (given or derived from the profile) lasts at most
    # MAX_DURATION_S; checked before anything is built or allocated.
    if not start < MAX_DURATION_S or (duration_s is None and not end <= MAX_DURATION_S):
        raise ParameterError(run_length_error(system, profile, settings))
    if duration_s is None:
        duration_s = end
    _check_positive("duration_s", duration_s)
    if not (round(duration_s * system.drive.pwm_hz) * system.drive.pwm_hz ** -1 > start
            and duration_s <= MAX_DURATION_S):
        raise ParameterError(
            f"duration_s={duration_s:.6g} s must end after the measuring window opens at "
            f"{start:.6g} s (ramp + settle) and last at most {MAX_DURATION_S:g} s: allowed "
            f"range ({start:.6g}, {MAX_DURATION_S:g}] s")
    n_periods = int(round(duration_s * system.drive.pwm_hz))
    if trace:
        check_trace_memory(n_periods, trace_every, system.drive.pwm_hz)
    config = build_config(system, profile, settings, window_start_s=start)
    substeps = int(config[K.CONFIG.SUBSTEPS])
    if n_periods * substeps > LIMITS.plant_steps:
        raise ParameterError(
            f"duration_s={duration_s:g} s at {system.drive.pwm_hz:g} Hz with substeps={substeps} "
            f"is {n_periods * substeps:.3g} plant steps (hours of a core); allowed at most "
            f"{LIMITS.plant_steps:.3g}: at most {LIMITS.plant_steps / substeps / system.drive.pwm_hz:.6g}"
            " s, or fewer substeps")
    state = initial_state(config)
    acc = new_accumulators()
    inputs = np.zeros(len(K.INPUT))
    if trace:
        rows = -(-n_periods // trace_every)
        buf = np.zeros((rows, len(K.TRACE)))
    else:
        buf = np.zeros((0, len(K.TRACE)))
    written = run_periods_chunked(config, state, acc, inputs, n_periods, buf, trace_every)
    trace_dict = None
    if trace:
        trace_dict = {name: buf[:written, i].copy() for i, name in enumerate(K.TRACE_NAMES)}
    metrics = metrics_from_accumulators(acc, system, profile.speed_rps)
    check_converged(system, settings.substeps, state, metrics, profile.speed_rps)
    return RunResult(system=system, profile=profile, settings=settings, window_start_s=start,
                     duration_s=n_periods / system.drive.pwm_hz, metrics=metrics,
                     trace=trace_dict, final_state=state, accumulators=acc)
