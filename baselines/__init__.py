"""Model-based policies of StepperDamp (installed as ``stepdamp_baselines``).

========================  ==========================================================
``none``                  no damping: the base controller without feedforward (the
                          protocol's reference, registered by ``stepdamp_env.bench``)
``patent-ff-oracle``      the patent's feedforward with the plant's exact parameters
``patent-ff-identified``  the patent's feedforward with the identified parameters
``ff-delay-comp``         identified feedforward sent ahead of the current loop's and
                          the PWM hold's delay (and, in open loop, the rotor's lag)
``adaptive-ff``           identified feedforward corrected online from the velocity
                          error (Kalman filter on the ripple phasors, filterpy)
========================  ==========================================================

Every baseline implements the policy contract of :mod:`stepdamp_env.bench.policy`.
:func:`register_policies` (the ``stepdamp.policies`` entry point ``baselines``)
puts them into the leaderboard's registry. A new baseline: a class in this
package, a line in ``BASELINE_NAMES`` and :func:`make_baseline`.
"""

from stepdamp_env.bench.policy import Policy, ZeroAction, reference_policy
from stepdamp_env.bench.protocol import REFERENCE_POLICY
from stepdamp_env.bench.registry import register_policy

from .harmonic import AdaptiveFF, DelayCompensatedFF

__all__ = ["AdaptiveFF", "DelayCompensatedFF", "BASELINE_NAMES", "make_baseline",
           "register_policies"]

BASELINE_NAMES = (REFERENCE_POLICY, "patent-ff-oracle", "patent-ff-identified",
                  "ff-delay-comp", "adaptive-ff")

_DESCRIPTIONS = {
    "patent-ff-oracle": "patent feedforward, exact model (oracle)",
    "patent-ff-identified": "patent feedforward, identified model",
    "ff-delay-comp": "identified feedforward with drive-model delay compensation",
    "adaptive-ff": "identified feedforward corrected online (Kalman ripple tracker)",
}


def make_baseline(name: str) -> Policy:
    """A fresh baseline policy by name (one of ``BASELINE_NAMES``)."""
    if name == REFERENCE_POLICY:
        return reference_policy()
    if name == "patent-ff-oracle":
        return ZeroAction("patent-ff-oracle", estimate="exact")
    if name == "patent-ff-identified":
        return ZeroAction("patent-ff-identified", estimate="identified")
    if name == "ff-delay-comp":
        return DelayCompensatedFF()
    if name == "adaptive-ff":
        return AdaptiveFF()
    raise ValueError(f"unknown baseline {name!r}; choose one of {list(BASELINE_NAMES)}")


def _factory(name: str):
    def make() -> Policy:
        return make_baseline(name)
    make.__qualname__ = f"make_baseline[{name}]"
    return make


_FACTORIES = {name: _factory(name) for name in BASELINE_NAMES if name != REFERENCE_POLICY}


def register_policies() -> None:
    """Register every baseline with the leaderboard (idempotent)."""
    for name, make in _FACTORIES.items():
        register_policy(name, make, kind="baseline", description=_DESCRIPTIONS.get(name, ""))
