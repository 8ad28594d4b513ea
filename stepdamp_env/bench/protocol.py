"""The protocol contract: what every ``stepdamp-bench`` version says, and the
settings all versions share.

A protocol version is one module under :mod:`stepdamp_env.bench.protocols`
(its docstring is the version's specification) with a frozen dataclass that
implements :class:`Protocol`: its settings as fields, its motors
(:meth:`Protocol.motors`), how runs become ranked entries
(:meth:`Protocol.entries`), and the class facts the runner and the report read
(``known_suites``, ``pools_training_seeds``, ``nominal_on_failed_identification``,
``min_training_seeds``). The runner, the statistics, the report and the CLI ask
the object; none of them compares version strings. ``protocols.protocol_for``
builds a registered version by name.
"""

from __future__ import annotations

import abc
import dataclasses
import math
from typing import TYPE_CHECKING, Any, ClassVar, Mapping, Sequence

# Seeds below it are training seeds (agents, tuning); evaluation seeds are at or
# above it. Defined with the env, which warns on them (StepperDamp-v2).
from ..env.registration import RESERVED_SEEDS_FROM as TRAINING_SEED_LIMIT
from ..metrics import METRICS_V0_V3
from ..params import ParameterError
from .suites import SUITES_BY_NAME, SUITES_THROUGH_V3, SuiteField

if TYPE_CHECKING:
    from ..params import SystemParams
    from .motors import ProtocolMotor

__all__ = [
    "PROTOCOL_NAME",
    "TRAINING_SEED_LIMIT",
    "POLICY_OPTIONS",
    "POLICY_OPTIONS_V1",
    "SUITES",
    "ALL_SUITES",
    "SUITE_MODE",
    "SUITE_DRIVE_MODE",
    "FAILURE_RATIO",
    "REFERENCE_POLICY",
    "REFERENCE_ROW",
    "PHASE_FIELDS",
    "Protocol",
    "rank",
]

PROTOCOL_NAME = "stepdamp-bench"
#: v0's and v1's suites.
SUITES = tuple(name for name, s in SUITES_BY_NAME.items() if s.since == "v0")
#: Every suite of v2 and v3 (:mod:`.suites`): v2 adds the voltage-mode drive's mid-band.
ALL_SUITES = SUITES_THROUGH_V3
#: The env mode a suite runs in, and its drive_mode (live views of :mod:`.suites`).
SUITE_MODE = SuiteField("mode")
SUITE_DRIVE_MODE = SuiteField("drive_mode")
# A failed run (step loss, termination) counts as this many times the undamped ripple.
FAILURE_RATIO = 10.0

# What a policy may choose through env_options(); the rest is the protocol's.
POLICY_OPTIONS = ("base_controller", "estimate", "action_mode", "agent_hz",
                  "harmonic_scale_nm", "current_scale_a", "velocity_estimator",
                  "current_penalty", "termination_penalty")
# The same for a policy that runs in StepperDamp-v1 (its ``env_id``): the agent's
# interface (action mode, rate, history, context, the damping law's scales), never
# the plant, its nominal model, the sensors, the speed or the window.
POLICY_OPTIONS_V1 = ("base_controller", "estimate", "action_mode", "agent_hz",
                     "harmonic_scale_nm", "current_scale_a", "velocity_estimator",
                     "current_penalty", "history", "context", "damping_ratio_scale",
                     "resonant_rate_scale", "law_limit_factor")

# The reference of every ratio: the base controller alone, without feedforward
# (a zero action with ``base_controller="none"``); its entry has this name.
REFERENCE_POLICY = "none"

# The unranked row of a suite's "no phenomenon" runs (v3): policy ``none`` on
# :meth:`Protocol.reference_motor`, the same motor without what the suite scores.
REFERENCE_ROW = "reference"

# Drawn as absolute values (rad), not as factors.
PHASE_FIELDS = ("phi1", "phi2")


def rank(group: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Entries of one table sorted by headline IQM (non-finite last, then by
    name), each given its ``rank`` from 1."""
    group.sort(key=lambda e: (not math.isfinite(e["headline"]["iqm"]),
                              e["headline"]["iqm"], e["name"]))
    for k, e in enumerate(group, 1):
        e["rank"] = k
    return group


#: The default entries of the published v0, v1 and v2 boards: every registered
#: default entry of 0.11.0 (v0 runs those its env can; the others are "not run").
PUBLISHED_ENTRIES_V0_V2 = (
    "none", "patent-ff-oracle", "patent-ff-identified", "ff-delay-comp", "adaptive-ff",
    "velocity-feedback", "sensorless-damping", "calibrated-table", "repetitive-control",
    "tuned-constant-gain", "oracle-floor", "ars-per-step", "ars-per-step-25hz",
    "ppo-gain-selector", "ppo-per-step", "td3-per-step")


class Protocol(abc.ABC):
    """A ``stepdamp-bench`` version: the interface the runner, the statistics, the
    report and the CLI use. Implementations are frozen dataclasses whose fields
    include at least those annotated here."""

    name: str
    version: str
    variant: str                      # "full" or "quick"
    suites: tuple[str, ...]
    eval_seeds: tuple[int, ...]
    accel_rps2: float                 # command ramp (rev/s^2)
    window_s: float                   # measuring window (s)
    current_noise_a: float
    encoder_cpr: int
    identification_method: str
    failure_ratio: float
    bootstrap_resamples: int
    bootstrap_seed: int
    confidence: float

    #: The suites this version may run (``with_suites`` picks among them).
    known_suites: ClassVar[tuple[str, ...]] = SUITES
    #: A learned entry runs every training seed it has, each seed's runs its cells.
    pools_training_seeds: ClassVar[bool] = False
    #: A failed identification leaves the drive its nominal model (else the run stops).
    nominal_on_failed_identification: ClassVar[bool] = False
    #: Fewer training seeds than this: the report makes no claim for the entry.
    min_training_seeds: ClassVar[int] = 1
    #: Entries' records carry their card's ``trained_on`` (v3's eligibility rule).
    records_training_coverage: ClassVar[bool] = False
    #: A frozen version's default board: the entries it was published with (an
    #: entry registered later would change every other row's comparisons). None:
    #: every registered default entry (the current version, which new entries join).
    published_entries: ClassVar[tuple[str, ...] | None] = PUBLISHED_ENTRIES_V0_V2
    #: The run metrics a board records (``RunMetrics`` fields); None: all of them.
    #: v0-v3 keep the fields they were published with.
    run_metrics: ClassVar[tuple[str, ...] | None] = METRICS_V0_V3
    #: Registered entries a current version leaves off its default board (an
    #: entry another one supersedes there; ``--entries`` still runs it).
    retired_entries: ClassVar[tuple[str, ...]] = ()
    #: How the report renders and reads its board: rows scored as ripple over
    #: ``none``'s ("ratio") or as attenuation against the reference row ("dB").
    headline_unit: ClassVar[str] = "ratio"
    #: Whether its rows are per split of its motors.
    rows_per_split: ClassVar[bool] = False

    def default_entries(self, names: Sequence[str]) -> list[str]:
        """The registered default entries ``names`` that this version runs by default."""
        keep = self.published_entries
        return [n for n in names if (keep is None or n in keep)
                and n not in self.retired_entries]

    @abc.abstractmethod
    def motors(self) -> tuple["ProtocolMotor", ...]:
        """The protocol's motors, in order (deterministic)."""

    @abc.abstractmethod
    def entries(self, names: Mapping[str, tuple[str, str]],
                by_entry: Mapping[tuple[str, str], list[dict[str, Any]]],
                motors: Sequence["ProtocolMotor"],
                meta: Mapping[str, dict[str, Any]], *, workers: int = 1
                ) -> list[dict[str, Any]]:
        """The board's ranked entries. ``names``: policy spec -> (entry name, spec
        as recorded), in board order; ``by_entry``: (spec, suite) -> that
        policy's run records; ``meta``: spec -> oracle flag, env options, card.
        ``workers``: processes a version may score on (v4 on: its tables; the
        numbers do not depend on it)."""

    @abc.abstractmethod
    def to_dict(self) -> dict[str, Any]:
        """The protocol as the board records it (``leaderboard.json``)."""

    @abc.abstractmethod
    def with_suites(self, suites: Sequence[str]) -> "Protocol":
        """The same protocol on a subset of its suites."""

    def with_splits(self, splits: Sequence[str]) -> "Protocol":
        """The same protocol on other splits (``--split``)."""
        raise ParameterError(f"--split: {self.name} {self.version} has no choice of splits "
                             "(--protocol v3 or later)")

    def with_eval_seeds(self, count: int) -> "Protocol":
        """The same protocol with ``count`` evaluation seeds (``--eval-seeds``)."""
        raise ParameterError(f"--eval-seeds: {self.name} {self.version}'s evaluation seeds are "
                             "frozen (--protocol v4 or later)")

    def tables(self, entries: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
        """Facts per suite and split the board records beside its rows (``tables``);
        none (the default) before v4."""
        return []

    def check_derived(self, entries: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
        """``report --check``'s items for rows the version derives from other rows'
        runs (``what``, ``reproduces``, ``detail``), from the board's ``entries``
        with their runs; none (the default) before v5."""
        return []

    def with_custom_motors(self, systems: Sequence["SystemParams"]) -> "Protocol":
        """The protocol on the user's motors (``--motors FILE``)."""
        raise ParameterError(f"--motors: {self.name} {self.version}'s motors are frozen; "
                             "use a protocol with a custom split (--protocol v1 or later)")

    def lag_limit(self) -> float | None:
        """The env's lag limit in full steps for this version's runs, which are then
        judged by their final slip (:func:`.runner.lost_steps`); None (the
        default): a lag past one full step ends the run as a step loss."""
        return None

    def run_command(self, motor: "ProtocolMotor", suite: str, index: int) -> dict[str, Any]:
        """How the run of a suite's ``index``-th speed on ``motor`` is commanded,
        as :class:`.runner.EpisodeSpec` fields beyond the speed ({}: a ramp at
        ``accel_rps2`` to the speed, then held; v4's moves suite: a move's
        ``profile``, ``distance_rev`` and ``accel_rps2``)."""
        return {}

    def reference_motor(self, motor: "ProtocolMotor", suite: str) -> "ProtocolMotor | None":
        """The motor a suite's ``reference`` row runs policy ``none`` on: the same
        motor, speeds, drive and sensors without the phenomenon the suite scores;
        None (the default): the version has no reference rows."""
        return None

    def checked_suites(self, suites: Sequence[str]) -> tuple[str, ...]:
        """``suites`` as a tuple, or a one-line error naming what this version has."""
        bad = [s for s in suites if s not in self.known_suites]
        if bad or not suites:
            raise ParameterError(f"--suite {', '.join(bad) or '(none)'}: {self.name} "
                                 f"{self.version} has {list(self.known_suites)}")
        return tuple(suites)

    def check_suites_and_seeds(self) -> None:
        """Its suites are known ones and its evaluation seeds are never training seeds."""
        bad = [s for s in self.suites if s not in self.known_suites]
        if bad or not self.suites:
            raise ParameterError(f"suites={self.suites!r}: each must be one of "
                                 f"{list(self.known_suites)}")
        if any(s < TRAINING_SEED_LIMIT for s in self.eval_seeds) or not self.eval_seeds:
            raise ParameterError(f"eval_seeds={self.eval_seeds!r}: each must be >= "
                                 f"{TRAINING_SEED_LIMIT} (training seeds are below it)")

    def replace(self, **changes: Any) -> "Protocol":
        """A copy with some settings changed (validated)."""
        return dataclasses.replace(self, **changes)     # type: ignore[type-var]
