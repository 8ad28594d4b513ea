"""The policy contract: what every entry of the benchmark implements and is told.

A policy runs in ``StepperDamp-v0`` (observation in, action out). It states the
environment options it needs (base controller, its model, action mode) through
:meth:`Policy.env_options`, given what the drive may know about its motor
(:class:`MotorKnowledge`: the datasheet values and an identified detent model,
never the true plant), and is told the episode's context by :meth:`Policy.reset`.
Read observation entries by name (:mod:`stepdamp_env.env.layout`). Baselines
(``stepdamp_baselines``) and agents (``stepdamp_agents``) implement it; the
leaderboard runs every policy through :func:`stepdamp_env.bench.runner.run_episodes`.
"""

from __future__ import annotations

import math

from dataclasses import dataclass
from typing import Any, Callable, Mapping, Protocol as TypingProtocol, Sequence, runtime_checkable

import numpy as np

from ..env.options import BASE_CONTROLLERS, ESTIMATES, EnvOptions, default_action_scales
from ..params import FeedforwardModel, ParameterError, SystemParams
from ..simulation import DEFAULT_ACCEL_RPS2
from ..env.registration import ENV_ID, ENV_ID_V1
from .protocol import POLICY_OPTIONS, POLICY_OPTIONS_V1, REFERENCE_POLICY
from .suites import get_suite, suite_of

__all__ = ["MotorKnowledge", "PolicyContext", "Policy", "PolicyCard", "policy_card",
           "ZeroAction", "reference_policy", "KNOWLEDGE_ESTIMATES", "ORACLE_OPTIONS",
           "resolve_estimate", "estimate_model", "policy_env_options", "policy_context",
           "check_policy", "policy_env_id", "POLICY_ENV_IDS", "BatchPolicy", "ScalarPolicies",
           "batch_policy", "RowPolicy"]

# The envs a policy may run in (its optional ``env_id`` attribute; v0 by default).
POLICY_ENV_IDS = (ENV_ID, ENV_ID_V1)

# What a policy may name as its base controller's model.
KNOWLEDGE_ESTIMATES = ("exact", "identified", "nominal")
# Env options only an entry whose card says ``oracle`` may set (the true states).
ORACLE_OPTIONS = ("privileged",)


@dataclass(frozen=True)
class MotorKnowledge:
    """What a drive knows of the motor it runs.

    Attributes:
        nominal: the datasheet system (motor, drive, servo); for a randomised
            motor this is the preset it was drawn around, not the draw.
        identified: the detent model identified on this very motor
            (``stepdamp_env.identify``), or ``None`` when not available.
        exact: the plant's own detent model, for oracle baselines only.
        plant: the true plant itself (every parameter), for oracle baselines
            only; None where the caller does not give it.
        rig: a calibration rig on this very motor (:class:`.rig.CalibrationRig`)
            for entries that calibrate before they run; None where the caller
            does not give it.
    """

    nominal: SystemParams
    identified: FeedforwardModel | None
    exact: FeedforwardModel
    plant: SystemParams | None = None
    rig: Any = None


@dataclass(frozen=True)
class PolicyCard:
    """What an entry knows and senses, shown in LEADERBOARD.md's knowledge column.

    Attributes:
        sensors: what it reads while it runs, e.g. "encoder", "currents +
            voltages (no encoder)", "true state".
        model: the motor model it uses: "none", "nominal", "identified",
            "exact" or "true plant".
        calibration: what it measures before the run ("" for nothing); the
            simulated seconds are reported per run, never scored.
        oracle: uses what no drive can know (the plant's exact model or true
            states); only such entries may set ``ORACLE_OPTIONS``.
        suites: the suites it runs in; ``not_in_suites`` says why not in the
            others.
        learned: its settings come from training (an agent).
        trained_on: a learned entry's training coverage, (suite, lowest rev/s,
            highest rev/s) ranges; from v3 on it is ranked only where these
            cover a suite's headline speeds.
    """

    sensors: str
    model: str
    calibration: str = ""
    oracle: bool = False
    suites: tuple[str, ...] | None = None
    not_in_suites: str = ""
    learned: bool = False
    trained_on: tuple[tuple[str, float, float], ...] = ()

    def knowledge(self) -> str:
        """One line for the knowledge column."""
        parts = [f"sensors: {self.sensors}", f"model: {self.model}"]
        if self.calibration:
            parts.append(f"calibration: {self.calibration}")
        if self.learned:
            parts.append("learned")
        if self.oracle:
            parts.append("oracle")
        return "; ".join(parts)


def policy_card(policy: Any) -> PolicyCard | None:
    """The policy's :class:`PolicyCard` (its ``card`` attribute), or None."""
    card = getattr(policy, "card", None)
    return card if isinstance(card, PolicyCard) else None


@dataclass(frozen=True)
class PolicyContext:
    """The episode a policy is about to act in (known to the drive).

    Attributes:
        knowledge: see :class:`MotorKnowledge`.
        estimate: the base controller's detent model in this episode (None
            without a base feedforward).
        mode: "open-loop" or "servo".
        speed_rps: the held command speed (rev/s).
        action_mode: "harmonic", "current" or "harmonic+current".
        action_scale: physical size of action 1.0 of the first action entry
            (N*m per harmonic coefficient, or A in "current" mode).
        agent_hz: decision rate (Hz).
        current_scale_a: physical size of a q-current action of 1.0 (A).
        accel_rps2: the start-up ramp's acceleration (rev/s^2); the speed is
            held from ``speed_rps / accel_rps2`` seconds on.
        suite: the stepdamp-bench suite the run belongs to (:mod:`.suites`:
            "open-loop", "servo", "mid-band"); left None, the one of ``mode`` on
            the nominal motor's drive (None for a run of no suite).
        window_s, settle_s, lag_limit_steps: how the runner measures the run
            (:func:`.runner.run_episode`'s arguments of those names; None where
            the run has none or they are not given), for an entry that rehearses
            its run (``plant-bound``).
        profile, distance_rev, ramp: the command: "constant" (the ramp to
            ``speed_rps``, then held), or "move": a point-to-point move of
            ``distance_rev`` (rev) at up to ``speed_rps`` whose ramps are
            "trapezoid" (constant acceleration) or "s-curve" (half cosines),
            of peak acceleration ``accel_rps2`` (the ``moves`` suite).
    """

    knowledge: MotorKnowledge
    estimate: FeedforwardModel | None
    mode: str
    speed_rps: float
    action_mode: str
    action_scale: float
    agent_hz: float
    current_scale_a: float = 0.0
    accel_rps2: float = DEFAULT_ACCEL_RPS2
    suite: str | None = None
    window_s: float | None = None
    settle_s: float | None = None
    lag_limit_steps: float | None = None
    profile: str = "constant"
    distance_rev: float = 0.0
    ramp: str = "trapezoid"

    def __post_init__(self) -> None:
        if self.suite is None:          # the one of the mode on the nominal drive
            nominal = getattr(self.knowledge, "nominal", None)
            if nominal is not None:
                object.__setattr__(self, "suite", suite_of(self.mode,
                                                           nominal.drive.drive_mode))

    @property
    def ramp_s(self) -> float:
        """Duration of the start-up ramp (s)."""
        v = abs(self.speed_rps)
        return 0.5 * math.pi * v / self.accel_rps2 if self.ramp == "s-curve" else \
            v / self.accel_rps2


@runtime_checkable
class Policy(TypingProtocol):
    """A policy of the benchmark (see the module docstring)."""

    name: str

    def env_options(self, knowledge: MotorKnowledge) -> dict[str, Any]:
        """StepperDamp-v0 keyword options this policy needs (base_controller,
        estimate, action_mode, ...); only ``POLICY_OPTIONS`` are allowed."""

    def reset(self, context: PolicyContext) -> None:
        """Called after each ``env.reset``. A policy whose law cannot be made for
        this motor or speed raises ``ParameterError`` (here or in
        ``env_options``): the run counts as lost and the row's note gives the
        message. Any other exception stops the board (a bug)."""

    def act(self, observation: np.ndarray) -> np.ndarray:
        """Action in [-1, 1] (float32) for one observation."""


@runtime_checkable
class BatchPolicy(Policy, TypingProtocol):
    """A policy that acts for many runs at once (the batched episode runner's).

    Rows are the runs of one :meth:`reset_batch`, numbered from 0; a row leaves
    the batch when its run ends and never comes back. A batched policy must act
    on each row exactly as a fresh scalar instance reset with that row's
    context would (``tests/test_scale.py`` checks this bit for bit).
    ``env_options`` and ``name`` are those of :class:`Policy`. A policy that
    calibrates reports each row's simulated rig seconds by an optional
    ``row_calibration_s(row)`` (without it, its ``calibration_s`` counts for
    every row). A policy without ``act_batch`` (or whose ``act_batch`` is
    inherited from another class than its ``act``) is run through
    :class:`ScalarPolicies`.
    """

    def reset_batch(self, contexts: Sequence[PolicyContext]) -> None:
        """Start one run per context: rows 0 .. len(contexts) - 1 (a new batch; the
        previous one, if any, is over)."""

    def act_batch(self, observations: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Actions (k, act_dim) in [-1, 1] for the observations (k, obs_dim) of
        the running ``rows`` (k increasing row numbers)."""


_ROW_0 = np.zeros(1, dtype=np.int64)
_ROW_0.flags.writeable = False


class RowPolicy:
    """A policy written once, on rows (:class:`BatchPolicy`): :meth:`reset` is
    ``reset_batch`` of one context and :meth:`act` is ``act_batch`` of its row, so a
    scalar run and a batched one run the same code. A subclass gives
    ``reset_batch`` and ``act_batch``; ``configure(context)`` computes one run's
    settings (its ``reset_batch`` calls it for each context, e.g. through
    ``stepdamp_baselines.harmonic.gather_rows``)."""

    def configure(self, context: PolicyContext) -> None:
        """One run's settings, on ``self`` (none by default)."""

    def reset(self, context: PolicyContext) -> None:
        self.reset_batch([context])

    def act(self, observation: np.ndarray) -> np.ndarray:
        return self.act_batch(np.asarray(observation)[None], _ROW_0)[0]

    def reset_batch(self, contexts: Sequence[PolicyContext]) -> None:
        raise NotImplementedError

    def act_batch(self, observations: np.ndarray, rows: np.ndarray) -> np.ndarray:
        raise NotImplementedError


class ScalarPolicies:
    """A scalar :class:`Policy` as a :class:`BatchPolicy`: one fresh instance
    per row from ``make`` (a zero-argument factory), each reset and stepped
    alone, so every row is what a scalar run gives."""

    def __init__(self, make: Callable[[], Any], probe: Any = None) -> None:
        self._make = make
        self._probe = make() if probe is None else probe
        self.name = str(self._probe.name)
        self._rows: list[Any] = []

    @property
    def probe(self) -> Any:
        """The instance that answers ``env_options``, ``card`` and ``env_id``."""
        return self._probe

    def __getattr__(self, attr: str) -> Any:
        # card, env_id, privileged, velocity_estimator ...: the wrapped policy's.
        if attr.startswith("_"):
            raise AttributeError(attr)
        return getattr(self._probe, attr)

    def env_options(self, knowledge: MotorKnowledge) -> dict[str, Any]:
        return self._probe.env_options(knowledge)

    def reset_batch(self, contexts: Sequence[PolicyContext]) -> None:
        self._rows = [self._make() for _ in contexts]
        for policy, context in zip(self._rows, contexts):
            policy.reset(context)

    def act_batch(self, observations: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return np.stack([np.asarray(self._rows[r].act(obs))
                         for r, obs in zip(rows.tolist(), observations)])

    def row_calibration_s(self, row: int) -> float:
        """Simulated seconds row ``row``'s instance calibrated (0 if it does not)."""
        return float(getattr(self._rows[row], "calibration_s", 0.0))


def _defined_by(cls: type, name: str) -> type | None:
    return next((c for c in cls.__mro__ if name in vars(c)), None)


def batch_policy(make: Callable[[], Any]) -> Any:
    """``make()`` if it is a :class:`BatchPolicy` whose ``act_batch`` belongs to
    its ``act`` and whose ``reset_batch`` belongs to its ``reset`` (each pair defined
    by the same class, or ``act``/``reset`` are :class:`RowPolicy`'s: a subclass that
    changes ``act`` or ``reset`` alone does not inherit a batched law that is no
    longer its own), else :class:`ScalarPolicies` of ``make``."""
    policy = make()
    cls = type(policy)
    if callable(getattr(policy, "act_batch", None)) and \
            callable(getattr(policy, "reset_batch", None)) and \
            _defined_by(cls, "act") in (_defined_by(cls, "act_batch"), RowPolicy) and \
            _defined_by(cls, "reset") in (_defined_by(cls, "reset_batch"), RowPolicy):
        return policy
    return ScalarPolicies(make, policy)


def check_policy(obj: Any, spec: str) -> None:
    """A ParameterError unless ``obj`` has the Policy interface."""
    for attr in ("name", "env_options", "reset", "act"):
        if not hasattr(obj, attr):
            raise ParameterError(f"policy {spec!r} has no {attr!r}: a Policy needs name, "
                                 "env_options(knowledge), reset(context) and act(obs)")


class ZeroAction:
    """The base controller alone: a zero action every step.

    ``base_controller`` is "none" or "patent-ff"; ``estimate`` picks the
    feedforward's model: "exact" (oracle), "identified" or "nominal".
    """

    def __init__(self, name: str, base_controller: str = "patent-ff",
                 estimate: str = "exact") -> None:
        if base_controller not in BASE_CONTROLLERS:
            raise ValueError(f"base_controller={base_controller!r} is not one of "
                             f"{list(BASE_CONTROLLERS)}")
        if estimate not in KNOWLEDGE_ESTIMATES:
            raise ValueError(f"estimate={estimate!r} is not one of "
                             f"{list(KNOWLEDGE_ESTIMATES)}")
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

    def reset_batch(self, contexts: Sequence[PolicyContext]) -> None:
        pass

    def act_batch(self, observations: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return np.zeros((len(rows), 1), dtype=np.float32)


def reference_policy() -> ZeroAction:
    """The protocol's reference: the base controller without feedforward, zero action."""
    return ZeroAction(REFERENCE_POLICY, base_controller="none")


def resolve_estimate(which: str, knowledge: MotorKnowledge) -> str | FeedforwardModel:
    """The env's ``estimate`` option for "exact", "identified" or "nominal"."""
    if which == "exact":
        return "exact"
    if which == "nominal":
        return FeedforwardModel.from_motor(knowledge.nominal.motor)
    if which != "identified":
        raise ValueError(f"estimate={which!r} is not one of {list(KNOWLEDGE_ESTIMATES)}")
    if knowledge.identified is None:
        raise ValueError("this policy needs an identified motor model "
                         "(MotorKnowledge.identified is None)")
    return knowledge.identified


def estimate_model(which: str, knowledge: MotorKnowledge) -> FeedforwardModel:
    """The model named ``which`` as a FeedforwardModel ("exact" is the plant's)."""
    est = resolve_estimate(which, knowledge)
    return est if isinstance(est, FeedforwardModel) else knowledge.exact


def policy_env_id(policy: Any) -> str:
    """The env the policy runs in: its ``env_id`` attribute, "StepperDamp-v0" without one."""
    env_id = getattr(policy, "env_id", ENV_ID)
    if env_id not in POLICY_ENV_IDS:
        raise ParameterError(f"policy {getattr(policy, 'name', policy)!r}: env_id={env_id!r} "
                             f"is not one of {list(POLICY_ENV_IDS)}")
    return env_id


def policy_env_options(policy: Policy, knowledge: MotorKnowledge) -> dict[str, Any]:
    """The policy's env options, checked against ``POLICY_OPTIONS`` (``POLICY_OPTIONS_V1``
    for a policy whose ``env_id`` is StepperDamp-v1) and made fair: "nominal" is
    the nominal preset and unset action scales come from it."""
    options = dict(policy.env_options(knowledge))
    card = policy_card(policy)
    base = POLICY_OPTIONS_V1 if policy_env_id(policy) == ENV_ID_V1 else POLICY_OPTIONS
    allowed = base + (ORACLE_OPTIONS if card is not None and card.oracle else ())
    bad = sorted(set(options) - set(allowed))
    if bad:
        raise ParameterError(f"policy {policy.name!r} sets env option(s) {bad} that the "
                             f"protocol fixes; a policy may set only {list(base)} "
                             f"(an oracle also {list(ORACLE_OPTIONS)})")
    if options.get("estimate") == "nominal":
        options["estimate"] = FeedforwardModel.from_motor(knowledge.nominal.motor)
    harmonic, current = default_action_scales(knowledge.nominal)
    if options.get("harmonic_scale_nm") is None:
        options["harmonic_scale_nm"] = harmonic
    if options.get("current_scale_a") is None:
        options["current_scale_a"] = current
    return options


def policy_context(options: Mapping[str, Any], knowledge: MotorKnowledge, mode: str,
                   speed_rps: float, accel_rps2: float = DEFAULT_ACCEL_RPS2,
                   suite: str | None = None, window_s: float | None = None,
                   settle_s: float | None = None,
                   lag_limit_steps: float | None = None, profile: str = "constant",
                   distance_rev: float = 0.0, ramp: str = "trapezoid") -> PolicyContext:
    """The :class:`PolicyContext` of a run with the checked ``options``
    (:func:`policy_env_options`); ``suite`` None: the one of ``mode`` on the
    nominal motor's drive (:func:`.suites.suite_of`); the run's measuring
    settings as :class:`PolicyContext` has them."""
    if suite is None:
        suite = suite_of(mode, knowledge.nominal.drive.drive_mode)
    else:
        get_suite(suite)
    base = options.get("base_controller", EnvOptions.base_controller)
    est = options.get("estimate", EnvOptions.estimate)
    action_mode = options.get("action_mode", EnvOptions.action_mode)
    return PolicyContext(
        knowledge=knowledge,
        estimate=None if base == "none" else (knowledge.exact if est == "exact" else est),
        mode=mode, speed_rps=speed_rps, action_mode=action_mode,
        action_scale=float(options["current_scale_a"] if action_mode == "current"
                           else options["harmonic_scale_nm"]),
        agent_hz=float(options.get("agent_hz", EnvOptions.agent_hz)),
        current_scale_a=float(options["current_scale_a"]),
        accel_rps2=float(accel_rps2), suite=suite,
        window_s=None if window_s is None else float(window_s),
        settle_s=None if settle_s is None else float(settle_s),
        lag_limit_steps=None if lag_limit_steps is None else float(lag_limit_steps),
        profile=profile, distance_rev=float(distance_rev), ramp=ramp)


assert set(ESTIMATES) <= set(KNOWLEDGE_ESTIMATES)
