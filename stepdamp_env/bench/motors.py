"""A protocol's motors: :class:`ProtocolMotor`, and the pieces the versions
share to build them (sensors, the resonance speed grid, draws around a preset,
the physics rule, the servo loop's slowest pole). Each version draws its own
motors (:meth:`.protocol.Protocol.motors`); :func:`protocol_motors` keeps them."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, NamedTuple, Sequence

import numpy as np

from ..params import SystemParams
from .protocol import PHASE_FIELDS, SUITE_DRIVE_MODE, Protocol

__all__ = ["SpeedGrid", "ProtocolMotor", "protocol_motors", "speed_grid", "with_sensors", "holds_its_load",
           "draw_around", "slowest_decay_rate"]


class SpeedGrid(NamedTuple):
    """A suite's speeds of one motor and their labels (e.g. "h=4", "off-0.7")."""

    speeds_rps: tuple[float, ...]
    labels: tuple[str, ...]


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

    def speeds(self, suite: str) -> SpeedGrid:
        """The speeds (rev/s) and labels of a suite (v0: one grid for both)."""
        for name, speeds, labels in self.grids:
            if name == suite:
                return SpeedGrid(speeds, labels)
        return SpeedGrid(self.speeds_rps, self.speed_labels)

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


_MOTOR_CACHE: dict[Any, tuple[ProtocolMotor, ...]] = {}


def protocol_motors(protocol: Protocol) -> tuple[ProtocolMotor, ...]:
    """The protocol's motors (:meth:`.protocol.Protocol.motors`), drawn once per
    protocol and process."""
    if protocol not in _MOTOR_CACHE:
        _MOTOR_CACHE[protocol] = protocol.motors()
    return _MOTOR_CACHE[protocol]


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


def holds_its_load(system: SystemParams, margin: float) -> bool:
    """The physics rule of v1: holding torque >= margin x (peak detent + friction + load)."""
    m = system.motor
    need = m.Kd1 + m.Kd2 + m.Kd4 + m.Fs + abs(m.load_torque)
    return m.Km * system.drive.holding_current >= margin * need


def draw_around(nom: SystemParams, rng: np.random.Generator,
                ranges: Sequence[tuple[str, float, float]]) -> dict[str, Any]:
    """One draw around ``nom``, field by field in ``ranges`` order: magnitudes as
    factors of the preset's, phases as values (rad)."""
    changes: dict[str, Any] = {}
    for field_name, lo, hi in ranges:
        x = float(rng.uniform(lo, hi))
        changes[field_name] = x if field_name in PHASE_FIELDS else \
            getattr(nom.motor, field_name) * x
    return changes
