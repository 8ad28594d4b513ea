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
``velocity-feedback``     ``ff-delay-comp`` plus a damping current from the encoder's
                          velocity error, gains from a damping ratio on the nominal model
``sensorless-damping``    the same without an encoder: speed from the back-EMF
                          (currents and winding voltages; US 5,847,535's idea)
``calibrated-table``      a fixed feedforward table tuned by golden-section search on
                          a calibration rig (US 5,659,234, Prusa's phase stepping)
``repetitive-control``    the feedforward learned online per electrical period from
                          the encoder (repetitive / iterative learning control)
``tuned-constant-gain``   ``ff-delay-comp`` plus StepperDamp-v1's damping law at one
                          constant gain tuned on training motors (what the per-step
                          agents act on)
``tuned-gain-pair``       the same law at a constant (kv, kp) per suite, the best of a
                          grid on v3's dev split
``oracle-floor``          exact cancellation and state feedback on the true state
                          (oracle): how far the ripple can fall on this drive
``privileged-bound``      oracle-floor's law with its gain and rate chosen per suite on
                          v3's dev split: v3's privileged bound
``plant-bound``           per run, the best of a portfolio of true-state laws,
                          rehearsed on the true plant: v4's privileged bound
========================  ==========================================================

Every baseline implements the policy contract of :mod:`stepdamp_env.bench.policy`.
:func:`register_policies` (the ``stepdamp.policies`` entry point ``baselines``)
puts them into the leaderboard's registry. A new baseline: its class in a module
of this package, one row in :data:`BASELINES` (name, factory, description; the
row's place is the board's order) and one in the table above (a test checks
both agree); docs/architecture.md, "Adding a baseline".
"""

from typing import Callable

from stepdamp_env.bench.policy import Policy, ZeroAction, reference_policy
from stepdamp_env.bench.protocol import REFERENCE_POLICY
from stepdamp_env.bench.registry import register_policy

from .feedback import OracleFloor, PrivilegedBound, SensorlessDamping, TunedConstantGain, VelocityFeedback
from .gain_pair import TunedGainPair
from .harmonic import AdaptiveFF, DelayCompensatedFF
from .learning import CalibratedTable, RepetitiveControl
from .plant_bound import PlantBound

__all__ = ["AdaptiveFF", "DelayCompensatedFF", "VelocityFeedback", "SensorlessDamping",
           "CalibratedTable", "RepetitiveControl", "TunedConstantGain", "TunedGainPair",
           "OracleFloor", "PrivilegedBound", "PlantBound", "BASELINES", "BASELINE_NAMES", "make_baseline",
           "register_policies"]

#: Every baseline but the reference (registered by stepdamp_env.bench), in the
#: registry's order: (name, a zero-argument factory, one-line description).
BASELINES: tuple[tuple[str, Callable[[], Policy], str], ...] = (
    ("patent-ff-oracle", lambda: ZeroAction("patent-ff-oracle", estimate="exact"),
     "patent feedforward, exact model (oracle)"),
    ("patent-ff-identified", lambda: ZeroAction("patent-ff-identified", estimate="identified"),
     "patent feedforward, identified model"),
    ("ff-delay-comp", DelayCompensatedFF,
     "identified feedforward with drive-model delay compensation"),
    ("adaptive-ff", AdaptiveFF,
     "identified feedforward corrected online (Kalman ripple tracker)"),
    ("velocity-feedback", VelocityFeedback,
     "ff-delay-comp plus velocity-feedback damping (encoder)"),
    ("sensorless-damping", SensorlessDamping,
     "ff-delay-comp plus back-EMF damping (no encoder)"),
    ("calibrated-table", CalibratedTable,
     "feedforward table calibrated on a rig (golden-section search)"),
    ("repetitive-control", RepetitiveControl,
     "feedforward learned online per electrical period (encoder)"),
    ("tuned-constant-gain", TunedConstantGain,
     "ff-delay-comp plus v1's damping law at a constant gain tuned on training motors"),
    ("tuned-gain-pair", TunedGainPair,
     "ff-delay-comp plus v1's damping law at a constant (kv, kp) per suite tuned on v3's "
     "dev split"),
    ("oracle-floor", OracleFloor, "exact cancellation and true-state feedback (oracle floor)"),
    ("privileged-bound", PrivilegedBound,
     "oracle-floor's law tuned per suite on v3's dev split (privileged)"),
    ("plant-bound", PlantBound,
     "per run, the best of a portfolio of true-state laws rehearsed on the true plant "
     "(privileged)"),
)
BASELINE_NAMES = (REFERENCE_POLICY, *(name for name, _, _ in BASELINES))
_MAKE = {name: make for name, make, _ in BASELINES}


def make_baseline(name: str) -> Policy:
    """A fresh baseline policy by name (one of ``BASELINE_NAMES``)."""
    if name == REFERENCE_POLICY:
        return reference_policy()
    if name not in _MAKE:
        raise ValueError(f"unknown baseline {name!r}; choose one of {list(BASELINE_NAMES)}")
    return _MAKE[name]()


def _factory(name: str) -> Callable[[], Policy]:
    def make() -> Policy:
        return make_baseline(name)
    make.__qualname__ = f"make_baseline[{name}]"
    return make


_FACTORIES = {name: _factory(name) for name, _, _ in BASELINES}


def register_policies() -> None:
    """Register every baseline with the leaderboard (idempotent)."""
    for name, _, description in BASELINES:
        register_policy(name, _FACTORIES[name], kind="baseline", description=description)
