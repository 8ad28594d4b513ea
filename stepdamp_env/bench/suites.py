"""The suites of stepdamp-bench, one record each: what the drive runs, which
speeds are scored, what the reference row removes and how an agent trains for
it. Protocols choose which suites they run (``Protocol.known_suites``); the CLI's
choices, the policies' context (:attr:`.policy.PolicyContext.suite`) and the
training tasks (``stepdamp_agents.task.SUITE_TASKS``) read them from here.

Adding a suite: one :class:`Suite` in :data:`SUITES_BY_NAME`, a protocol that
runs it (its grid in ``suite_grids``), and its tests (docs/architecture.md).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Collection, Iterator, Mapping

from ..params import ParameterError

__all__ = ["Suite", "SUITES_BY_NAME", "register_suite", "get_suite", "suite_names", "suite_of",
           "nearest_suite", "tuned_suite", "SuiteField", "MODES", "DRIVE_MODES", "PROFILES",
           "SUITES_THROUGH_V3"]

#: The env's modes and the drive's current controls a suite may pair.
MODES = ("open-loop", "servo")
DRIVE_MODES = ("current", "voltage")
#: A suite's command: a constant speed, or point-to-point moves.
PROFILES = ("constant", "move")


@dataclass(frozen=True)
class Suite:
    """One suite.

    Attributes:
        name: the suite's name on the CLI, in boards and in policy cards.
        mode: the env's mode ("open-loop" microstepping or encoder "servo").
        drive_mode: the drive's current control ("current" loops, or "voltage").
        description: what the suite measures, in a line.
        headline: which speeds are scored (the headline-speed rule, v3).
        reference: what the unranked reference row removes (v3).
        since: the first protocol version that runs it.
        training_task: StepperDamp-v1 options ``stepdamp train --suite`` sets on
            the reference task (``overrides`` merged key by key): the servo loop or
            the voltage-mode drive, and speeds drawn uniformly over the dev
            split's headline speeds (servo 0.168-0.545 rev/s, mid-band
            1.58-10.79) widened by x0.8 and x1.2 (open loop: the reference task's
            own draw, which covers its resonances; moves: that draw as moves).
            Chosen on the dev split, never on a scored one.
        profile: the command (a :class:`..simulation.SpeedProfile` kind):
            "constant" (a ramp to each speed, then held) or "move" (point-to-point
            moves cruising at each speed, v4's moves suite: the protocol gives
            each cell's ramp and acceleration, ``Protocol.run_command``).
        tuning: the suite whose tuned settings an entry tuned per suite uses
            here when it has none of its own (None: none; it cannot run).
    """

    name: str
    mode: str
    drive_mode: str
    description: str
    headline: str
    reference: str
    since: str
    training_task: Mapping[str, Any] = field(default_factory=dict)
    profile: str = "constant"
    tuning: str | None = None

    def __post_init__(self) -> None:
        # A copy of its own, read-only at the top (the builders deep-copy what they use).
        object.__setattr__(self, "training_task", MappingProxyType(copy.deepcopy(
            dict(self.training_task))))


_SUITES: dict[str, Suite] = {}
#: Every registered suite by name (read-only; :func:`register_suite` adds one).
SUITES_BY_NAME: Mapping[str, Suite] = MappingProxyType(_SUITES)


def register_suite(suite: Suite) -> None:
    """Add a suite (its name new and not "all"; its mode and drive one of
    :data:`MODES` and :data:`DRIVE_MODES`, its profile one of :data:`PROFILES`;
    mode, drive and profile together a triple no suite has yet). Processes
    forked later see it; a spawned or Ray worker registers it again."""
    if not isinstance(suite.name, str) or not suite.name or suite.name == "all":
        raise ParameterError(f"suite name {suite.name!r}: a non-empty name other than 'all'")
    if suite.mode not in MODES or suite.drive_mode not in DRIVE_MODES:
        raise ParameterError(f"suite {suite.name!r}: mode {suite.mode!r} must be one of "
                             f"{list(MODES)}, drive_mode {suite.drive_mode!r} one of "
                             f"{list(DRIVE_MODES)}")
    if suite.profile not in PROFILES:
        raise ParameterError(f"suite {suite.name!r}: profile {suite.profile!r} must be one of "
                             f"{list(PROFILES)}")
    if suite.name in _SUITES:
        raise ParameterError(f"suite {suite.name!r} is registered twice")
    taken = next((s.name for s in _SUITES.values() if (s.mode, s.drive_mode, s.profile)
                  == (suite.mode, suite.drive_mode, suite.profile)), None)
    if taken is not None:
        raise ParameterError(f"suite {suite.name!r}: mode {suite.mode!r} on the "
                             f"{suite.drive_mode!r} drive with profile {suite.profile!r} is "
                             f"suite {taken!r} already")
    if suite.tuning is not None and suite.tuning not in _SUITES:
        raise ParameterError(f"suite {suite.name!r}: tuning {suite.tuning!r} is not a "
                             f"registered suite {list(_SUITES)}")
    _SUITES[suite.name] = suite


class SuiteField(Mapping[str, Any]):
    """One field of every registered suite, by suite name (a live, read-only view:
    ``SuiteField("mode")["servo"] == "servo"``)."""

    def __init__(self, name: str) -> None:
        if name not in Suite.__dataclass_fields__:
            raise ValueError(f"SuiteField({name!r}): not a field of Suite "
                             f"{list(Suite.__dataclass_fields__)}")
        self._field = name

    def __getitem__(self, suite: str) -> Any:
        return getattr(_SUITES[suite], self._field)

    def __iter__(self) -> Iterator[str]:
        return iter(_SUITES)

    def __len__(self) -> int:
        return len(_SUITES)




def suite_names() -> tuple[str, ...]:
    """Every suite's name, in the order the protocols list them."""
    return tuple(SUITES_BY_NAME)


def get_suite(name: str) -> Suite:
    """The suite named ``name``; a one-line error naming the suites otherwise."""
    try:
        return SUITES_BY_NAME[name]
    except (KeyError, TypeError):
        raise ParameterError(f"suite {name!r} is not one of {list(SUITES_BY_NAME)}") from None


def nearest_suite(mode: str, drive_mode: str) -> str | None:
    """:func:`suite_of`, or else the suite of the same drive in open loop (a servo
    on the voltage-mode drive: the mid-band's), for a policy tuned per suite run
    outside the suites."""
    return suite_of(mode, drive_mode) or suite_of("open-loop", drive_mode)


def suite_of(mode: str, drive_mode: str, profile: str = "constant") -> str | None:
    """The suite a run of ``mode`` on a ``drive_mode`` drive with the command
    ``profile`` belongs to (None if none: a servo on the voltage-mode drive)."""
    return next((s.name for s in SUITES_BY_NAME.values()
                 if (s.mode, s.drive_mode, s.profile) == (mode, drive_mode, profile)), None)


def tuned_suite(suite: str, tuned: Collection[str]) -> str:
    """The suite whose settings an entry tuned for the suites ``tuned`` uses in
    ``suite``: its own, else the suite's ``tuning`` (the moves suite: the
    open-loop suite's); ``suite`` itself if neither was tuned."""
    if suite in tuned:
        return suite
    fallback = SUITES_BY_NAME[suite].tuning if suite in SUITES_BY_NAME else None
    return fallback if fallback is not None and fallback in tuned else suite


# The suites of v0-v3.
for _suite in (
    Suite("open-loop", "open-loop", "current",
          "microstepping on the holding current's spring: the detent resonances",
          "the predicted resonances f4, f2, f1 where the detent ripple dominates",
          "the same motor without torque harmonics (Kd1 = Kd2 = Kd4 = 0)", "v0"),
    Suite("servo", "servo", "current",
          "the encoder servo (eq. 15) holding the speed: its disturbance response",
          "the 3 of 0.2-1.6 x f4 where undamped ripple is largest and dominated by the "
          "detent", "the same motor without torque harmonics", "v0",
          {"mode": "servo", "speed_range_rps": [0.13, 0.65], "resonance_prob": 0.0}),
    Suite("mid-band", "open-loop", "voltage",
          "the voltage-mode drive's mid-band instability",
          "five speeds log-spaced through the predicted unstable band",
          "the same motor on the current-mode drive at 4 x its bus voltage", "v2",
          {"mode": "open-loop", "speed_range_rps": [1.25, 13.0], "resonance_prob": 0.0,
           "overrides": {"drive_mode": "voltage"}}),
):
    register_suite(_suite)
#: The suites v0-v3 know (frozen: a later suite never joins their boards).
SUITES_THROUGH_V3 = tuple(_SUITES)

# v4's.
register_suite(Suite(
    "moves", "open-loop", "current",
    "point-to-point moves through the resonances: ramps (trapezoid and S-curve) that "
    "pass the lower resonances, a cruise at a resonant speed, the stop and its settling",
    "moves cruising at the open-loop headline speeds f2 and f1, each as a trapezoid and "
    "as an S-curve", "the same motor without torque harmonics", "v4",
    # Moves over a machine range rather than the protocol's two accelerations (the
    # range holds them): the reference task's speeds, either ramp, peak accelerations
    # log-uniform over belt axes' 1,000-10,000 mm/s^2 on 40 and 32 mm/rev pulleys
    # (25-312.5 rev/s^2), not capped by the motor's torque as the cells are (the
    # presets reach these), the suite's 0.3 s cruise (added in 0.19.0).
    {"profile": "move", "ramp": "any", "cruise_s": 0.3, "accel_range_rps2": [25.0, 312.5]},
    profile="move", tuning="open-loop"))
