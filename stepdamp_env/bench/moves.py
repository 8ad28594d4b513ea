"""The moves suite's cells (stepdamp-bench v4): point-to-point moves that
accelerate through a motor's lower resonances and cruise at a resonant speed.

A protocol that runs the suite builds its grid with :func:`moves_grid` from the
motor's open-loop grid and commands each cell with :func:`cell_command`; the
runner measures a move over its cruise and runs it until the settling after
the stop ends (:func:`.runner.move_window`). Units: rev, rev/s, rev/s^2, s.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

from ..params import SystemParams
from ..simulation import RAMPS, ramps_distance_rev

__all__ = ["moves_grid", "move_accel_rps2", "cell_command"]


def moves_grid(speeds_rps: Sequence[float], labels: Sequence[str], cruise_speeds: int = 2
               ) -> tuple[tuple[float, ...], tuple[str, ...]]:
    """The moves cells from an open-loop grid: a trapezoid and an S-curve move
    cruising at each of its ``cruise_speeds`` fastest headline speeds (f2 and f1
    where they are headline), so that the ramps pass the resonances below;
    labelled ``<speed label>-<ramp>`` (:data:`..simulation.RAMPS`)."""
    cruise = sorted(((v, lb) for v, lb in zip(speeds_rps, labels) if not lb.startswith("off")),
                    key=lambda x: -x[0])[:cruise_speeds]
    cells = [(float(v), f"{lb}-{ramp}") for v, lb in sorted(cruise) for ramp in RAMPS]
    return tuple(v for v, _ in cells), tuple(lb for _, lb in cells)


def move_accel_rps2(system: SystemParams, machine_rps2: float, torque_share: float) -> float:
    """A move's (peak) acceleration on ``system``: the machine's value, at most
    what ``torque_share`` of the holding torque gives the rotor and its load,
    ``torque_share * Km * I_hold / J / (2*pi)``."""
    m = system.motor
    limit = torque_share * m.Km * system.drive.holding_current / m.J / (2.0 * math.pi)
    return float(min(machine_rps2, limit))


def cell_command(system: SystemParams, speed_rps: float, label: str,
                 accel_rps2: dict[str, float], torque_share: float,
                 cruise_s: float) -> dict[str, Any]:
    """The :class:`.runner.EpisodeSpec` fields of the cell (``speed_rps``,
    ``label``): a move from rest with the label's ramp (peak acceleration from
    ``accel_rps2`` by ramp, :func:`move_accel_rps2`) that cruises at the
    speed for ``cruise_s`` rounded up to whole periods of the first detent
    harmonic, then stops."""
    ramp = next(r for r in RAMPS if label.endswith("-" + r))
    accel = move_accel_rps2(system, accel_rps2[ramp], torque_share)
    v = float(speed_rps)
    period = 1.0 / (system.motor.Nr * v)
    cruise = math.ceil(cruise_s / period - 1e-9) * period
    return {"profile": "move", "ramp": ramp, "accel_rps2": accel,
            "distance_rev": ramps_distance_rev(v, accel, ramp) + v * cruise}
