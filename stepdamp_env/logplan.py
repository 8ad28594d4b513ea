"""The drive logs to record for :func:`.logfit.identify_from_logs` on a motor
(``stepdamp identify --plan``; docs/drivelogs.md, "Good logs")."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from .logfit import DEFAULT_SETTLE_S, FILTER_ZERO_PER_H4
from .logstats import PRIOR_J_UNCERTAINTY
from .motorfile import load_system
from .params import SystemParams

__all__ = ["LogPlan", "PLAN_SPEEDS_PER_F4", "PRIOR_J_UNCERTAINTY", "log_plan"]


#: The speeds :func:`log_plan` asks for, as fractions of the prior's h=4
#: resonance speed: below it the rotor's inertia does not carry the detent
#: ripple, and three distinct speeds give J, D and Fs apart
#: (``benchmarks/identify_accuracy.py`` measures the result).
PLAN_SPEEDS_PER_F4 = (0.25, 0.4, 0.6)


@dataclass(frozen=True)
class LogPlan:
    """The drive logs :func:`log_plan` asks for (what ``stepdamp identify --plan`` prints).

    Attributes:
        motor: the prior motor's name.
        f4_rps: its h=4 resonance speed (rev/s), from the prior's J and holding torque.
        speeds_rps: one constant-speed log at each (rev/s; either sign, servo or
            open loop).
        durations_s: each log's length from the moment it reaches its speed (s):
            the settle plus at least 40 electrical periods, and at least 1 s.
        settle_s: the start of each log the fit leaves out (s).
        min_sample_rate_hz: sample at least this fast (10 times what the fit's
            low-pass needs at the fastest speed); one sample per PWM period is best.
    """

    motor: str
    f4_rps: float
    speeds_rps: tuple[float, ...]
    durations_s: tuple[float, ...]
    settle_s: float
    min_sample_rate_hz: float

    def to_dict(self) -> dict[str, Any]:
        return {"motor": self.motor, "f4_rps": self.f4_rps, "speeds_rps": list(self.speeds_rps),
                "durations_s": list(self.durations_s), "settle_s": self.settle_s,
                "min_sample_rate_hz": self.min_sample_rate_hz}


def log_plan(nominal: SystemParams | str, settle_s: float = DEFAULT_SETTLE_S) -> LogPlan:
    """The logs to record on ``nominal`` (the prior) for the torque balance:
    :data:`PLAN_SPEEDS_PER_F4` times its h=4 resonance speed. Below the
    resonance the harmonics hardly depend on J, and three distinct speeds give
    J, D and Fs apart; ``benchmarks/identify_accuracy.py`` measures what the
    plan identifies on the presets and a catalogue motor (docs/drivelogs.md)."""
    if not isinstance(nominal, SystemParams):
        nominal = load_system(nominal)
    f4 = nominal.predicted_resonances_rps()[4]
    nr = nominal.motor.Nr
    speeds = tuple(k * f4 for k in PLAN_SPEEDS_PER_F4)
    durations = tuple(settle_s + max(1.0, 40.0 / (nr * v)) for v in speeds)
    rate = 10.0 * 2.0 * FILTER_ZERO_PER_H4 * 4.0 * nr * max(speeds)
    return LogPlan(motor=nominal.name, f4_rps=f4, speeds_rps=speeds, durations_s=durations,
                   settle_s=float(settle_s), min_sample_rate_hz=rate)
