"""Model-based policies of StepperDamp behind one interface (:mod:`baselines.base`)."""

from .base import MotorKnowledge, Policy, PolicyContext, ZeroResidual

__all__ = ["MotorKnowledge", "Policy", "PolicyContext", "ZeroResidual", "BASELINE_NAMES",
           "make_baseline"]

BASELINE_NAMES = ("none", "patent-ff-oracle", "patent-ff-identified")


def make_baseline(name: str) -> Policy:
    """A fresh baseline policy by name (one of ``BASELINE_NAMES``)."""
    if name == "none":
        return ZeroResidual("none", base_controller="none")
    if name == "patent-ff-oracle":
        return ZeroResidual("patent-ff-oracle", estimate="exact")
    if name == "patent-ff-identified":
        return ZeroResidual("patent-ff-identified", estimate="identified")
    raise ValueError(f"unknown baseline {name!r}; choose one of {list(BASELINE_NAMES)}")
