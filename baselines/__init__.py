"""Model-based policies of StepperDamp behind one interface (:mod:`baselines.base`).

========================  ==========================================================
``none``                  no damping: the base controller without feedforward
``patent-ff-oracle``      the patent's feedforward with the plant's exact parameters
``patent-ff-identified``  the patent's feedforward with the identified parameters
``ff-delay-comp``         identified feedforward sent ahead of the current loop's and
                          the PWM hold's delay (and, in open loop, the rotor's lag)
``adaptive-ff``           identified feedforward corrected online from the velocity
                          error (Kalman filter on the ripple phasors, filterpy)
========================  ==========================================================
"""

from .base import MotorKnowledge, Policy, PolicyContext, ZeroResidual
from .harmonic import AdaptiveFF, DelayCompensatedFF

__all__ = ["MotorKnowledge", "Policy", "PolicyContext", "ZeroResidual", "AdaptiveFF",
           "DelayCompensatedFF", "BASELINE_NAMES", "make_baseline"]

BASELINE_NAMES = ("none", "patent-ff-oracle", "patent-ff-identified", "ff-delay-comp",
                  "adaptive-ff")


def make_baseline(name: str) -> Policy:
    """A fresh baseline policy by name (one of ``BASELINE_NAMES``)."""
    if name == "none":
        return ZeroResidual("none", base_controller="none")
    if name == "patent-ff-oracle":
        return ZeroResidual("patent-ff-oracle", estimate="exact")
    if name == "patent-ff-identified":
        return ZeroResidual("patent-ff-identified", estimate="identified")
    if name == "ff-delay-comp":
        return DelayCompensatedFF()
    if name == "adaptive-ff":
        return AdaptiveFF()
    raise ValueError(f"unknown baseline {name!r}; choose one of {list(BASELINE_NAMES)}")
