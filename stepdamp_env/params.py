"""Validated parameter sets of the drive: motor, power stage and current loop, servo.

Parameters are what a domain randomiser changes; they never change during a run.
Every field is SI (A, V, Ohm, H, N*m, rad, rad/s, kg*m^2, s, Hz) and is checked at
construction: a bad value raises ``ValueError`` naming the field and its allowed
range, which sits beside the field as its metadata (:func:`allowed`). The flat
field names below are the public vocabulary of the API, of motor JSON files and
of ``stepdamp ... --set FIELD=VALUE``. The named presets are in
:mod:`stepdamp_env.presets`; motor files, datasheets and ``--set`` are read by
:mod:`stepdamp_env.motorfile`.

Motor (eqs. 1-4 and 9 of US 7,733,051, as corrected in docs/model.md):
    R, L, Km, Nr, J, D, Kd1, Kd2, Kd4, phi1, phi2, Fs, load_torque
Drive: Vdc, pwm_hz, holding_current, microsteps, current_bandwidth_hz,
    Kp_current, Ki_current, current_noise_a, current_offset_a, current_offset_b,
    drive_mode ("current" or "voltage", the one field that is not a number)
Servo: encoder_cpr, velocity_cutoff_hz, Kp_vel, Kp_pos, Ki_pos, kalman_accel_std

Derived gains (``None`` means "derive"): the current PI is designed on the
sampled loop the drive really has. With the winding discretised exactly over a
PWM period (pole a = exp(-R*dt/L)) and one period of computation delay, the PI
zero cancels the pole (Ki_current = Kp_current*(1 - a)/dt) and the loop gain
g = Kp_current*(1 - a)/R leaves the closed loop T(z) = g/(z^2 - z + g); g is
solved in closed form so that |T| is -3 dB at current_bandwidth_hz. The servo gains place
the three poles of J*s^3 + Kp_vel*s^2 + Kp_pos*s + Ki_pos at -ws (a triple pole),
ws = 2*pi*velocity_cutoff_hz / 5, a fifth of the velocity filter's corner so the
filter's lag stays small at the loop's crossover. The 100 Hz default corner
suits the patent's 4000 count/rev encoder at 20 kHz, whose raw differentiated
velocity has a resolution of 31 rad/s: at 1 kHz the loop amplifies that noise
into a limit cycle, and at 200 Hz the noise current of a heavy axis (the
QSH6018 preset) already saturates the bridge. In servo mode the encoder
angle is taken at the centre of its count (a floored count lags by half a
count on average).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
from dataclasses import dataclass, field, fields
from typing import Any, Mapping, NamedTuple

import numpy as np

from . import fixedmath as fm
from .errors import ParameterError, show_value
from .limits import LIMITS
from .stability import (RK4_STABLE_RADIUS, current_loop_radius, current_loop_terms,
                        delayed_loop_gain, fastest_plant_mode, fastest_plant_mode_bound,
                        loop_radius, loop_surely_stable, required_substeps)

__all__ = [
    "CurrentGains",
    "ServoGains",
    "MotorParams",
    "DriveParams",
    "DRIVE_MODES",
    "ServoParams",
    "SystemParams",
    "FeedforwardModel",
    "ParameterError",
    "predicted_resonances",
    "DETENT_HARMONICS",
    "RK4_STABLE_RADIUS",
    "current_loop_radius",
    "fastest_plant_mode",
    "fastest_plant_mode_bound",
    "detent_coefficients",
    "delayed_loop_gain",
    "required_substeps",
    "RESONANCE_HARMONICS",
    "check_name",
    "ALL_FIELDS",
    "MOTOR_FIELDS",
    "DRIVE_FIELDS",
    "SERVO_FIELDS",
    "INTEGER_FIELDS",
    "TEXT_FIELDS",
    "META_KEYS",
]


class CurrentGains(NamedTuple):
    """The d and q current PI loops' gains."""

    kp: float           #: V/A
    ki: float           #: V/(A*s)


class ServoGains(NamedTuple):
    """The servo's gains (eq. 15 of the patent)."""

    kp_vel: float       #: N*m*s/rad
    kp_pos: float       #: N*m/rad
    ki_pos: float       #: N*m/(rad*s)


_INF = math.inf


@dataclass(frozen=True)
class Allowed:
    """Allowed range of a field, [low, high] with either end open; integer-only if set."""

    low: float
    high: float
    low_open: bool = False
    high_open: bool = False
    integer: bool = False

    def check(self, name: str, value: Any) -> None:
        """Raise ``ParameterError`` naming ``name`` and this range if ``value`` is outside."""
        # numbers.Real admits numpy scalars; bool is a number only by accident.
        if type(value) is not float and (isinstance(value, (bool, np.bool_))
                                         or not isinstance(value, numbers.Real)):
            raise ParameterError(f"{name} must be a number, got {show_value(value)}")
        try:
            number = float(value)       # a float32 -2*pi must compare as a Python float
        except OverflowError:
            raise ParameterError(self.outside(name, value)) from None
        if not math.isfinite(number):
            raise ParameterError(f"{name} must be finite, got {show_value(value)}")
        if self.integer and number != int(value):
            raise ParameterError(f"{name} must be an integer, got {show_value(value)}")
        if not ((number > self.low if self.low_open else number >= self.low)
                and (number < self.high if self.high_open else number <= self.high)):
            raise ParameterError(self.outside(name, value))

    def outside(self, name: str, value: Any) -> str:
        """The message for ``value`` outside this range."""
        return (f"{name}={show_value(value)} is outside its allowed range {'(['[not self.low_open]}"
                f"{self.low}, {self.high}{')]'[not self.high_open]}")


@dataclass(frozen=True)
class OneOf:
    """Allowed values of a text field (the drive's ``drive_mode``)."""

    choices: tuple[str, ...]
    integer: bool = False

    def check(self, name: str, value: Any) -> None:
        """Raise ``ParameterError`` naming ``name`` and the choices if ``value`` is not one."""
        if not isinstance(value, str) or value not in self.choices:
            raise ParameterError(f"{name}={show_value(value)} is not one of {list(self.choices)}")


def allowed(low: float, high: float, *, low_open: bool = False, high_open: bool = False,
            integer: bool = False) -> dict[str, Allowed]:
    """Field metadata holding the field's allowed range: ``field(metadata=allowed(...))``."""
    return {"allowed": Allowed(low, high, low_open, high_open, integer)}


def _same_range_as(cls: type, name: str) -> Mapping[str, Allowed]:
    """The metadata (allowed range) of field ``name`` of dataclass ``cls``."""
    return next(f.metadata for f in fields(cls) if f.name == name)


@functools.lru_cache(maxsize=None)
def _checked_fields(cls: type) -> tuple[tuple[str, bool, "Allowed | OneOf"], ...]:
    """(name, optional, allowed range) of each field of ``cls``, read once per class."""
    return tuple((f.name, f.default is None, f.metadata["allowed"]) for f in fields(cls))


def _validate_fields(obj: Any) -> None:
    """Check every set field against the range in its metadata; coerce to int or float."""
    for name, optional, rng in _checked_fields(type(obj)):
        value = getattr(obj, name)
        if value is None and optional:      # an optional gain: derived
            continue
        rng.check(name, value)
        if not isinstance(rng, OneOf):
            object.__setattr__(obj, name, int(value) if rng.integer else float(value))


@dataclass(frozen=True)
class MotorParams:
    """Two-phase hybrid stepper with the patent's multi-harmonic detent model.

    Attributes:
        R: winding resistance per phase (Ohm).
        L: winding inductance per phase (H).
        Km: torque / back-EMF constant (N*m/A = V*s/rad).
        Nr: rotor teeth (electrical angle = Nr * shaft angle); 50 for 1.8 degree.
        J: inertia of rotor plus rigidly coupled load (kg*m^2).
        D: viscous damping (N*m*s/rad).
        Kd1, Kd2, Kd4: amplitudes of the 1st, 2nd and 4th detent harmonics (N*m).
        phi1, phi2: phases of the 1st and 2nd detent harmonics (rad).
        Fs: Coulomb (and breakaway) friction torque (N*m).
        load_torque: constant load torque opposing positive rotation (N*m).
    """

    R: float = field(metadata=allowed(0.0, 1e3, low_open=True))
    L: float = field(metadata=allowed(1e-12, 10.0))
    Km: float = field(metadata=allowed(1e-12, 100.0))
    Nr: int = field(metadata=allowed(1, 1000, integer=True))
    J: float = field(metadata=allowed(1e-12, 10.0))
    D: float = field(metadata=allowed(0.0, 100.0))
    Kd1: float = field(metadata=allowed(0.0, 100.0))
    Kd2: float = field(metadata=allowed(0.0, 100.0))
    Kd4: float = field(metadata=allowed(0.0, 100.0))
    phi1: float = field(metadata=allowed(-2 * math.pi, 2 * math.pi))
    phi2: float = field(metadata=allowed(-2 * math.pi, 2 * math.pi))
    Fs: float = field(metadata=allowed(0.0, 100.0))
    load_torque: float = field(default=0.0, metadata=allowed(-100.0, 100.0))

    def __post_init__(self) -> None:
        _validate_fields(self)

    @property
    def full_step_rad(self) -> float:
        """Shaft angle of one full step, 2*pi/(4*Nr) (rad); 1.8 degree for Nr = 50."""
        return 2.0 * math.pi / (4 * self.Nr)


#: Values of ``drive_mode``: current control (the default) or voltage mode.
DRIVE_MODES = ("current", "voltage")


@dataclass(frozen=True)
class DriveParams:
    """Three-leg SVPWM chopper and DQ current loops.

    Attributes:
        Vdc: bus voltage (V).
        pwm_hz: PWM and control rate (Hz); 20 kHz in the patent.
        holding_current: open-loop d-axis current, eq. 7 (A).
        microsteps: microsteps per full step (64 default; finer allowed).
        current_bandwidth_hz: designed bandwidth of the current loops (Hz).
        Kp_current: proportional gain (V/A); ``None`` derives it (module docstring).
        Ki_current: integral gain (V/(A*s)); ``None`` derives it likewise.
        current_noise_a: current-sensor noise, standard deviation per sample (A).
        current_offset_a, current_offset_b: current-sensor offsets (A).
        drive_mode: ``"current"`` (the DQ PI current loops, the default) or
            ``"voltage"``: the drive applies the winding voltages its model of
            the winding (R, L and the back-EMF Km*omega at the command speed)
            predicts for the commanded currents, with no current feedback, as
            quiet voltage-mode stepper drivers do (docs/model.md, "Voltage-mode
            drive"). Its rotor is negatively damped in a mid-band of speeds
            (:func:`stepdamp_env.analysis.midband`).
    """

    Vdc: float = field(default=48.0, metadata=allowed(0.0, 1e4, low_open=True))
    pwm_hz: float = field(default=20_000.0, metadata=allowed(1e3, 1e6))
    holding_current: float = field(default=1.9, metadata=allowed(0.0, 100.0, low_open=True))
    microsteps: int = field(default=64, metadata=allowed(1, 65536, integer=True))
    # Upper end pwm_hz/8 checked in __post_init__.
    current_bandwidth_hz: float = field(
        default=1_500.0, metadata=allowed(0.0, _INF, low_open=True, high_open=True))
    Kp_current: float | None = field(default=None, metadata=allowed(0.0, 1e6, low_open=True))
    Ki_current: float | None = field(default=None, metadata=allowed(0.0, 1e9))
    current_noise_a: float = field(default=0.0, metadata=allowed(0.0, 100.0))
    current_offset_a: float = field(default=0.0, metadata=allowed(-100.0, 100.0))
    current_offset_b: float = field(default=0.0, metadata=allowed(-100.0, 100.0))
    drive_mode: str = field(default="current", metadata={"allowed": OneOf(DRIVE_MODES)})

    def __post_init__(self) -> None:
        _validate_fields(self)
        if self.current_bandwidth_hz > self.pwm_hz / 8:
            raise ParameterError(
                f"current_bandwidth_hz={self.current_bandwidth_hz} is outside its allowed "
                f"range (0, pwm_hz/8 = {self.pwm_hz / 8}]: past that a sampled loop with "
                "one period of computation delay rings")


@dataclass(frozen=True)
class ServoParams:
    """Encoder feedback and the servo law of eqs. 14-15.

    Attributes:
        encoder_cpr: encoder counts per revolution after quadrature decoding.
        velocity_cutoff_hz: corner of the first-order low-pass on the
            differentiated encoder position (Hz).
        Kp_vel: velocity gain (N*m*s/rad); ``None`` derives 3*J*ws.
        Kp_pos: position gain (N*m/rad); ``None`` derives 3*J*ws^2.
        Ki_pos: position integral gain (N*m/(rad*s)); ``None`` derives J*ws^3.
        kalman_accel_std: acceleration noise of the Kalman velocity estimator's
            model, per control period (rad/s^2); used when it is selected.
    """

    encoder_cpr: int = field(default=4000, metadata=allowed(1, 1 << 30, integer=True))
    # Upper end pwm_hz/2 checked in SystemParams.
    velocity_cutoff_hz: float = field(
        default=100.0, metadata=allowed(0.0, _INF, low_open=True, high_open=True))
    Kp_vel: float | None = field(default=None, metadata=allowed(0.0, 1e6))
    Kp_pos: float | None = field(default=None, metadata=allowed(0.0, 1e9))
    Ki_pos: float | None = field(default=None, metadata=allowed(0.0, 1e12))
    kalman_accel_std: float = field(default=2000.0, metadata=allowed(0.0, 1e9, low_open=True))

    def __post_init__(self) -> None:
        _validate_fields(self)


MOTOR_FIELDS = tuple(f.name for f in fields(MotorParams))
DRIVE_FIELDS = tuple(f.name for f in fields(DriveParams))
SERVO_FIELDS = tuple(f.name for f in fields(ServoParams))
ALL_FIELDS = MOTOR_FIELDS + DRIVE_FIELDS + SERVO_FIELDS
INTEGER_FIELDS = frozenset(f.name for cls in (MotorParams, DriveParams, ServoParams)
                            for f in fields(cls) if f.metadata["allowed"].integer)
#: The fields whose value is text, not a number.
TEXT_FIELDS = ("drive_mode",)
# Keys a motor file may carry besides the fields: where it starts from and what it is.
META_KEYS = ("base", "name", "source", "notes")


def check_name(name: Any, label: str = "name") -> str:
    """``name`` if it is 1 to ``LIMITS.name_chars`` printable characters, else a
    one-line ``ParameterError`` naming ``label`` and the allowed range (a name is
    copied into every record, file and message of a run: a 50 MB name would
    cost gigabytes)."""
    if not isinstance(name, str):
        raise ParameterError(f"{label} must be text, got {type(name).__name__}")
    if not 1 <= len(name) <= LIMITS.name_chars or not name.isprintable():
        # Only the start of the name into the message (show_value shortens it anyway).
        raise ParameterError(f"{label}={show_value(name[:60])} ({len(name)} characters) is outside "
                             f"its allowed range: 1 to {LIMITS.name_chars} printable characters "
                             "(no line breaks or tabs)")
    return name


@dataclass(frozen=True)
class SystemParams:
    """Motor, drive and servo parameters of one simulated system."""

    motor: MotorParams
    drive: DriveParams = field(default_factory=DriveParams)
    servo: ServoParams = field(default_factory=ServoParams)
    name: str = "custom"

    def __post_init__(self) -> None:
        check_name(self.name)
        if self.drive.pwm_hz / 2 <= self.servo.velocity_cutoff_hz:
            raise ParameterError(
                f"velocity_cutoff_hz={self.servo.velocity_cutoff_hz} is outside its allowed "
                f"range (0, pwm_hz/2 = {self.drive.pwm_hz / 2})")
        kp, ki = gains = self._derive_current_gains()
        object.__setattr__(self, "_current_gains", gains)     # kept: a run reads them often
        if not kp >= MIN_KP_CURRENT:
            raise ParameterError(
                f"current_bandwidth_hz={self.drive.current_bandwidth_hz:.4g} Hz (or Kp_current) "
                f"gives Kp_current={kp:.4g} V/A; allowed [{MIN_KP_CURRENT:g}, 1e6] V/A: the loop "
                "must control the current")
        # Back-calculation anti-windup pulls the integrator at dt*Ki/Kp per period.
        aw = ki / (kp * self.drive.pwm_hz)
        if not aw < 2.0:
            raise ParameterError(
                f"Kp_current={kp:.4g} V/A with Ki_current={ki:.4g} V/(A*s) make the anti-windup "
                f"unstable (Ki_current/(Kp_current*pwm_hz) = {aw:.4g}, allowed < 2); raise "
                "Kp_current or leave both unset")
        terms = current_loop_terms(self)
        radius = 0.0 if loop_surely_stable(*terms) else loop_radius(*terms)
        # A pole at 1 within rounding is the integrator of a lossless winding (R -> 0).
        if not radius <= 1.0 + 1e-9:
            hint = ("leave Kp_current and Ki_current unset to derive stable gains"
                    if self.drive.Kp_current is not None or self.drive.Ki_current is not None
                    else "lower current_bandwidth_hz")
            raise ParameterError(
                f"Kp_current={kp:.4g} V/A, Ki_current={ki:.4g} V/(A*s) make the sampled current "
                f"loop unstable (pole radius {radius:.4g}, allowed <= 1) with R={self.motor.R:.4g} "
                f"Ohm, L={self.motor.L:.4g} H, pwm_hz={self.drive.pwm_hz:.4g}; {hint}")

    # -- flat view -------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Flat dict of every field as set (``None`` = derived) plus ``name``.

        Loading it back with :meth:`from_dict` gives an equal system; the gains in
        use are in :meth:`derived_dict`. ``drive_mode`` is left out while it is
        the default ``"current"``, so the files and leaderboards written before it
        existed stay the same byte for byte.
        """
        out: dict[str, Any] = {"name": self.name}
        out.update(dataclasses.asdict(self.motor))
        out.update(dataclasses.asdict(self.drive))
        out.update(dataclasses.asdict(self.servo))
        if out["drive_mode"] == "current":
            del out["drive_mode"]
        return out

    def derived_dict(self) -> dict[str, float]:
        """The gains in use and the resonance prediction, SI units."""
        kp, ki = self.current_gains()
        kv, kpp, kip = self.servo_gains()
        return {"Kp_current": kp, "Ki_current": ki, "Kp_vel": kv, "Kp_pos": kpp,
                "Ki_pos": kip, "natural_frequency_rad_s": self.natural_frequency()}

    @classmethod
    def from_dict(cls, values: Mapping[str, Any], base: "SystemParams | None" = None
                  ) -> "SystemParams":
        """Build from a flat mapping of model fields (and metadata keys); missing
        fields come from ``base``. Without ``base`` every motor field without a
        default must be given (the drive's and servo's come from their defaults).
        A mapping that names a preset as ``"base"`` or gives datasheet values is a
        motor file's: :func:`stepdamp_env.motorfile.load_system` reads it."""
        meta = set(META_KEYS) - {"base"}
        unknown = sorted(set(values) - set(ALL_FIELDS) - meta)
        if unknown:
            raise ParameterError(
                f"unknown parameter(s) {unknown}; allowed: {list(ALL_FIELDS)} and metadata keys "
                f"{sorted(meta)} (a preset base or datasheet keys: load_system)")
        name = base.name if base is not None else "custom"
        if base is None:
            missing = [f.name for f in fields(MotorParams) if f.name not in values
                       and f.default is dataclasses.MISSING]
            if missing:
                raise ParameterError(f"motor field(s) {missing} missing; give base= or load the "
                                     "mapping with load_system (a preset base for the rest)")
            base_fields: dict[str, Any] = {}
        else:   # shallow copies: every field is a number or a string
            base_fields = {**vars(base.motor), **vars(base.drive), **vars(base.servo)}

        def part(cls_: type, names: tuple[str, ...], record: str) -> Any:
            if base is not None and not any(k in values for k in names):
                return getattr(base, record)    # unchanged: validated already
            return cls_(**{k: values[k] if k in values else base_fields[k] for k in names
                           if k in values or k in base_fields})

        return cls(part(MotorParams, MOTOR_FIELDS, "motor"),
                   part(DriveParams, DRIVE_FIELDS, "drive"),
                   part(ServoParams, SERVO_FIELDS, "servo"), name=str(values.get("name", name)))

    def replace(self, **overrides: Any) -> "SystemParams":
        """Copy with some flat fields changed (validated like construction)."""
        return SystemParams.from_dict({"name": self.name, **overrides}, base=self)

    # -- derived quantities ----------------------------------------------------
    def current_gains(self) -> CurrentGains:
        """(kp, ki) of the d and q current PI loops in V/A and V/(A*s)."""
        gains = self.__dict__.get("_current_gains")     # absent in a pickle of 0.18.0
        return gains if gains is not None else self._derive_current_gains()

    def _derive_current_gains(self) -> CurrentGains:
        dt = 1.0 / self.drive.pwm_hz
        g = delayed_loop_gain(self.drive.current_bandwidth_hz * dt)
        x = self.motor.R * dt / self.motor.L
        # 1 - exp(-x) as v0 computed it; expm1 only where that cancels to 0.
        one_minus_pole = 1.0 - fm.exp(-x) if x > 1e-8 else -fm.expm1(-x)
        if one_minus_pole > 0.0:
            kp = g * self.motor.R / one_minus_pole
            ki = kp * one_minus_pole / dt
        else:                           # R*dt/L underflows: the lossless limit
            kp, ki = g * self.motor.L / dt, 0.0
        if self.drive.Kp_current is not None:
            kp = self.drive.Kp_current
        if self.drive.Ki_current is not None:
            ki = self.drive.Ki_current
        return CurrentGains(kp, ki)

    def servo_gains(self) -> ServoGains:
        """(Kp_vel, Kp_pos, Ki_pos) of eq. 15 in N*m*s/rad, N*m/rad, N*m/(rad*s)."""
        ws = 2.0 * math.pi * self.servo.velocity_cutoff_hz / 5.0
        J = self.motor.J
        kv = self.servo.Kp_vel if self.servo.Kp_vel is not None else 3.0 * J * ws
        kp = self.servo.Kp_pos if self.servo.Kp_pos is not None else 3.0 * J * ws * ws
        ki = self.servo.Ki_pos if self.servo.Ki_pos is not None else J * ws * ws * ws
        return ServoGains(kv, kp, ki)

    def natural_frequency(self) -> float:
        """Open-loop rotor resonance wn = sqrt(Km*holding_current*Nr/J) (rad/s)."""
        m = self.motor
        return math.sqrt(m.Km * self.drive.holding_current * m.Nr / m.J)

    def predicted_resonances_rps(self) -> dict[int, float]:
        """Shaft speeds wn/(h*Nr) for h = 4, 2, 1, in rev/s (lowest first)."""
        return predicted_resonances(self)


#: Smallest current-loop gain (V/A) a drive may have; the anti-windup divides by it.
MIN_KP_CURRENT = 1e-6

# Detent harmonics of the model, in the order of its sin/cos coefficients.
DETENT_HARMONICS = (1, 2, 4)
# The same harmonics in the order of their resonant speeds (lowest speed first).
RESONANCE_HARMONICS = (4, 2, 1)


def predicted_resonances(system: SystemParams) -> dict[int, float]:
    """Speeds (rev/s) at which detent harmonic h excites the rotor resonance.

    Detent harmonic h acts at h*Nr*w_shaft; it meets wn when
    w_shaft = wn/(h*Nr) (docs/model.md, "Frames, the holding spring and the resonances"). Keys are h = 4, 2, 1.
    """
    wn = system.natural_frequency()
    return {h: wn / (h * system.motor.Nr) / (2.0 * math.pi) for h in RESONANCE_HARMONICS}


@dataclass(frozen=True)
class FeedforwardModel:
    """The controller's own estimate of the motor, used by the feedforward.

    It may differ from the plant on purpose (model mismatch). Fields as in
    :class:`MotorParams`: Km (N*m/A), Kd1, Kd2, Kd4, Fs (N*m), phi1, phi2 (rad).
    """

    # Each estimate has the allowed range of the motor field it estimates.
    Km: float = field(metadata=_same_range_as(MotorParams, "Km"))
    Kd1: float = field(metadata=_same_range_as(MotorParams, "Kd1"))
    Kd2: float = field(metadata=_same_range_as(MotorParams, "Kd2"))
    Kd4: float = field(metadata=_same_range_as(MotorParams, "Kd4"))
    phi1: float = field(metadata=_same_range_as(MotorParams, "phi1"))
    phi2: float = field(metadata=_same_range_as(MotorParams, "phi2"))
    Fs: float = field(metadata=_same_range_as(MotorParams, "Fs"))

    def __post_init__(self) -> None:
        _validate_fields(self)

    @classmethod
    def from_motor(cls, motor: MotorParams) -> "FeedforwardModel":
        """The exact estimate: the plant's own values."""
        return cls(Km=motor.Km, Kd1=motor.Kd1, Kd2=motor.Kd2, Kd4=motor.Kd4,
                   phi1=motor.phi1, phi2=motor.phi2, Fs=motor.Fs)

    def coefficients(self) -> tuple[float, float, float, float, float, float]:
        """Detent model as sin/cos coefficients (N*m) of harmonics 1, 2, 4.

        Kd_h*sin(h*x + phi_h) = Kd_h*cos(phi_h)*sin(h*x) + Kd_h*sin(phi_h)*cos(h*x);
        returned as (s1, c1, s2, c2, s4, c4) with phi4 = 0.
        """
        return detent_coefficients(self)


def detent_coefficients(model: "MotorParams | FeedforwardModel"
                        ) -> tuple[float, float, float, float, float, float]:
    """:meth:`FeedforwardModel.coefficients` of a motor's or a model's detent fields."""
    return (model.Kd1 * fm.cos(model.phi1), model.Kd1 * fm.sin(model.phi1),
            model.Kd2 * fm.cos(model.phi2), model.Kd2 * fm.sin(model.phi2),
            model.Kd4, 0.0)
