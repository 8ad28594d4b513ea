"""The ``stepdamp-bench v0`` protocol and the leaderboard that runs it.

Protocol ``stepdamp-bench`` version ``v0`` (frozen: any change of a value below,
of the motor draw, the speed grid, the scoring or the statistics makes it v1)
=============================================================================

Suites
    ``open-loop`` (eqs. 7-8, microstepping at the holding current) and ``servo``
    (eqs. 14-15, encoder feedback). Every policy runs both (``--suite`` picks one).

Motors
    The four presets ``patent``, ``qsh4218-51-10-049``, ``qsh5718-56-28-126``,
    ``qsh6018-65-28-210`` plus three randomised motors drawn around each preset
    (16 motors). The draws come from one ``numpy.random.default_rng(7733051)``
    stream, preset by preset in that order, each field in the order R, L, Km, J,
    Kd1, Kd2, Kd4, Fs, phi1, phi2: magnitudes scaled by U(low, high) factors
    (R, L: 0.8-1.25; Km: 0.85-1.15; J: 0.5-2.0; Kd1, Kd2, Kd4, Fs: 0.5-1.5, the
    env's ``DEFAULT_RANDOMIZATION``, copied here so that v0 does not follow it),
    phases phi1, phi2 drawn U(-pi, pi) rad, validated by ``SystemParams``. A draw
    is usable only if the undamped drive (no feedforward, noise seed 0) keeps its
    position lag below half a full step at every speed of its grid in both
    suites; unusable draws are rejected and the stream moves on (at most 100
    attempts per motor), so the set is the same on every machine. Every motor,
    preset or drawn, carries the protocol's sensors: current-sensor noise
    ``current_noise_a`` = 0.01 A (standard deviation per sample) and an encoder
    of ``encoder_cpr`` = 4000 counts/rev. The drawn motors are named
    ``<preset>~r<k>``. Training must never use these motors (nor the protocol
    seed 7733051 to draw motors).

Speeds
    Per motor: its three predicted resonant speeds f4, f2, f1
    (``predicted_resonances``) and four off-resonance speeds 0.6*f4,
    sqrt(2)*f4, sqrt(2)*f2 and 1.3*f1 (between 0.6x the lowest and 1.3x the
    highest resonance, halfway between resonances on a log scale).

Runs
    Each run: ``StepperDampEnv(motor=<true motor>, mode=<suite>, speed_rps=v,
    accel_rps2=50, measure_from_s=<window start>, **policy options)`` reset
    with the evaluation seed (which also seeds the current-sensor noise), the
    policy reset with its :class:`~baselines.base.PolicyContext`, stepped with
    ``policy.act(obs)`` until the agent step in which the simulated time
    reaches the end of the measuring window, or until the env terminates (step
    loss, over-current); then ``env.run_metrics()``.
    Ramp 50 rev/s^2; settling: the simulation core's default
    (``simulation.measuring_window``: four decay times 1/(zeta*wn), clipped to
    [0.1, 0.6] s, after the ramp); measuring window 0.3 s rounded up to whole
    periods of the first detent harmonic. Per run the core's metrics
    (``RunMetrics.to_dict()``) are kept.

Seeds
    Evaluation seeds 1_000_000 + k, k = 0..4. Training must use seeds below
    1_000_000 (``TRAINING_SEED_LIMIT``).

Knowledge
    ``MotorKnowledge.nominal``: the preset the motor was drawn around (with the
    protocol's sensors); ``identified``: ``identify(true motor,
    method="iterative", noise_seed=<eval seed>).model``, once per (motor,
    seed) and shared by all policies; ``exact``: the plant's own model (oracle
    baselines only; entries that use it are flagged ``oracle``). The env option
    ``estimate="nominal"`` is resolved against the nominal preset, never the
    true motor, and unset action scales (``harmonic_scale_nm``,
    ``current_scale_a``) come from the nominal motor as in training with
    ``randomize=True``. A policy may set only ``POLICY_OPTIONS``; everything
    that defines the plant, the operating point or what is observed is fixed.

Scores (per motor and seed)
    ``headline``: the mean RMS velocity ripple (``rms_velocity_error_rad_s``)
    at the three resonant speeds divided by the mean of the undamped one
    (policy ``none``, same motor, seed and speeds); lower is better, ``none``
    scores 1. ``sweep_mean_ratio``: the mean over the whole speed grid of the
    per-speed ratio to ``none``; ``sweep_worst_ratio``: its maximum.
    ``rms_injected_current_a``: the mean over the grid of the RMS injected q
    current. A run that loses steps or is terminated counts with a ripple of
    ``FAILURE_RATIO`` = 10 times the undamped one (its own if larger); the
    step losses are also counted beside the score.

Aggregates (over motors and seeds)
    Interquartile mean (IQM: the mean of the middle 50 % of the per-(motor,
    seed) scores, fractional weights at the quartiles) with a 95 % percentile
    interval from a stratified bootstrap: 2000 resamples, strata = motors
    (each motor's seeds are resampled with replacement within it), generator
    ``numpy.random.default_rng(2000)``. The raw per-run numbers are kept.

``--quick`` (variant ``quick``, for CI): the four presets only, one seed
(1_000_000), the resonant speeds only, a 0.1 s measuring window. Its numbers
are not comparable with the full protocol's.
"""

from __future__ import annotations

import copy
import dataclasses
import importlib
import importlib.metadata
import json
import math
import multiprocessing
import os
import platform
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from .params import FeedforwardModel, ParameterError, SystemParams, get_preset
from .simulation import RunSettings, SpeedProfile, measuring_window, simulate

__all__ = [
    "PROTOCOL_NAME",
    "PROTOCOL_VERSION",
    "TRAINING_SEED_LIMIT",
    "POLICY_OPTIONS",
    "SUITES",
    "Protocol",
    "ProtocolMotor",
    "full_protocol",
    "quick_protocol",
    "protocol_motors",
    "PolicySource",
    "resolve_policy",
    "iqm",
    "stratified_bootstrap_ci",
    "run_leaderboard",
    "write_outputs",
]

PROTOCOL_NAME = "stepdamp-bench"
PROTOCOL_VERSION = "v0"
TRAINING_SEED_LIMIT = 1_000_000
SUITES = ("open-loop", "servo")
RESONANCE_HARMONICS = (4, 2, 1)
# A failed run (step loss, termination) counts as this many times the undamped ripple.
FAILURE_RATIO = 10.0

# What a policy may choose through env_options(); the rest is the protocol's.
POLICY_OPTIONS = ("base_controller", "estimate", "action_mode", "agent_hz",
                  "harmonic_scale_nm", "current_scale_a", "velocity_estimator",
                  "current_penalty", "termination_penalty")

# v0's randomisation ranges: a frozen copy of envs.DEFAULT_RANDOMIZATION.
_V0_RANDOMIZATION: tuple[tuple[str, float, float], ...] = (
    ("R", 0.8, 1.25), ("L", 0.8, 1.25), ("Km", 0.85, 1.15), ("J", 0.5, 2.0),
    ("Kd1", 0.5, 1.5), ("Kd2", 0.5, 1.5), ("Kd4", 0.5, 1.5), ("Fs", 0.5, 1.5),
    ("phi1", -math.pi, math.pi), ("phi2", -math.pi, math.pi),
)
_PHASES = ("phi1", "phi2")
_V0_PRESETS = ("patent", "qsh4218-51-10-049", "qsh5718-56-28-126", "qsh6018-65-28-210")
# Off-resonance speeds: (harmonic whose resonance anchors it, factor).
_V0_OFF_RESONANCE = ((4, 0.6), (4, math.sqrt(2.0)), (2, math.sqrt(2.0)), (1, 1.3))


@dataclass(frozen=True)
class Protocol:
    """Every setting of a ``stepdamp-bench`` protocol (see the module docstring).

    Use :func:`full_protocol` or :func:`quick_protocol`; other values are for
    tests and make results that are not v0's.
    """

    name: str = PROTOCOL_NAME
    version: str = PROTOCOL_VERSION
    variant: str = "full"
    suites: tuple[str, ...] = SUITES
    presets: tuple[str, ...] = _V0_PRESETS
    randomized_per_preset: int = 3
    motor_seed: int = 7733051
    randomization: tuple[tuple[str, float, float], ...] = _V0_RANDOMIZATION
    max_draw_attempts: int = 100
    usable_max_lag_steps: float = 0.5
    validation_noise_seed: int = 0
    eval_seeds: tuple[int, ...] = tuple(TRAINING_SEED_LIMIT + k for k in range(5))
    resonance_harmonics: tuple[int, ...] = RESONANCE_HARMONICS
    off_resonance: tuple[tuple[int, float], ...] = _V0_OFF_RESONANCE
    accel_rps2: float = 50.0
    window_s: float = 0.3
    settle: str = "core default: simulation.default_settle_s (4/(zeta*wn) in [0.1, 0.6] s)"
    current_noise_a: float = 0.01
    encoder_cpr: int = 4000
    identification_method: str = "iterative"
    failure_ratio: float = FAILURE_RATIO
    bootstrap_resamples: int = 2000
    bootstrap_seed: int = 2000
    confidence: float = 0.95

    def __post_init__(self) -> None:
        bad = [s for s in self.suites if s not in SUITES]
        if bad or not self.suites:
            raise ParameterError(f"suites={self.suites!r}: each must be one of {list(SUITES)}")
        if any(s < TRAINING_SEED_LIMIT for s in self.eval_seeds) or not self.eval_seeds:
            raise ParameterError(f"eval_seeds={self.eval_seeds!r}: each must be >= "
                                 f"{TRAINING_SEED_LIMIT} (training seeds are below it)")
        if not (isinstance(self.randomized_per_preset, int) and self.randomized_per_preset >= 0):
            raise ParameterError(f"randomized_per_preset={self.randomized_per_preset!r} is "
                                 "outside its allowed range [0, inf) (integer)")
        if not (math.isfinite(self.window_s) and self.window_s > 0):
            raise ParameterError(f"window_s={self.window_s!r} is outside (0, inf) s")

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["randomization"] = {n: [lo, hi] for n, lo, hi in self.randomization}
        out["off_resonance"] = [{"harmonic": h, "factor": f} for h, f in self.off_resonance]
        out["training_seed_limit"] = TRAINING_SEED_LIMIT
        out["policy_options"] = list(POLICY_OPTIONS)
        out["headline"] = ("mean RMS velocity ripple at the resonant speeds / the same for "
                           "policy 'none' (same motor, seed); IQM over motors and seeds")
        return out

    def with_suites(self, suites: Sequence[str]) -> "Protocol":
        return dataclasses.replace(self, suites=tuple(suites))


def full_protocol() -> Protocol:
    """``stepdamp-bench v0``, the full protocol."""
    return Protocol()


def quick_protocol() -> Protocol:
    """The reduced CI variant: presets only, one seed, resonant speeds, 0.1 s window."""
    return Protocol(variant="quick", randomized_per_preset=0,
                    eval_seeds=(TRAINING_SEED_LIMIT,), off_resonance=(), window_s=0.1)


# ---------------------------------------------------------------------------
# Motors and speeds
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class ProtocolMotor:
    """One motor of the protocol: the true plant and what a drive may know."""

    name: str
    system: SystemParams        # true plant, with the protocol's sensors
    nominal: SystemParams       # the preset it was drawn around (same sensors)
    speeds_rps: tuple[float, ...]
    speed_labels: tuple[str, ...]   # "h4", "h2", "h1" or "off"
    draw_attempts: int = 0          # draws it took (0 for a preset)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "nominal": self.nominal.name,
                "parameters": self.system.to_dict(),
                "speeds_rps": list(self.speeds_rps), "speed_labels": list(self.speed_labels),
                "draw_attempts": self.draw_attempts,
                "predicted_resonances_rps": {str(h): v for h, v in
                                             self.system.predicted_resonances_rps().items()}}


def _with_sensors(system: SystemParams, protocol: Protocol) -> SystemParams:
    return system.replace(current_noise_a=protocol.current_noise_a,
                          encoder_cpr=protocol.encoder_cpr)


def speed_grid(system: SystemParams, protocol: Protocol) -> tuple[tuple[float, ...],
                                                                  tuple[str, ...]]:
    """(speeds in rev/s ascending, labels) of one motor."""
    res = system.predicted_resonances_rps()
    points = [(res[h], f"h{h}") for h in protocol.resonance_harmonics]
    points += [(res[h] * f, "off") for h, f in protocol.off_resonance]
    points.sort(key=lambda p: p[0])
    return tuple(float(v) for v, _ in points), tuple(lbl for _, lbl in points)


def _usable(system: SystemParams, speeds: Sequence[float], protocol: Protocol) -> bool:
    """No undamped run of the grid lags by half a full step or more (both suites)."""
    for mode in SUITES:
        settings = RunSettings(mode=mode, damping="none", window_s=protocol.window_s,
                               noise_seed=protocol.validation_noise_seed)
        for v in speeds:
            res = simulate(system, profile=SpeedProfile(speed_rps=v,
                                                        accel_rps2=protocol.accel_rps2),
                           settings=settings)
            if not res.metrics.max_position_lag_steps < protocol.usable_max_lag_steps:
                return False
    return True


_MOTOR_CACHE: dict[Protocol, tuple[ProtocolMotor, ...]] = {}


def protocol_motors(protocol: Protocol) -> tuple[ProtocolMotor, ...]:
    """The protocol's motors: presets first, then the draws (deterministic)."""
    if protocol in _MOTOR_CACHE:
        return _MOTOR_CACHE[protocol]
    motors: list[ProtocolMotor] = []
    nominals = {name: _with_sensors(get_preset(name), protocol) for name in protocol.presets}
    for name, nom in nominals.items():
        speeds, labels = speed_grid(nom, protocol)
        motors.append(ProtocolMotor(name, nom, nom, speeds, labels))
    rng = np.random.default_rng(protocol.motor_seed)
    for name, nom in nominals.items():
        for k in range(protocol.randomized_per_preset):
            for attempt in range(1, protocol.max_draw_attempts + 1):
                changes: dict[str, Any] = {"name": f"{name}~r{k}"}
                for field_name, lo, hi in protocol.randomization:
                    x = float(rng.uniform(lo, hi))
                    changes[field_name] = x if field_name in _PHASES else \
                        getattr(nom.motor, field_name) * x
                try:
                    system = nom.replace(**changes)
                except ParameterError:
                    continue
                speeds, labels = speed_grid(system, protocol)
                if _usable(system, speeds, protocol):
                    motors.append(ProtocolMotor(system.name, system, nom, speeds, labels,
                                                attempt))
                    break
            else:
                raise RuntimeError(f"no usable draw around {name!r} in "
                                   f"{protocol.max_draw_attempts} attempts")
    _MOTOR_CACHE[protocol] = tuple(motors)
    return _MOTOR_CACHE[protocol]


# ---------------------------------------------------------------------------
# Policies: baselines, module paths, SB3 model files
# ---------------------------------------------------------------------------
def _sb3_algo_class(path: str):
    """The SB3 algorithm class of a saved model, from the policy class in its metadata."""
    import zipfile

    import stable_baselines3 as sb3

    module = ""
    try:
        with zipfile.ZipFile(path) as zf:
            data = json.loads(zf.read("data").decode("utf-8"))
        module = str(data.get("policy_class", {}).get("__module__", ""))
    except (KeyError, ValueError, zipfile.BadZipFile, AttributeError):
        pass
    for key, algo in ((".sac.", "SAC"), (".td3.", "TD3"), (".ddpg.", "DDPG"),
                      (".dqn.", "DQN"), (".ppo.", "PPO"), (".a2c.", "A2C")):
        if key in module + ".":
            return [getattr(sb3, algo)]
    # ActorCriticPolicy lives in common.policies (PPO and A2C); else try them all.
    return [sb3.PPO, sb3.SAC, sb3.TD3, sb3.A2C]


class SB3Policy:
    """A saved SB3 model as a :class:`~baselines.base.Policy`: deterministic predict.

    Env options: the JSON file beside the model with the same stem if present
    (``estimate`` may be "exact", "identified" or "nominal"), else harmonic
    residuals on top of the patent feedforward with the identified model.
    """

    def __init__(self, name: str, model: Any, options: Mapping[str, Any] | None) -> None:
        self.name = name
        self.model = model
        self.options = dict(options) if options else {"base_controller": "patent-ff",
                                                      "estimate": "identified",
                                                      "action_mode": "harmonic"}

    def env_options(self, knowledge) -> dict[str, Any]:
        from baselines.base import resolve_estimate

        out = dict(self.options)
        if isinstance(out.get("estimate"), str):
            out["estimate"] = resolve_estimate(out["estimate"], knowledge)
        return out

    def reset(self, context) -> None:
        pass

    def act(self, observation: np.ndarray) -> np.ndarray:
        action, _ = self.model.predict(observation, deterministic=True)
        return np.asarray(action, dtype=np.float32)


@dataclass
class PolicySource:
    """Makes fresh policy instances for one leaderboard entry."""

    spec: str
    name: str
    make: Callable[[], Any]


def _check_policy(obj: Any, spec: str) -> None:
    for attr in ("name", "env_options", "reset", "act"):
        if not hasattr(obj, attr):
            raise ParameterError(f"policy {spec!r} has no {attr!r}: a Policy needs name, "
                                 "env_options(knowledge), reset(context) and act(obs)")


def default_policy_names() -> tuple[str, ...]:
    """What a leaderboard runs by default: every baseline and every committed
    reference agent (``agents/reference``)."""
    from agents import reference_names
    from baselines import BASELINE_NAMES

    return tuple(BASELINE_NAMES) + reference_names()


def resolve_policy(spec: str) -> PolicySource:
    """A baseline name, ``package.module:attr`` or a ``.zip`` SB3 model file.

    ``attr`` may be a Policy class or factory (called without arguments for
    every run) or a Policy instance (deep-copied for every run).
    """
    from agents import reference_agent, reference_names
    from baselines import BASELINE_NAMES, make_baseline

    if spec in BASELINE_NAMES:
        return PolicySource(spec, spec, lambda: make_baseline(spec))
    if spec in reference_names():
        algo = spec.split("-")[0]
        return PolicySource(spec, spec, lambda: reference_agent(algo))
    if spec.endswith(".zip"):
        if not os.path.isfile(spec):
            raise ParameterError(f"policy file {spec!r} does not exist")
        path = os.path.abspath(spec)
        side = os.path.splitext(path)[0] + ".json"
        options = None
        if os.path.isfile(side):
            with open(side, encoding="utf-8") as fh:
                options = json.load(fh)
            if not isinstance(options, dict):
                raise ParameterError(f"{side!r} must hold a JSON object of env options")
        errors = []
        model = None
        for algo in _sb3_algo_class(path):
            try:
                model = algo.load(path, device="cpu")
                break
            except Exception as exc:  # noqa: BLE001 - try the next algorithm
                errors.append(f"{algo.__name__}: {exc}")
        if model is None:
            raise ParameterError(f"cannot load SB3 model {spec!r}: {'; '.join(errors)}")
        name = os.path.splitext(os.path.basename(path))[0]
        return PolicySource(spec, name, lambda: SB3Policy(name, model, options))
    if ":" in spec:
        module_name, _, attr = spec.partition(":")
        try:
            module = importlib.import_module(module_name)
            obj = getattr(module, attr)
        except (ImportError, AttributeError) as exc:
            raise ParameterError(f"policy {spec!r}: {exc}") from None
        if isinstance(obj, type) or (callable(obj) and not hasattr(obj, "act")):
            probe = obj()
            _check_policy(probe, spec)
            return PolicySource(spec, str(probe.name), obj)
        _check_policy(obj, spec)
        return PolicySource(spec, str(obj.name), lambda: copy.deepcopy(obj))
    raise ParameterError(f"policy {spec!r} is not one of the baselines {list(BASELINE_NAMES)}, "
                         f"a reference agent {list(reference_names())}, "
                         "a 'package.module:attr' path or an SB3 '.zip' model file")


# ---------------------------------------------------------------------------
# Runs (executed in worker processes)
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class _Job:
    spec: str
    suite: str
    motor_index: int
    seed: int
    speed_index: int


_WORKER: dict[str, Any] = {}


def _init_worker(motors: tuple[ProtocolMotor, ...], knowledge: dict, protocol: Protocol,
                 sources: dict[str, PolicySource] | None) -> None:
    _WORKER["motors"] = motors
    _WORKER["knowledge"] = knowledge
    _WORKER["protocol"] = protocol
    _WORKER["sources"] = dict(sources or {})
    if "torch" in sys.modules:     # one thread per process: both cores, no oversubscription
        sys.modules["torch"].set_num_threads(1)


def _source(spec: str) -> PolicySource:
    sources = _WORKER.setdefault("sources", {})
    if spec not in sources:
        sources[spec] = resolve_policy(spec)
    return sources[spec]


def _identify_job(args: tuple[int, int]) -> FeedforwardModel | None:
    motor_index, seed = args
    try:
        from .identify import identify
    except ImportError:
        return None
    motor = _WORKER["motors"][motor_index]
    result = identify(motor.system, method=_WORKER["protocol"].identification_method,
                      noise_seed=seed)
    return result.model


def policy_env_options(policy: Any, knowledge: Any) -> dict[str, Any]:
    """The policy's env options, checked against ``POLICY_OPTIONS`` and made fair:
    "nominal" is the nominal preset and unset action scales come from it."""
    options = dict(policy.env_options(knowledge))
    bad = sorted(set(options) - set(POLICY_OPTIONS))
    if bad:
        raise ParameterError(f"policy {policy.name!r} sets env option(s) {bad} that the "
                             f"protocol fixes; a policy may set only {list(POLICY_OPTIONS)}")
    if options.get("estimate") == "nominal":
        options["estimate"] = FeedforwardModel.from_motor(knowledge.nominal.motor)
    m, drive = knowledge.nominal.motor, knowledge.nominal.drive
    if options.get("harmonic_scale_nm") is None:
        scale = 2.0 * max(m.Kd1, m.Kd2, m.Kd4)
        options["harmonic_scale_nm"] = scale if scale > 0 else 0.02 * m.Km * drive.holding_current
    if options.get("current_scale_a") is None:
        options["current_scale_a"] = 0.25 * drive.holding_current
    return options


def _run_job(job: _Job) -> dict[str, Any]:
    from .envs import StepperDampEnv

    protocol: Protocol = _WORKER["protocol"]
    motor: ProtocolMotor = _WORKER["motors"][job.motor_index]
    knowledge = _WORKER["knowledge"][(job.motor_index, job.seed)]
    speed = motor.speeds_rps[job.speed_index]
    start, length = measuring_window(motor.system,
                                     SpeedProfile(speed_rps=speed, accel_rps2=protocol.accel_rps2),
                                     RunSettings(window_s=protocol.window_s))
    policy = _source(job.spec).make()
    options = policy_env_options(policy, knowledge)
    env = StepperDampEnv(motor=motor.system, mode=job.suite, speed_rps=speed,
                         accel_rps2=protocol.accel_rps2, measure_from_s=start, **options)
    obs, _ = env.reset(seed=job.seed)
    policy.reset(policy_context(options, knowledge, job.suite, speed))
    # Half a PWM period of slack: time_s is a float multiple of the period.
    end = start + length - 0.5 / motor.system.drive.pwm_hz
    steps, terminated, reason = 0, False, ""
    while env.time_s < end:
        obs, _, terminated, _, info = env.step(policy.act(obs))
        steps += 1
        if terminated:
            reason = ("step_loss" if info["step_loss"] else
                      "overcurrent" if info["overcurrent"] else "non_finite")
            break
    try:
        metrics: dict[str, Any] | None = env.run_metrics().to_dict()
    except ValueError:                  # terminated before the window opened
        metrics = None
    env.close()
    failed = terminated or (metrics is not None and bool(metrics["step_loss"]))
    return {"motor": motor.name, "seed": job.seed, "speed_rps": speed,
            "speed_label": motor.speed_labels[job.speed_index], "terminated": terminated,
            "termination": reason, "failed": failed, "steps": steps,
            "window_start_s": start, "window_s": length, "metrics": metrics}


def _warm_up(system: SystemParams) -> None:
    """Load the compiled kernel and env helpers once, before forking, so that the
    workers inherit them instead of each loading the numba cache again."""
    from .envs import StepperDampEnv

    simulate(system, settings=RunSettings(settle_s=0.0, window_s=0.001), trace=True,
             profile=SpeedProfile(speed_rps=0.5, accel_rps2=1000.0))
    env = StepperDampEnv(motor=system, speed_rps=0.5, measure_from_s=0.0)
    env.reset(seed=0)
    env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    env.run_metrics()


def _pool_map(fn: Callable, jobs: list, workers: int, initargs: tuple, bar=None) -> list:
    """Ordered results of fn over jobs, in this process or on ``workers`` forks."""
    out = []
    if workers <= 1 or len(jobs) < 2:
        _init_worker(*initargs)
        for job in jobs:
            out.append(fn(job))
            if bar is not None:
                bar.update()
        return out
    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    chunk = max(1, min(16, len(jobs) // (workers * 8)))
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context(method),
                             initializer=_init_worker, initargs=initargs) as pool:
        for r in pool.map(fn, jobs, chunksize=chunk):
            out.append(r)
            if bar is not None:
                bar.update()
    return out


# ---------------------------------------------------------------------------
# Statistics
# ---------------------------------------------------------------------------
def _iqm_weights(n: int) -> np.ndarray:
    """Weights of the sorted samples: each covers [i/n, (i+1)/n] of the
    distribution; its weight is its overlap with [0.25, 0.75], over 0.5."""
    edges = np.arange(n + 1) / n
    overlap = np.clip(np.minimum(edges[1:], 0.75) - np.maximum(edges[:-1], 0.25), 0.0, None)
    return overlap / 0.5


def iqm(values: Iterable[float]) -> float:
    """Interquartile mean: the mean of the middle 50 % (fractional at the quartiles)."""
    x = np.sort(np.asarray(list(values), dtype=float))
    if x.size == 0:
        return math.nan
    return float(x @ _iqm_weights(x.size))


def stratified_bootstrap_ci(values: Sequence[float], strata: Sequence[Any], *,
                            resamples: int = 2000, seed: int = 2000,
                            confidence: float = 0.95) -> tuple[float, float]:
    """Percentile interval of the IQM under a bootstrap that resamples within strata.

    Each resample draws, in every stratum, as many values as it holds, with
    replacement, from that stratum only; strata are visited in sorted order so
    the result does not depend on the input order of the strata.
    """
    x = np.asarray(values, dtype=float)
    keys = list(strata)
    if x.size == 0:
        return (math.nan, math.nan)
    if len(keys) != x.size:
        raise ValueError(f"strata has {len(keys)} labels for {x.size} values")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence={confidence!r} is outside (0, 1)")
    rng = np.random.default_rng(seed)
    groups = {}
    for i, k in enumerate(keys):
        groups.setdefault(k, []).append(i)
    parts = []
    for k in sorted(groups, key=str):
        idx = np.asarray(groups[k])
        parts.append(x[idx[rng.integers(0, idx.size, size=(resamples, idx.size))]])
    sample = np.sort(np.concatenate(parts, axis=1), axis=1)
    stats = sample @ _iqm_weights(sample.shape[1])
    alpha = (1.0 - confidence) / 2.0
    low, high = np.quantile(stats, [alpha, 1.0 - alpha])
    return (float(low), float(high))


def _summary(values: list[float], strata: list[str], protocol: Protocol) -> dict[str, Any]:
    x = np.asarray(values, dtype=float)
    keep = np.isfinite(x)
    x, s = x[keep], [k for k, ok in zip(strata, keep) if ok]
    low, high = stratified_bootstrap_ci(x, s, resamples=protocol.bootstrap_resamples,
                                        seed=protocol.bootstrap_seed,
                                        confidence=protocol.confidence)
    return {"iqm": iqm(x), "ci95": [low, high], "n": int(x.size)}


def _scores(runs: list[dict], reference: dict[tuple, dict], protocol: Protocol
            ) -> list[dict[str, Any]]:
    """Per (motor, seed) scores of one entry against the ``none`` runs."""
    groups: dict[tuple[str, int], list[dict]] = {}
    for r in runs:
        groups.setdefault((r["motor"], r["seed"]), []).append(r)
    out = []
    for (motor, seed), rs in groups.items():
        ratios, res_p, res_n, currents = [], [], [], []
        for r in rs:
            ref = reference.get((motor, seed, r["speed_rps"]))
            ok_ref = ref is not None and not ref["failed"] and ref["metrics"] is not None
            ref_rms = ref["metrics"]["rms_velocity_error_rad_s"] if ok_ref else math.nan
            own = r["metrics"]["rms_velocity_error_rad_s"] if r["metrics"] else math.nan
            if r["failed"]:
                own = max(own, protocol.failure_ratio * ref_rms) if math.isfinite(own) \
                    else protocol.failure_ratio * ref_rms
            ratios.append(own / ref_rms)
            if r["speed_label"] != "off":
                res_p.append(own)
                res_n.append(ref_rms)
            if r["metrics"]:
                currents.append(r["metrics"]["rms_injected_current_a"])
        ratios_a = np.asarray(ratios)
        fin = ratios_a[np.isfinite(ratios_a)]
        pn, nn = np.asarray(res_p, dtype=float), np.asarray(res_n, dtype=float)
        both = np.isfinite(pn) & np.isfinite(nn)
        out.append({
            "motor": motor, "seed": seed,
            "headline": float(pn[both].mean() / nn[both].mean()) if both.any() else math.nan,
            "sweep_mean_ratio": float(fin.mean()) if fin.size else math.nan,
            "sweep_worst_ratio": float(fin.max()) if fin.size else math.nan,
            "rms_injected_current_a": float(np.mean(currents)) if currents else math.nan,
            "step_losses": int(sum(r["failed"] for r in rs)),
            "runs": len(rs)})
    return out


def _entry(source: PolicySource, suite: str, runs: list[dict], reference: dict,
           protocol: Protocol, meta: dict[str, Any]) -> dict[str, Any]:
    scores = _scores(runs, reference, protocol)
    strata = [s["motor"] for s in scores]
    entry: dict[str, Any] = {"name": source.name, "spec": source.spec, "suite": suite, **meta}
    entry["headline"] = _summary([s["headline"] for s in scores], strata, protocol)
    for key in ("sweep_mean_ratio", "sweep_worst_ratio", "rms_injected_current_a"):
        entry[key] = _summary([s[key] for s in scores], strata, protocol)
    entry["sweep_worst_ratio"]["max"] = float(np.nanmax([s["sweep_worst_ratio"]
                                                         for s in scores]))
    entry["step_losses"] = {"runs_lost": int(sum(r["failed"] for r in runs)),
                            "runs": len(runs)}
    per_motor: dict[str, list[float]] = {}
    for s in scores:
        per_motor.setdefault(s["motor"], []).append(s["headline"])
    entry["per_motor_headline_mean"] = {k: float(np.mean(v)) for k, v in per_motor.items()}
    entry["scores"] = scores
    entry["runs"] = runs
    return entry


# ---------------------------------------------------------------------------
# The leaderboard
# ---------------------------------------------------------------------------
def _versions() -> dict[str, str]:
    from . import __version__

    out = {"package": __version__, "python": platform.python_version()}
    for dist, key in (("numpy", "numpy"), ("numba", "numba"), ("gymnasium", "gymnasium"),
                      ("stable-baselines3", "stable-baselines3"), ("torch", "torch")):
        try:
            out[key] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[key] = "not installed"
    return out


def _policy_meta(source: PolicySource, knowledge: Any) -> dict[str, Any]:
    """Oracle flag and the env options of a policy, JSON-ready."""
    policy = source.make()
    raw = dict(policy.env_options(knowledge))
    options = policy_env_options(policy, knowledge)
    est = raw.get("estimate", "exact")
    if isinstance(est, FeedforwardModel):
        # Nominal is checked before exact: for a preset the two are equal.
        est = ("identified" if est == knowledge.identified else
               "nominal" if est == FeedforwardModel.from_motor(knowledge.nominal.motor) else
               "exact" if est == knowledge.exact else "model")
    options["estimate"] = est
    oracle = est == "exact" and options.get("base_controller", "patent-ff") != "none"
    return {"oracle": bool(oracle), "env_options": options}


def run_leaderboard(protocol: Protocol, policies: Sequence[str] | None = None, *,
                    workers: int | None = None, progress: bool = True) -> dict[str, Any]:
    """Evaluate policies (baseline names, module paths, .zip files) under ``protocol``.

    ``policies`` defaults to :func:`default_policy_names`; ``none`` is always run (it is the
    reference of every ratio). Returns the leaderboard as a JSON-ready dict.
    Runs are independent and deterministic: the result does not depend on
    ``workers`` (default: every core this process may use). If torch is loaded
    (SB3 policies), it is set to one thread in this process too, so that a
    serial run computes exactly what a worker does.
    """
    from baselines.base import MotorKnowledge

    from .sweep import default_workers

    specs = list(dict.fromkeys(["none", *(policies if policies is not None
                                          else default_policy_names())]))
    sources = {spec: resolve_policy(spec) for spec in specs}
    names = [s.name for s in sources.values()]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ParameterError(f"two policies share the name(s) {dupes}; names must be unique")
    workers = default_workers() if workers is None else max(1, int(workers))
    motors = protocol_motors(protocol)
    pairs = [(i, seed) for i in range(len(motors)) for seed in protocol.eval_seeds]
    _warm_up(motors[0].system)

    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(pairs), desc="identify", unit="motor")
    init: tuple = (motors, {}, protocol, None)
    identified = _pool_map(_identify_job, pairs, workers, init, bar)
    if bar is not None:
        bar.close()
    knowledge = {(i, seed): MotorKnowledge(nominal=motors[i].nominal, identified=model,
                                           exact=FeedforwardModel.from_motor(motors[i].system.motor))
                 for (i, seed), model in zip(pairs, identified)}

    # Options and oracle flag per policy, for the record; the last motor is a drawn
    # one in the full protocol, where nominal, identified and exact all differ.
    meta = {spec: _policy_meta(src, knowledge[pairs[-1]]) for spec, src in sources.items()}

    jobs = [_Job(spec, suite, i, seed, j)
            for spec in specs for suite in protocol.suites
            for i, m in enumerate(motors) for seed in protocol.eval_seeds
            for j in range(len(m.speeds_rps))]
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(jobs), desc="leaderboard", unit="run")
    # SB3 models are loaded in the parent and inherited by the forked workers.
    results = _pool_map(_run_job, jobs, workers, (motors, knowledge, protocol, sources), bar)
    if bar is not None:
        bar.close()

    by_entry: dict[tuple[str, str], list[dict]] = {}
    for job, res in zip(jobs, results):
        by_entry.setdefault((job.spec, job.suite), []).append(res)
    entries = []
    for suite in protocol.suites:
        ref_runs = by_entry[("none", suite)]
        reference = {(r["motor"], r["seed"], r["speed_rps"]): r for r in ref_runs}
        suite_entries = [_entry(sources[spec], suite, by_entry[(spec, suite)], reference,
                                protocol, meta[spec]) for spec in specs]
        suite_entries.sort(key=lambda e: (not math.isfinite(e["headline"]["iqm"]),
                                          e["headline"]["iqm"], e["name"]))
        for rank, e in enumerate(suite_entries, 1):
            e["rank"] = rank
        entries += suite_entries
    identification = [{"motor": motors[i].name, "seed": seed,
                       "model": dataclasses.asdict(m) if m is not None else None}
                      for (i, seed), m in zip(pairs, identified)]
    return {"protocol": {**protocol.to_dict(), "motors": [m.to_dict() for m in motors]},
            "versions": _versions(), "identification": identification, "entries": entries}


# ---------------------------------------------------------------------------
# Outputs
# ---------------------------------------------------------------------------
def _fmt_ci(s: Mapping[str, Any], digits: int = 3) -> str:
    lo, hi = s["ci95"]
    return f"{s['iqm']:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def render_markdown(board: Mapping[str, Any]) -> str:
    """``LEADERBOARD.md``: one ranked table per suite."""
    p = board["protocol"]
    lines = [f"# Leaderboard: {p['name']} {p['version']} ({p['variant']})", "",
             f"{len(p['motors'])} motors x {len(p['eval_seeds'])} seeds; "
             f"window {p['window_s']} s, ramp {p['accel_rps2']} rev/s^2, current noise "
             f"{p['current_noise_a']} A, encoder {p['encoder_cpr']} counts/rev.",
             "Headline: mean RMS velocity ripple at the three resonant speeds over that of "
             "`none` (lower is better); IQM over motors x seeds with a 95 % stratified "
             "bootstrap interval. `oracle` entries use the plant's exact detent model.", ""]
    for suite in p["suites"]:
        rows = sorted((e for e in board["entries"] if e["suite"] == suite),
                      key=lambda e: e["rank"])
        lines += [f"## {suite}", "",
                  "| rank | policy | headline IQM [95 % CI] | sweep mean ratio | "
                  "sweep worst (IQM / max) | step losses | RMS injected current (A) |",
                  "|---|---|---|---|---|---|---|"]
        for e in rows:
            name = e["name"] + (" (oracle)" if e.get("oracle") else "")
            sw = e["sweep_worst_ratio"]
            sl = e["step_losses"]
            lines.append(f"| {e['rank']} | {name} | {_fmt_ci(e['headline'])} | "
                         f"{_fmt_ci(e['sweep_mean_ratio'])} | {sw['iqm']:.3f} / {sw['max']:.3f} | "
                         f"{sl['runs_lost']}/{sl['runs']} | "
                         f"{e['rms_injected_current_a']['iqm']:.4f} |")
        lines.append("")
    v = board["versions"]
    lines.append("Versions: " + ", ".join(f"{k} {val}" for k, val in v.items()))
    return "\n".join(lines) + "\n"


def _representative(board: Mapping[str, Any]) -> tuple[str, int]:
    p = board["protocol"]
    return p["motors"][0]["name"], p["eval_seeds"][0]


def plot_ripple(board: Mapping[str, Any], suite: str, path: str) -> None:
    """RMS ripple against speed per entry, for the representative motor and seed."""
    from .plots import _pyplot, _save

    plt = _pyplot()
    motor, seed = _representative(board)
    info = board["protocol"]["motors"][0]
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for e in sorted((e for e in board["entries"] if e["suite"] == suite), key=lambda e: e["rank"]):
        rs = sorted((r for r in e["runs"] if r["motor"] == motor and r["seed"] == seed
                     and r["metrics"] is not None), key=lambda r: r["speed_rps"])
        ax.semilogy([r["speed_rps"] for r in rs],
                    [r["metrics"]["rms_velocity_error_rad_s"] for r in rs], marker="o",
                    label=e["name"])
    for h, v in info["predicted_resonances_rps"].items():
        ax.axvline(v, color="grey", ls="--", lw=0.8)
        ax.text(v, 1.0, f" h={h}", transform=ax.get_xaxis_transform(), va="top",
                fontsize=8, color="grey")
    ax.set_xlabel("command speed (rev/s)")
    ax.set_ylabel("RMS velocity error (rad/s)")
    ax.set_title(f"{suite}: {motor}, seed {seed}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def policy_context(options: Mapping[str, Any], knowledge: Any, suite: str,
                   speed_rps: float) -> Any:
    """The :class:`~baselines.base.PolicyContext` of a run with the checked
    ``options`` (:func:`policy_env_options`)."""
    from baselines.base import PolicyContext

    base = options.get("base_controller", "patent-ff")
    est = options.get("estimate", "exact")
    action_mode = options.get("action_mode", "harmonic")
    return PolicyContext(
        knowledge=knowledge,
        estimate=None if base == "none" else (knowledge.exact if est == "exact" else est),
        mode=suite, speed_rps=speed_rps, action_mode=action_mode,
        action_scale=float(options["current_scale_a"] if action_mode == "current"
                           else options["harmonic_scale_nm"]),
        agent_hz=float(options.get("agent_hz", 1000.0)),
        current_scale_a=float(options["current_scale_a"]))


def trace_run(spec: str, motor: ProtocolMotor, knowledge: Any, suite: str, speed_rps: float,
              seed: int, protocol: Protocol, span_s: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """(time in the window (s), velocity error w_cmd - w (rad/s)) at the agent rate."""
    from . import kernel as K
    from .envs import StepperDampEnv

    policy = resolve_policy(spec).make()
    options = policy_env_options(policy, knowledge)
    start, _ = measuring_window(motor.system, SpeedProfile(speed_rps, protocol.accel_rps2),
                                RunSettings(window_s=protocol.window_s))
    env = StepperDampEnv(motor=motor.system, mode=suite, speed_rps=speed_rps,
                         accel_rps2=protocol.accel_rps2, **options)
    obs, _ = env.reset(seed=seed)
    policy.reset(policy_context(options, knowledge, suite, speed_rps))
    t, err = [], []
    while env.time_s < start + span_s:
        obs, _, terminated, _, _ = env.step(policy.act(obs))
        if env.time_s >= start:
            s = env.drive_state
            t.append(env.time_s - start)
            err.append(s[K.S_OMEGA_CMD] - s[K.S_OMEGA])
        if terminated:
            break
    return np.asarray(t), np.asarray(err)


def plot_resonance_traces(board: Mapping[str, Any], suite: str, path: str,
                          protocol: Protocol) -> None:
    """Velocity error against time at the three resonances: none vs the best entry
    (patent Figs. 4-7 style), representative motor and seed."""
    from baselines.base import MotorKnowledge

    from .plots import _pyplot, _save

    rows = sorted((e for e in board["entries"] if e["suite"] == suite), key=lambda e: e["rank"])
    best = next((e for e in rows if e["spec"] != "none"), None)
    specs = [("none", "none")] + ([(best["spec"], best["name"])] if best else [])
    motors = protocol_motors(protocol)
    motor = motors[0]
    seed = protocol.eval_seeds[0]
    ident = next(x["model"] for x in board["identification"]
                 if x["motor"] == motor.name and x["seed"] == seed)
    knowledge = MotorKnowledge(nominal=motor.nominal,
                               identified=FeedforwardModel(**ident) if ident else None,
                               exact=FeedforwardModel.from_motor(motor.system.motor))
    res = motor.system.predicted_resonances_rps()
    plt = _pyplot()
    fig, axes = plt.subplots(len(res), 1, figsize=(8, 6.5), sharex=True, squeeze=False)
    for ax, (h, v) in zip(axes[:, 0], res.items()):
        for spec, name in specs:
            t, err = trace_run(spec, motor, knowledge, suite, v, seed, protocol)
            ax.plot(t * 1e3, err, lw=0.8, label=name)
        ax.set_ylabel("rad/s", fontsize=8)
        ax.text(0.99, 0.92, f"h={h}: {v:.3g} rev/s", transform=ax.transAxes, ha="right",
                va="top", fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(fontsize=8, loc="upper left")
    axes[-1, 0].set_xlabel("time in the measuring window (ms; sampled at the agent rate)")
    fig.suptitle(f"Velocity error w_cmd - w at the resonances: {motor.name}, {suite}",
                 fontsize=10)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def write_outputs(board: Mapping[str, Any], out_dir: str, protocol: Protocol,
                  plots: bool = True) -> list[str]:
    """Write leaderboard.json, LEADERBOARD.md and the figures (atomically)."""
    from .io import atomic_path, write_json

    os.makedirs(out_dir, exist_ok=True)
    written = [os.path.join(out_dir, "leaderboard.json"), os.path.join(out_dir, "LEADERBOARD.md")]
    write_json(written[0], board)
    with atomic_path(written[1]) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(render_markdown(board))
    if plots:
        for suite in board["protocol"]["suites"]:
            p1 = os.path.join(out_dir, f"ripple_vs_speed_{suite}.png")
            p2 = os.path.join(out_dir, f"velocity_error_resonances_{suite}.png")
            plot_ripple(board, suite, p1)
            plot_resonance_traces(board, suite, p2, protocol)
            written += [p1, p2]
    return written
