"""The protocol's motors and each motor's speed grid (see :mod:`.protocol`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..params import ParameterError, SystemParams
from ..presets import get_preset
from ..simulation import RunSettings, SpeedProfile, simulate
from .protocol import PHASE_FIELDS, SUITES, Protocol

__all__ = ["ProtocolMotor", "protocol_motors", "speed_grid", "with_sensors"]


@dataclass(frozen=True)
class ProtocolMotor:
    """One motor of the protocol: the true plant and what a drive may know."""

    name: str
    system: SystemParams        # true plant, with the protocol's sensors
    nominal: SystemParams       # the preset it was drawn around (same sensors)
    speeds_rps: tuple[float, ...]
    speed_labels: tuple[str, ...]   # "h4", "h2", "h1" or "off"
    draw_attempts: int = 0          # draws it took (0 for a preset)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "nominal": self.nominal.name,
                "parameters": self.system.to_dict(),
                "speeds_rps": list(self.speeds_rps), "speed_labels": list(self.speed_labels),
                "draw_attempts": self.draw_attempts,
                "predicted_resonances_rps": {str(h): v for h, v in
                                             self.system.predicted_resonances_rps().items()}}


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


_MOTOR_CACHE: dict[Protocol, tuple[ProtocolMotor, ...]] = {}


def protocol_motors(protocol: Protocol) -> tuple[ProtocolMotor, ...]:
    """The protocol's motors: presets first, then the draws (deterministic)."""
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
                changes: dict[str, Any] = {"name": f"{name}~r{k}"}
                for field_name, lo, hi in protocol.randomization:
                    x = float(rng.uniform(lo, hi))
                    changes[field_name] = x if field_name in PHASE_FIELDS else \
                        getattr(nom.motor, field_name) * x
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
