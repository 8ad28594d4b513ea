"""The protocol's motors and each motor's speed grid (see :mod:`.protocol`)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from .. import fixedmath as fm
from ..analysis import midband
from ..params import ParameterError, SystemParams
from ..presets import get_preset
from ..simulation import RunSettings, SpeedProfile, simulate
from .protocol import PHASE_FIELDS, SUITE_DRIVE_MODE, SUITES, Protocol
from .protocol_v1 import ProtocolV1, ProtocolV2, Shift

__all__ = ["ProtocolMotor", "protocol_motors", "protocol_v1_motors", "speed_grid",
           "servo_grid", "midband_grid", "settle_times", "with_sensors", "holds_its_load",
           "in_training_distribution"]


@dataclass(frozen=True)
class ProtocolMotor:
    """One motor of the protocol: the true plant and what a drive may know."""

    name: str
    system: SystemParams        # true plant, with the protocol's sensors
    nominal: SystemParams       # the preset it was drawn around (same sensors)
    speeds_rps: tuple[float, ...]
    speed_labels: tuple[str, ...]   # "h4", "h2", "h1" or "off"
    draw_attempts: int = 0          # draws it took (0 for a preset)
    # v1 only (None / empty in v0): split, bootstrap stratum, per-suite grids and settling.
    split: str | None = None
    family: str | None = None
    grids: tuple[tuple[str, tuple[float, ...], tuple[str, ...]], ...] = ()
    settle: tuple[tuple[str, float], ...] = ()

    def speeds(self, suite: str) -> tuple[tuple[float, ...], tuple[str, ...]]:
        """(speeds in rev/s, labels) of a suite (v0: one grid for both)."""
        for name, speeds, labels in self.grids:
            if name == suite:
                return speeds, labels
        return self.speeds_rps, self.speed_labels

    def settle_s(self, suite: str) -> float | None:
        """Settling before the window (s); None: the core's default (v0)."""
        return dict(self.settle).get(suite)

    def for_suite(self, suite: str) -> "ProtocolMotor":
        """This motor as a suite runs it: the plant and the nominal model with the
        suite's ``drive_mode`` (the drive knows its own mode)."""
        mode = SUITE_DRIVE_MODE[suite]
        if self.system.drive.drive_mode == mode:
            return self
        return dataclasses.replace(self, system=self.system.replace(drive_mode=mode),
                                   nominal=self.nominal.replace(drive_mode=mode))

    def to_dict(self) -> dict[str, Any]:
        out = {"name": self.name, "nominal": self.nominal.name,
               "parameters": self.system.to_dict(),
               "speeds_rps": list(self.speeds_rps), "speed_labels": list(self.speed_labels),
               "draw_attempts": self.draw_attempts,
               "predicted_resonances_rps": {str(h): v for h, v in
                                            self.system.predicted_resonances_rps().items()}}
        if self.split is not None:
            out.update({"split": self.split, "family": self.family,
                        "nominal_parameters": self.nominal.to_dict(),
                        "grids": {s: {"speeds_rps": list(v), "speed_labels": list(lb)}
                                  for s, v, lb in self.grids},
                        "settle_s": dict(self.settle)})
        return out


def with_sensors(system: SystemParams, protocol: Protocol) -> SystemParams:
    return system.replace(current_noise_a=protocol.current_noise_a,
                          encoder_cpr=protocol.encoder_cpr)


def speed_grid(system: SystemParams, protocol: Protocol) -> tuple[tuple[float, ...],
                                                                  tuple[str, ...]]:
    """(speeds in rev/s ascending, labels) of one motor."""
    res = system.predicted_resonances_rps()
    points = [(res[h], f"h{h}") for h in protocol.resonance_harmonics]
    points += [(res[h] * f, "off") for h, f in protocol.off_resonance]
    points.sort(key=lambda p: p[0])
    return tuple(float(v) for v, _ in points), tuple(lbl for _, lbl in points)


def _usable(system: SystemParams, speeds: Sequence[float], protocol: Protocol) -> bool:
    """No undamped run of the grid lags by half a full step or more (both suites)."""
    for mode in SUITES:
        settings = RunSettings(mode=mode, damping="none", window_s=protocol.window_s,
                               noise_seed=protocol.validation_noise_seed)
        for v in speeds:
            try:
                res = simulate(system, profile=SpeedProfile(speed_rps=v,
                                                            accel_rps2=protocol.accel_rps2),
                               settings=settings)
            except ParameterError:      # the run diverged: as unusable as a NaN lag was
                return False
            if not res.metrics.max_position_lag_steps < protocol.usable_max_lag_steps:
                return False
    return True


_MOTOR_CACHE: dict[Any, tuple[ProtocolMotor, ...]] = {}


def protocol_motors(protocol: Protocol | ProtocolV1) -> tuple[ProtocolMotor, ...]:
    """The protocol's motors (deterministic). v0: presets first, then the draws;
    v1: the splits in the protocol's order (:func:`protocol_v1_motors`)."""
    if isinstance(protocol, ProtocolV1):
        return protocol_v1_motors(protocol)
    if protocol in _MOTOR_CACHE:
        return _MOTOR_CACHE[protocol]
    motors: list[ProtocolMotor] = []
    nominals = {name: with_sensors(get_preset(name), protocol) for name in protocol.presets}
    for name, nom in nominals.items():
        speeds, labels = speed_grid(nom, protocol)
        motors.append(ProtocolMotor(name, nom, nom, speeds, labels))
    rng = np.random.default_rng(protocol.motor_seed)
    for name, nom in nominals.items():
        for k in range(protocol.randomized_per_preset):
            for attempt in range(1, protocol.max_draw_attempts + 1):
                changes = {"name": f"{name}~r{k}",
                           **_draw(nom, rng, protocol.randomization)}
                try:
                    system = nom.replace(**changes)
                except ParameterError:
                    continue
                speeds, labels = speed_grid(system, protocol)
                if _usable(system, speeds, protocol):
                    motors.append(ProtocolMotor(system.name, system, nom, speeds, labels,
                                                attempt))
                    break
            else:
                raise RuntimeError(f"no usable draw around {name!r} in "
                                   f"{protocol.max_draw_attempts} attempts")
    _MOTOR_CACHE[protocol] = tuple(motors)
    return _MOTOR_CACHE[protocol]


# ---------------------------------------------------------------------------
# stepdamp-bench v1
# ---------------------------------------------------------------------------
def servo_grid(system: SystemParams, protocol: ProtocolV1) -> tuple[tuple[float, ...],
                                                                     tuple[str, ...]]:
    """v1's servo speeds: ``servo_factors`` x f4 (rev/s), labelled ``s<factor>``."""
    f4 = system.predicted_resonances_rps()[4]
    return (tuple(float(f * f4) for f in protocol.servo_factors),
            tuple(f"s{f:g}" for f in protocol.servo_factors))


def midband_grid(system: SystemParams, protocol: ProtocolV2
                 ) -> tuple[tuple[float, ...], tuple[str, ...]]:
    """v2's mid-band speeds (rev/s), labelled ``m<factor>``: log-spaced through the
    predicted unstable band of ``system`` in voltage mode (see :class:`ProtocolV2`)."""
    band = midband(system.replace(drive_mode="voltage"))
    if band.unstable_rps is not None:
        lo, hi = band.unstable_rps
    else:
        lo, hi = band.at_rps / 1.5, band.at_rps * 1.5
    return (tuple(float(lo * fm.exp(f * fm.log(hi / lo))) for f in protocol.midband_factors),
            tuple(f"m{f:g}" for f in protocol.midband_factors))


def slowest_decay_rate(a: float, b: float, c: float, d: float) -> float:
    """min(-Re(root)) of a s^3 + b s^2 + c s + d (1/s; <= 0 if a root is not in the
    left half-plane), in plain float arithmetic (LAPACK's eigenvalues, which
    ``np.roots`` uses, depend on the CPU in their last bits): the real root by
    bisection, then the quadratic left after dividing it out."""
    if not (a > 0.0 and b > 0.0 and c > 0.0 and d > 0.0):
        return -math.inf if not (a > 0.0 and d >= 0.0) else 0.0
    f = lambda s: ((a * s + b) * s + c) * s + d           # noqa: E731
    lo, hi = -(1.0 + max(b, c, d) / a), 0.0              # f(lo) < 0 < f(0) = d
    for _ in range(2000):
        mid = 0.5 * (lo + hi)
        if mid == lo or mid == hi:
            break
        if f(mid) > 0.0:
            hi = mid
        else:
            lo = mid
    r = 0.5 * (lo + hi)
    # a s^3 + ... = (s - r)(a s^2 + p s + q)
    p = b + a * r
    q = c + p * r
    disc = p * p - 4.0 * a * q
    if disc < 0.0:
        rest = p / (2.0 * a)                               # -Re of the complex pair
    else:
        rest = (p - math.sqrt(disc)) / (2.0 * a)           # -(the larger root)
    return min(-r, rest)


def settle_times(system: SystemParams, protocol: ProtocolV1) -> dict[str, float]:
    """v1's settling per suite (s): open loop ``settle_open_loop_decays`` decay
    times 1/(zeta*wn) = 2J/D of the undamped resonance; servo
    ``settle_servo_time_constants`` time constants of the servo loop's slowest
    pole; at least ``settle_min_s``, no upper clip."""
    m = system.motor
    decay_rate = m.D / (2.0 * m.J)
    ol = protocol.settle_open_loop_decays / decay_rate if decay_rate > 0 else math.inf
    kv, kp, ki = system.servo_gains()
    slowest = slowest_decay_rate(m.J, kv, kp, ki)      # the servo loop's
    servo = protocol.settle_servo_time_constants / slowest if slowest > 0 else math.inf
    if not math.isfinite(ol):
        raise ParameterError(f"motor {system.name!r}: D = 0 leaves its resonance undamped; "
                             "v1 settles four decay times 2J/D, so D must be > 0")
    if not math.isfinite(servo):
        raise ParameterError(f"motor {system.name!r}: its servo gains (Kp_vel, Kp_pos, "
                             "Ki_pos) leave the servo loop unstable")
    out = {"open-loop": max(ol, protocol.settle_min_s),
           "servo": max(servo, protocol.settle_min_s)}
    if isinstance(protocol, ProtocolV2):    # the open-loop rule, for the voltage drive
        out["mid-band"] = out["open-loop"]
    return out


def holds_its_load(system: SystemParams, margin: float) -> bool:
    """v1's physics rule: holding torque >= margin x (peak detent + friction + load)."""
    m = system.motor
    need = m.Kd1 + m.Kd2 + m.Kd4 + m.Fs + abs(m.load_torque)
    return m.Km * system.drive.holding_current >= margin * need


def in_training_distribution(system: SystemParams, preset: SystemParams,
                             protocol: ProtocolV1) -> bool:
    """Whether ``system`` could be a training draw around ``preset``: every
    randomised field within its range (as a factor, phases as values) and every
    other field the preset's (sensors aside)."""
    eps = 1e-12
    for name, lo, hi in protocol.training_randomization:
        x = getattr(system.motor, name)
        if name not in PHASE_FIELDS:
            x = x / getattr(preset.motor, name)
        if not lo - eps <= x <= hi + eps:
            return False
    drawn = {n for n, _, _ in protocol.training_randomization} | {"current_noise_a",
                                                                    "encoder_cpr"}
    mine, theirs = system.to_dict(), preset.to_dict()
    return all(mine[k] == theirs[k] for k in mine if k not in drawn and k != "name")


def _draw(nom: SystemParams, rng: np.random.Generator,
          ranges: Sequence[tuple[str, float, float]]) -> dict[str, Any]:
    """One draw around ``nom``, field by field in ``ranges`` order: magnitudes as
    factors of the preset's, phases as values (rad)."""
    changes: dict[str, Any] = {}
    for field_name, lo, hi in ranges:
        x = float(rng.uniform(lo, hi))
        changes[field_name] = x if field_name in PHASE_FIELDS else \
            getattr(nom.motor, field_name) * x
    return changes


def _apply_shift(nom: SystemParams, changes: dict[str, Any], shift: Shift,
                 rng: np.random.Generator) -> tuple[dict[str, Any], dict[str, Any]]:
    """(the drawn changes with the shift on top, the shift's declared part)."""
    out, declared = dict(changes), {}
    drawn = nom.replace(**changes)
    for field_name, lo, hi, how in shift.changes:
        x = float(rng.uniform(lo, hi)) if hi > lo else float(lo)
        if how == "value":
            value: Any = int(x) if field_name == "Nr" else x
        elif how == "factor":                  # of the preset's value: outside the box
            value = nom.to_dict()[field_name] * x
        else:                                   # "holding"
            value = x * drawn.motor.Km * drawn.drive.holding_current
        out[field_name] = value
        if shift.declared:
            declared[field_name] = value
    return out, declared


def _v1_motor(name: str, system: SystemParams, nominal: SystemParams, protocol: ProtocolV1,
              split: str, family: str, attempts: int) -> ProtocolMotor:
    ol = speed_grid(system, protocol)           # v1 keeps v0's open-loop grid rule
    sv = servo_grid(system, protocol)
    settle = settle_times(system, protocol)
    grids: tuple[Any, ...] = (("open-loop", *ol), ("servo", *sv))
    if isinstance(protocol, ProtocolV2):
        grids += (("mid-band", *midband_grid(system, protocol)),)
    return ProtocolMotor(name, system, nominal, ol[0], ol[1], attempts, split=split,
                         family=family, grids=grids,
                         settle=tuple((s, settle[s]) for s in settle))


def protocol_v1_motors(protocol: ProtocolV1) -> tuple[ProtocolMotor, ...]:
    """v1's motors: interpolation, then extrapolation, or the custom ones."""
    if protocol in _MOTOR_CACHE:
        return _MOTOR_CACHE[protocol]
    motors: list[ProtocolMotor] = []
    nominals = {name: with_sensors(get_preset(name), protocol) for name in protocol.presets}
    rng = np.random.default_rng(protocol.motor_seed)

    def draw(label: str, nom: SystemParams, shift: Shift | None) -> tuple[SystemParams,
                                                                          SystemParams, int]:
        for attempt in range(1, protocol.max_draw_attempts + 1):
            changes = _draw(nom, rng, protocol.training_randomization)
            declared: dict[str, Any] = {}
            if shift is not None:
                changes, declared = _apply_shift(nom, changes, shift, rng)
            try:
                system = nom.replace(name=label, **changes)
                nominal = nom.replace(**declared) if declared else nom
            except ParameterError:
                continue
            if holds_its_load(system, protocol.holding_margin):
                return system, nominal, attempt
        raise RuntimeError(f"no draw for {label!r} passes the physics rule in "
                           f"{protocol.max_draw_attempts} attempts")

    # Both splits draw from one stream, in this order, whichever splits are run.
    interp = []
    for name, nom in nominals.items():
        for k in range(protocol.interpolation_per_preset):
            interp.append((f"{name}~i{k}", *draw(f"{name}~i{k}", nom, None), name))
    pairs = protocol.extrapolation_pairs or tuple(
        (i, s.name) for s in protocol.shifts for i in range(len(protocol.presets)))
    shifts = {s.name: s for s in protocol.shifts}
    extrap = []
    for i, shift_name in pairs:
        preset = protocol.presets[i]
        label = f"{preset}~x-{shift_name}"
        extrap.append((label, *draw(label, nominals[preset], shifts[shift_name]), shift_name))
    if "interpolation" in protocol.splits:
        motors += [_v1_motor(n, s, nom, protocol, "interpolation", fam, a)
                   for n, s, nom, a, fam in interp]
    if "extrapolation" in protocol.splits:
        motors += [_v1_motor(n, s, nom, protocol, "extrapolation", fam, a)
                   for n, s, nom, a, fam in extrap]
    if "custom" in protocol.splits:
        for system in protocol.custom_motors:
            if not holds_its_load(system, protocol.holding_margin):
                m = system.motor
                need = m.Kd1 + m.Kd2 + m.Kd4 + m.Fs + abs(m.load_torque)
                raise ParameterError(
                    f"--motors: motor {system.name!r} fails the physics rule: holding torque "
                    f"{m.Km * system.drive.holding_current:.4g} N*m must be >= "
                    f"{protocol.holding_margin:g} x (Kd1 + Kd2 + Kd4 + Fs + |load_torque|) = "
                    f"{protocol.holding_margin * need:.4g} N*m")
            motors.append(_v1_motor(system.name, system, system, protocol, "custom", "custom",
                                    0))
    _MOTOR_CACHE[protocol] = tuple(motors)
    return _MOTOR_CACHE[protocol]
