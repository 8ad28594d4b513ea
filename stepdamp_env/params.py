"""Validated parameter sets of the drive: motor, power stage and current loop, servo.

Parameters are what a domain randomiser changes; they never change during a run.
Every field is SI (A, V, Ohm, H, N*m, rad, rad/s, kg*m^2, s, Hz) and is checked at
construction: a bad value raises ``ValueError`` naming the field and its allowed
range. The flat field names below are the public vocabulary of the API, of motor
JSON files and of ``stepdamp ... --set FIELD=VALUE``.

Motor (eqs. 1-4 and 9 of US 7,733,051, as corrected in physics-notes.md):
    R, L, Km, Nr, J, D, Kd1, Kd2, Kd4, phi1, phi2, Fs, load_torque
Drive: Vdc, pwm_hz, holding_current, microsteps, current_bandwidth_hz,
    Kp_current, Ki_current, current_noise_a, current_offset_a, current_offset_b
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
import json
import math
import os
from dataclasses import dataclass, field, fields
from typing import Any, Iterable, Mapping

__all__ = [
    "MotorParams",
    "DriveParams",
    "ServoParams",
    "SystemParams",
    "FeedforwardModel",
    "ParameterError",
    "PRESETS",
    "preset_names",
    "get_preset",
    "load_system",
    "parse_set_overrides",
    "predicted_resonances",
    "DETENT_HARMONICS",
    "RESONANCE_HARMONICS",
]


class ParameterError(ValueError):
    """A parameter is outside its allowed range or unknown."""


_INF = math.inf


def _check_range(name: str, value: Any, low: float, high: float, *,
                 low_open: bool = False, high_open: bool = False,
                 integer: bool = False) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"{name} must be a number, got {value!r}")
    if integer and float(value) != int(value):
        raise ParameterError(f"{name} must be an integer, got {value!r}")
    if not math.isfinite(value):
        raise ParameterError(f"{name} must be finite, got {value!r}")
    lo_ok = value > low if low_open else value >= low
    hi_ok = value < high if high_open else value <= high
    if not (lo_ok and hi_ok):
        lo_b = "(" if low_open else "["
        hi_b = ")" if high_open else "]"
        raise ParameterError(
            f"{name}={value!r} is outside its allowed range {lo_b}{low}, {high}{hi_b}")


# (field, low, high, low_open, high_open, integer): the allowed range of each field.
_RANGES: dict[str, tuple[float, float, bool, bool, bool]] = {
    # motor
    "R": (0.0, 1e3, True, False, False),
    "L": (0.0, 10.0, True, False, False),
    "Km": (0.0, 100.0, True, False, False),
    "Nr": (1, 1000, False, False, True),
    "J": (0.0, 10.0, True, False, False),
    "D": (0.0, 100.0, False, False, False),
    "Kd1": (0.0, 100.0, False, False, False),
    "Kd2": (0.0, 100.0, False, False, False),
    "Kd4": (0.0, 100.0, False, False, False),
    "phi1": (-2 * math.pi, 2 * math.pi, False, False, False),
    "phi2": (-2 * math.pi, 2 * math.pi, False, False, False),
    "Fs": (0.0, 100.0, False, False, False),
    "load_torque": (-100.0, 100.0, False, False, False),
    # drive
    "Vdc": (0.0, 1e4, True, False, False),
    "pwm_hz": (1e3, 1e6, False, False, False),
    "holding_current": (0.0, 100.0, True, False, False),
    "microsteps": (1, 65536, False, False, True),
    "current_bandwidth_hz": (0.0, _INF, True, True, False),
    "Kp_current": (0.0, 1e6, True, False, False),
    "Ki_current": (0.0, 1e9, False, False, False),
    "current_noise_a": (0.0, 100.0, False, False, False),
    "current_offset_a": (-100.0, 100.0, False, False, False),
    "current_offset_b": (-100.0, 100.0, False, False, False),
    # servo
    "encoder_cpr": (1, 1 << 30, False, False, True),
    "velocity_cutoff_hz": (0.0, _INF, True, True, False),
    "Kp_vel": (0.0, 1e6, False, False, False),
    "Kp_pos": (0.0, 1e9, False, False, False),
    "Ki_pos": (0.0, 1e12, False, False, False),
    "kalman_accel_std": (0.0, 1e9, True, False, False),
}


def _validate_fields(obj: Any) -> None:
    for f in fields(obj):
        value = getattr(obj, f.name)
        if value is None:
            continue
        low, high, low_open, high_open, integer = _RANGES[f.name]
        _check_range(f.name, value, low, high, low_open=low_open,
                     high_open=high_open, integer=integer)
        if integer:
            object.__setattr__(obj, f.name, int(value))
        else:
            object.__setattr__(obj, f.name, float(value))


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

    R: float
    L: float
    Km: float
    Nr: int
    J: float
    D: float
    Kd1: float
    Kd2: float
    Kd4: float
    phi1: float
    phi2: float
    Fs: float
    load_torque: float = 0.0

    def __post_init__(self) -> None:
        _validate_fields(self)

    @property
    def full_step_rad(self) -> float:
        """Shaft angle of one full step, 2*pi/(4*Nr) (rad); 1.8 degree for Nr = 50."""
        return 2.0 * math.pi / (4 * self.Nr)


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
    """

    Vdc: float = 48.0
    pwm_hz: float = 20_000.0
    holding_current: float = 1.9
    microsteps: int = 64
    current_bandwidth_hz: float = 1_500.0
    Kp_current: float | None = None
    Ki_current: float | None = None
    current_noise_a: float = 0.0
    current_offset_a: float = 0.0
    current_offset_b: float = 0.0

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

    encoder_cpr: int = 4000
    velocity_cutoff_hz: float = 100.0
    Kp_vel: float | None = None
    Kp_pos: float | None = None
    Ki_pos: float | None = None
    kalman_accel_std: float = 2000.0

    def __post_init__(self) -> None:
        _validate_fields(self)


MOTOR_FIELDS = tuple(f.name for f in fields(MotorParams))
DRIVE_FIELDS = tuple(f.name for f in fields(DriveParams))
SERVO_FIELDS = tuple(f.name for f in fields(ServoParams))
ALL_FIELDS = MOTOR_FIELDS + DRIVE_FIELDS + SERVO_FIELDS
# Keys a motor file may carry besides the fields: where it starts from and what it is.
META_KEYS = ("base", "name", "source", "notes")


@dataclass(frozen=True)
class SystemParams:
    """Motor, drive and servo parameters of one simulated system."""

    motor: MotorParams
    drive: DriveParams = field(default_factory=DriveParams)
    servo: ServoParams = field(default_factory=ServoParams)
    name: str = "custom"

    def __post_init__(self) -> None:
        if self.drive.pwm_hz / 2 <= self.servo.velocity_cutoff_hz:
            raise ParameterError(
                f"velocity_cutoff_hz={self.servo.velocity_cutoff_hz} is outside its allowed "
                f"range (0, pwm_hz/2 = {self.drive.pwm_hz / 2})")

    # -- flat view -------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Flat dict of every field as set (``None`` = derived) plus ``name``.

        Loading it back with :meth:`from_dict` gives an equal system; the gains in
        use are in :meth:`derived_dict`.
        """
        out: dict[str, Any] = {"name": self.name}
        out.update(dataclasses.asdict(self.motor))
        out.update(dataclasses.asdict(self.drive))
        out.update(dataclasses.asdict(self.servo))
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
        """Build from a flat mapping; missing fields come from ``base``."""
        unknown = sorted(set(values) - set(ALL_FIELDS) - set(META_KEYS))
        if unknown:
            raise ParameterError(
                f"unknown parameter(s) {unknown}; allowed: {list(ALL_FIELDS)} "
                f"and metadata keys {list(META_KEYS)}")
        if base is None:
            base = get_preset(str(values.get("base", "patent")))
        motor = {**dataclasses.asdict(base.motor),
                 **{k: values[k] for k in MOTOR_FIELDS if k in values}}
        drive = {**dataclasses.asdict(base.drive),
                 **{k: values[k] for k in DRIVE_FIELDS if k in values}}
        servo = {**dataclasses.asdict(base.servo),
                 **{k: values[k] for k in SERVO_FIELDS if k in values}}
        return cls(MotorParams(**motor), DriveParams(**drive), ServoParams(**servo),
                   name=str(values.get("name", base.name)))

    def replace(self, **overrides: Any) -> "SystemParams":
        """Copy with some flat fields changed (validated like construction)."""
        return SystemParams.from_dict({"name": self.name, **overrides}, base=self)

    # -- derived quantities ----------------------------------------------------
    def current_gains(self) -> tuple[float, float]:
        """(Kp, Ki) of the d and q current PI loops in V/A and V/(A*s)."""
        dt = 1.0 / self.drive.pwm_hz
        g = delayed_loop_gain(self.drive.current_bandwidth_hz * dt)
        pole = math.exp(-self.motor.R * dt / self.motor.L)
        kp = g * self.motor.R / (1.0 - pole)
        ki = kp * (1.0 - pole) / dt
        if self.drive.Kp_current is not None:
            kp = self.drive.Kp_current
        if self.drive.Ki_current is not None:
            ki = self.drive.Ki_current
        return kp, ki

    def servo_gains(self) -> tuple[float, float, float]:
        """(Kp_vel, Kp_pos, Ki_pos) of eq. 15 in N*m*s/rad, N*m/rad, N*m/(rad*s)."""
        ws = 2.0 * math.pi * self.servo.velocity_cutoff_hz / 5.0
        J = self.motor.J
        kv = self.servo.Kp_vel if self.servo.Kp_vel is not None else 3.0 * J * ws
        kp = self.servo.Kp_pos if self.servo.Kp_pos is not None else 3.0 * J * ws ** 2
        ki = self.servo.Ki_pos if self.servo.Ki_pos is not None else J * ws ** 3
        return kv, kp, ki

    def natural_frequency(self) -> float:
        """Open-loop rotor resonance wn = sqrt(Km*holding_current*Nr/J) (rad/s)."""
        m = self.motor
        return math.sqrt(m.Km * self.drive.holding_current * m.Nr / m.J)

    def predicted_resonances_rps(self) -> dict[int, float]:
        """Shaft speeds wn/(h*Nr) for h = 4, 2, 1, in rev/s (lowest first)."""
        return predicted_resonances(self)


def delayed_loop_gain(bandwidth_per_sample: float) -> float:
    """Loop gain g for which g/(z^2 - z + g) is -3 dB at ``bandwidth_per_sample``.

    The argument is the bandwidth over the sample rate (f_c/f_s). From
    |z^2 - z + g|^2 = 2 g^2 at z = exp(j*2*pi*f_c/f_s): with A = z^2 - z,
    g^2 - 2 Re(A) g - |A|^2 = 0.
    """
    theta = 2.0 * math.pi * bandwidth_per_sample
    a = complex(math.cos(2 * theta), math.sin(2 * theta)) - complex(math.cos(theta),
                                                                    math.sin(theta))
    return a.real + math.sqrt(a.real ** 2 + abs(a) ** 2)


# Detent harmonics of the model, in the order of its sin/cos coefficients.
DETENT_HARMONICS = (1, 2, 4)
# The same harmonics in the order of their resonant speeds (lowest speed first).
RESONANCE_HARMONICS = (4, 2, 1)


def predicted_resonances(system: SystemParams) -> dict[int, float]:
    """Speeds (rev/s) at which detent harmonic h excites the rotor resonance.

    Detent harmonic h acts at h*Nr*w_shaft; it meets wn when
    w_shaft = wn/(h*Nr) (physics-notes.md section 4). Keys are h = 4, 2, 1.
    """
    wn = system.natural_frequency()
    return {h: wn / (h * system.motor.Nr) / (2.0 * math.pi) for h in RESONANCE_HARMONICS}


@dataclass(frozen=True)
class FeedforwardModel:
    """The controller's own estimate of the motor, used by the feedforward.

    It may differ from the plant on purpose (model mismatch). Fields as in
    :class:`MotorParams`: Km (N*m/A), Kd1, Kd2, Kd4, Fs (N*m), phi1, phi2 (rad).
    """

    Km: float
    Kd1: float
    Kd2: float
    Kd4: float
    phi1: float
    phi2: float
    Fs: float

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
        return (self.Kd1 * math.cos(self.phi1), self.Kd1 * math.sin(self.phi1),
                self.Kd2 * math.cos(self.phi2), self.Kd2 * math.sin(self.phi2),
                self.Kd4, 0.0)


# ---------------------------------------------------------------------------
# Presets
# ---------------------------------------------------------------------------

def _patent() -> SystemParams:
    """The system of US 7,733,051.

    From the patent: Km = 0.3 N*m/A and Nr = 50 (section A), D = 0.001 N*m*s/rad
    (eq. 9), holding current 1.9 A (eq. 7), 20 kHz PWM and control rate, a
    4000 count/rev encoder (section C), microstepping 1/64 (description).
    Chosen here (the patent is silent), values of a 57 mm (NEMA 23) hybrid
    stepper of that torque constant: R = 1.2 Ohm, L = 3.6 mH, 48 V bus;
    J = 4.0e-5 kg*m^2, a rotor of about 1.2e-5 plus a rigidly coupled load of
    2.8e-5, which puts the three resonances at about 0.58, 1.2 and 2.3 rev/s;
    detent harmonics Kd4 = 0.012 N*m (2 % of the 0.57 N*m holding torque at
    1.9 A), Kd2 = 0.006 N*m with phi2 = 0.6 rad, Kd1 = 0.004 N*m with
    phi1 = -1.1 rad (the manufacturing imperfections that give a real motor its
    2nd and 1st harmonic resonances); Fs = 0.004 N*m.
    """
    motor = MotorParams(R=1.2, L=3.6e-3, Km=0.3, Nr=50, J=4.0e-5, D=0.001,
                        Kd1=0.004, Kd2=0.006, Kd4=0.012, phi1=-1.1, phi2=0.6,
                        Fs=0.004, load_torque=0.0)
    drive = DriveParams(Vdc=48.0, pwm_hz=20_000.0, holding_current=1.9, microsteps=64,
                        current_bandwidth_hz=1_500.0)
    return SystemParams(motor, drive, ServoParams(encoder_cpr=4000), name="patent")


# Real motors. Datasheet figures are quoted beside the numbers; the rest is
# marked ASSUMED. Conventions used for every datasheet preset:
# * holding torque is taken with both phases at the rated RMS current, so the
#   sinusoidal-microstep amplitude is sqrt(2)*I_rated (that is holding_current)
#   and Km = T_hold / (sqrt(2)*I_rated), giving Km*holding_current = T_hold;
# * the datasheet detent torque is the peak of the detent curve, split ASSUMED
#   60 % / 25 % / 15 % over the 4th / 2nd / 1st harmonic, phases ASSUMED;
# * J = rotor inertia plus an ASSUMED rigidly coupled load of nine times the
#   rotor's (10:1 total to rotor, the usual upper end for open-loop steppers;
#   lighter loads push the resonances to speeds where the drive's own
#   electrical dynamics shift the peaks further from the rigid-spring formula);
# * D ASSUMED so that the mechanical damping ratio D/(2*sqrt(Km*I*Nr*J)) is
#   0.02, a lightly damped rig like the patent's; Fs ASSUMED about 1 % of T_hold.
# The detent also modulates the spring by +-4*Nr*Kd4; past a modulation depth
# eps = 4*Kd4/T_hold of about 4*zeta that drives a parametric (Mathieu)
# resonance at the h=2 speed which no feedforward at the command angle removes
# (README, "Known limits"): the QSH4218-35-10-027 (eps = 0.2) is left out for that.
_SQRT2 = math.sqrt(2.0)


def _datasheet_motor(*, name: str, i_rated: float, r: float, l: float, t_hold: float,
                     detent: float, j_rotor: float, vdc: float,
                     fs: float, phi1: float, phi2: float) -> SystemParams:
    j = 10.0 * j_rotor
    stiffness = t_hold * 50          # Km*holding_current*Nr, N*m/rad
    d = 2.0 * 0.02 * math.sqrt(stiffness * j)
    motor = MotorParams(R=r, L=l, Km=t_hold / (_SQRT2 * i_rated), Nr=50, J=j, D=d,
                        Kd1=0.15 * detent, Kd2=0.25 * detent, Kd4=0.6 * detent,
                        phi1=phi1, phi2=phi2, Fs=fs, load_torque=0.0)
    drive = DriveParams(Vdc=vdc, pwm_hz=20_000.0, holding_current=_SQRT2 * i_rated,
                        microsteps=64, current_bandwidth_hz=1_500.0)
    return SystemParams(motor, drive, ServoParams(encoder_cpr=4000), name=name)


def _qsh4218_51_10_049() -> SystemParams:
    """Trinamic QSH4218-51-10-049, NEMA 17, 1.8 degree.

    Source: Trinamic "QMot QSH4218 manual" V1.10, table 2.1: rated current
    1.0 A RMS, 5.0 Ohm, 8.0 mH, holding torque 0.49 N*m, detent torque
    28 mN*m, rotor inertia 68 g*cm^2; torque curve measured at 24 V (Vdc).
    """
    return _datasheet_motor(name="qsh4218-51-10-049", i_rated=1.0, r=5.0, l=8.0e-3,
                            t_hold=0.49, detent=0.028, j_rotor=68e-7, vdc=24.0, fs=0.005, phi1=0.9, phi2=-0.5)


def _qsh5718_56_28_126() -> SystemParams:
    """Trinamic QSH5718-56-28-126, NEMA 23, 1.8 degree.

    Source: Trinamic "QMot QSH5718 manual" V2.6, table 2.1: rated current
    2.8 A RMS, 0.9 Ohm, 2.5 mH, holding torque 1.26 N*m, detent torque
    0.039 N*m, rotor inertia 300 g*cm^2; torque curve measured at 30 V (Vdc).
    """
    return _datasheet_motor(name="qsh5718-56-28-126", i_rated=2.8, r=0.9, l=2.5e-3,
                            t_hold=1.26, detent=0.039, j_rotor=300e-7, vdc=30.0, fs=0.012, phi1=0.3, phi2=2.0)


def _qsh6018_65_28_210() -> SystemParams:
    """Trinamic QSH6018-65-28-210, 60 mm flange, 1.8 degree.

    Source: Trinamic "QMot QSH6018 manual" V1.20, table 1.1: rated current
    2.8 A RMS, 1.2 Ohm, 4.6 mH, holding torque 2.1 N*m, rotor inertia
    570 g*cm^2; torque curves measured at 30 V (Vdc). The datasheet leaves the
    detent torque blank: ASSUMED 0.06 N*m (about 3 % of T_hold, in line with
    the family's smaller motors).
    """
    return _datasheet_motor(name="qsh6018-65-28-210", i_rated=2.8, r=1.2, l=4.6e-3,
                            t_hold=2.1, detent=0.06, j_rotor=570e-7, vdc=30.0, fs=0.02, phi1=-1.3, phi2=0.4)


PRESETS: dict[str, Any] = {
    "patent": _patent,
    "qsh4218-51-10-049": _qsh4218_51_10_049,
    "qsh5718-56-28-126": _qsh5718_56_28_126,
    "qsh6018-65-28-210": _qsh6018_65_28_210,
}


def preset_names() -> list[str]:
    """Names accepted by :func:`get_preset` and by ``--motor``."""
    return sorted(PRESETS)


def get_preset(name: str) -> SystemParams:
    """A preset system by name; ``ParameterError`` lists the names on a miss."""
    try:
        factory = PRESETS[name]
    except KeyError:
        raise ParameterError(
            f"unknown motor preset {name!r}; choose one of {preset_names()} "
            "or give a path to a motor .json file") from None
    return factory()


def load_system(spec: str | os.PathLike[str] | Mapping[str, Any] | SystemParams,
                overrides: Mapping[str, Any] | None = None) -> SystemParams:
    """Resolve a preset name, a motor JSON file or a mapping to a SystemParams.

    A JSON file (or mapping) holds any of the flat field names; the others come
    from the preset named by its optional ``"base"`` key (``"patent"`` if absent).
    ``overrides`` (flat field names, e.g. from ``--set``) are applied last.
    """
    if isinstance(spec, SystemParams):
        system = spec
    elif isinstance(spec, Mapping):
        system = SystemParams.from_dict(spec)
    else:
        text = os.fspath(spec)
        if text.endswith(".json") or os.path.sep in text or os.path.isfile(text):
            if not os.path.isfile(text):
                raise ParameterError(f"motor file {text!r} does not exist")
            with open(text, encoding="utf-8") as fh:
                try:
                    values = json.load(fh)
                except json.JSONDecodeError as exc:
                    raise ParameterError(f"motor file {text!r} is not valid JSON: {exc}"
                                         ) from None
            if not isinstance(values, dict):
                raise ParameterError(f"motor file {text!r} must hold a JSON object")
            values.setdefault("name", os.path.splitext(os.path.basename(text))[0])
            system = SystemParams.from_dict(values)
        else:
            system = get_preset(text)
    if overrides:
        system = system.replace(**overrides)
    return system


def parse_set_overrides(items: Iterable[str]) -> dict[str, float]:
    """Parse ``FIELD=VALUE`` strings (``--set``) into a dict of numbers."""
    out: dict[str, float] = {}
    for item in items:
        name, sep, raw = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise ParameterError(f"--set expects FIELD=VALUE, got {item!r}")
        if name not in ALL_FIELDS:
            raise ParameterError(f"--set: unknown parameter {name!r}; allowed: "
                                 f"{list(ALL_FIELDS)}")
        try:
            value = float(raw)
        except ValueError:
            raise ParameterError(f"--set {name}: {raw!r} is not a number") from None
        out[name] = int(value) if value.is_integer() and _RANGES[name][4] else value
    return out
