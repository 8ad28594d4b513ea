"""One interface for every policy: model-based baselines and learned agents.

A policy runs in ``StepperDamp-v0`` (observation in, action out). It states the
environment options it needs (base controller, its model, action mode) through
:meth:`Policy.env_options`, given what the drive may know about its motor
(:class:`MotorKnowledge`: the datasheet values and an identified detent model,
never the true plant), and is told the episode's context by :meth:`Policy.reset`.
The leaderboard (``stepdamp_env.leaderboard``) runs every policy this way.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from stepdamp_env.params import FeedforwardModel, SystemParams

__all__ = ["MotorKnowledge", "PolicyContext", "Policy", "ZeroResidual"]


@dataclass(frozen=True)
class MotorKnowledge:
    """What a drive knows of the motor it runs.

    Attributes:
        nominal: the datasheet system (motor, drive, servo); for a randomised
            motor this is the preset it was drawn around, not the draw.
        identified: the detent model identified on this very motor
            (``stepdamp_env.identify``), or ``None`` when not available.
        exact: the plant's own detent model, for oracle baselines only.
    """

    nominal: SystemParams
    identified: FeedforwardModel | None
    exact: FeedforwardModel


@dataclass(frozen=True)
class PolicyContext:
    """The episode a policy is about to act in (known to the drive).

    Attributes:
        knowledge: see :class:`MotorKnowledge`.
        estimate: the base controller's detent model in this episode.
        mode: "open-loop" or "servo".
        speed_rps: the held command speed (rev/s).
        action_mode: "harmonic", "current" or "harmonic+current".
        action_scale: physical size of action 1.0 of the first action entry
            (N*m per harmonic coefficient, or A in "current" mode).
        agent_hz: decision rate (Hz).
        current_scale_a: physical size of a q-current action of 1.0 (A).
    """

    knowledge: MotorKnowledge
    estimate: FeedforwardModel | None
    mode: str
    speed_rps: float
    action_mode: str
    action_scale: float
    agent_hz: float
    current_scale_a: float = 0.0


@runtime_checkable
class Policy(Protocol):
    """A policy of the benchmark (see the module docstring)."""

    name: str

    def env_options(self, knowledge: MotorKnowledge) -> dict[str, Any]:
        """StepperDamp-v0 keyword options this policy needs (base_controller,
        estimate, action_mode, ...)."""

    def reset(self, context: PolicyContext) -> None:
        """Called after each ``env.reset``."""

    def act(self, observation: np.ndarray) -> np.ndarray:
        """Action in [-1, 1] (float32) for one observation."""


class ZeroResidual:
    """The base controller alone: a zero action every step.

    ``base_controller`` is "none" or "patent-ff"; ``estimate`` picks the
    feedforward's model: "exact" (oracle), "identified" or "nominal".
    """

    def __init__(self, name: str, base_controller: str = "patent-ff",
                 estimate: str = "exact") -> None:
        if base_controller not in ("none", "patent-ff"):
            raise ValueError(f"base_controller={base_controller!r} is not one of "
                             "['none', 'patent-ff']")
        if estimate not in ("exact", "identified", "nominal"):
            raise ValueError(f"estimate={estimate!r} is not one of "
                             "['exact', 'identified', 'nominal']")
        self.name = name
        self.base_controller = base_controller
        self.estimate = estimate
        self._zero = np.zeros(1, dtype=np.float32)

    def env_options(self, knowledge: MotorKnowledge) -> dict[str, Any]:
        return {"base_controller": self.base_controller, "action_mode": "current",
                "estimate": resolve_estimate(self.estimate, knowledge)}

    def reset(self, context: PolicyContext) -> None:
        self._zero = np.zeros(1, dtype=np.float32)

    def act(self, observation: np.ndarray) -> np.ndarray:
        return self._zero


def resolve_estimate(which: str, knowledge: MotorKnowledge) -> str | FeedforwardModel:
    """The env's ``estimate`` option for "exact", "identified" or "nominal"."""
    if which == "exact":
        return "exact"
    if which == "nominal":
        return FeedforwardModel.from_motor(knowledge.nominal.motor)
    if knowledge.identified is None:
        raise ValueError("this policy needs an identified motor model "
                         "(MotorKnowledge.identified is None)")
    return knowledge.identified
