"""The drive logs to record for :func:`.logfit.identify_from_logs` on a motor
(``stepdamp identify --plan``; docs/drivelogs.md, "Good logs")."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .logfit import DEFAULT_SETTLE_S, FILTER_ZERO_PER_H4
from .logstats import PRIOR_J_UNCERTAINTY
from .motorfile import load_system
from .params import SystemParams
from .simulation import RunSettings, SpeedProfile, simulate

__all__ = ["LogPlan", "PLAN_SPEEDS_PER_F4", "PRIOR_J_UNCERTAINTY", "log_plan",
           "servo_reversals"]


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
        servo_stick_slip: per log, whether the prior, simulated in servo at
            that speed, stalls and reverses (stick-slip, :func:`servo_reversals`),
            which biases a servo log's fit by tens of per cent. The plan asks
            for open-loop logs: on the 27 catalogue motors (with the prior's J
            x0.6, x1 and x1.3) they identified Kd1, Kd2 and Kd4 within 2.7 %,
            the same plan in servo 40 of 81 times over 5 % (docs/drivelogs.md).
    """

    motor: str
    f4_rps: float
    speeds_rps: tuple[float, ...]
    durations_s: tuple[float, ...]
    settle_s: float
    min_sample_rate_hz: float
    servo_stick_slip: tuple[bool, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {"motor": self.motor, "f4_rps": self.f4_rps, "speeds_rps": list(self.speeds_rps),
                "durations_s": list(self.durations_s), "settle_s": self.settle_s,
                "min_sample_rate_hz": self.min_sample_rate_hz,
                "servo_stick_slip": list(self.servo_stick_slip)}


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
    stick = tuple(servo_reversals(nominal, v, d, settle_s) > 0 for v, d in zip(speeds, durations))
    return LogPlan(motor=nominal.name, f4_rps=f4, speeds_rps=speeds, durations_s=durations,
                   settle_s=float(settle_s), min_sample_rate_hz=rate, servo_stick_slip=stick)


def servo_reversals(system: SystemParams, speed_rps: float, duration_s: float,
                    settle_s: float = DEFAULT_SETTLE_S) -> int:
    """How often the encoder steps backwards in a simulated servo log of
    ``system`` at ``speed_rps`` (rev/s) after the ramp and the settle (its
    sensors, noise seed 0): more than none means stick-slip, where the fit's
    friction model Fs*sign(speed) fails (on 5 of the 27 catalogue motors the
    plan's servo logs then identified 14-52 % off, their open-loop logs within
    2.7 %)."""
    profile = SpeedProfile(speed_rps=speed_rps)
    ramp_s = abs(speed_rps) / profile.accel_rps2
    result = simulate(system, profile=profile, settings=RunSettings(mode="servo", noise_seed=0),
                      duration_s=ramp_s + duration_s, trace=True)
    t = np.asarray(result.trace["t"])
    theta = np.asarray(result.trace["theta_fb"])[t >= ramp_s + settle_s]
    return int(np.count_nonzero(np.diff(theta) * np.sign(speed_rps) < 0))
