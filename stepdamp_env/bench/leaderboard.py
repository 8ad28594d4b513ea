"""The leaderboard: every policy under a protocol, in a process pool, scored and ranked.

:func:`run_leaderboard` identifies each (motor, seed) once, runs every policy
(:mod:`.registry`) on every motor, seed, suite and speed of the protocol
(:mod:`.protocol`, :mod:`.motors`) with the one episode runner
(:func:`.runner.run_episode`), scores the runs against the reference policy
(:mod:`.scoring`, :mod:`.stats`) and returns the board as a JSON-ready dict;
:func:`.report.write_outputs` writes it.
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import math
import platform
import sys
import time
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..env.options import EnvOptions
from ..env.scalar import StepperDampEnv
from ..identify import identify
from ..parallel import default_workers, pool_map
from ..params import FeedforwardModel, ParameterError, SystemParams
from ..simulation import RunSettings, SpeedProfile, simulate
from .motors import ProtocolMotor, protocol_motors
from .policy import MotorKnowledge, policy_card, policy_env_options
from .rig import CalibrationRig
from .protocol import REFERENCE_POLICY, Protocol
from .protocol_v1 import ProtocolV1
from .registry import PolicySource, default_policy_names, resolve_policy
from .runner import run_episode
from .scoring import (add_probability_of_improvement, make_entry, make_entry_v1,
                      reference_index)

__all__ = ["LeaderboardJob", "run_leaderboard", "package_versions", "protocol_knowledge"]


@dataclass(frozen=True)
class LeaderboardJob:
    """One run of the leaderboard (indices into the protocol's motors and grids)."""

    spec: str
    suite: str
    motor_index: int
    seed: int
    speed_index: int
    training_seed: int | None = None      # v1: which of a learned entry's models


# What a worker process needs; set once per process by _init_worker.
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


def _make(spec: str, training_seed: int | None) -> Any:
    source = _source(spec)
    return source.make() if training_seed is None else source.training_seeds[training_seed]()


def _identify_job(args: tuple[int, int]) -> FeedforwardModel | str:
    """The identified model; under v1 the reason as a string if identification
    failed (the drive then falls back to its nominal model, see protocol_v1)."""
    motor_index, seed = args
    motor = _WORKER["motors"][motor_index]
    protocol = _WORKER["protocol"]
    try:
        return identify(motor.system, method=protocol.identification_method,
                        noise_seed=seed).model
    except (RuntimeError, ParameterError) as exc:
        if not isinstance(protocol, ProtocolV1):
            raise
        return f"{type(exc).__name__}: {exc}"


def _run_job(job: LeaderboardJob) -> dict[str, Any]:
    protocol: Protocol = _WORKER["protocol"]
    motor: ProtocolMotor = _WORKER["motors"][job.motor_index]
    speeds, labels = motor.speeds(job.suite)
    speed = speeds[job.speed_index]
    result = run_episode(_make(job.spec, job.training_seed),
                         _WORKER["knowledge"][(job.motor_index, job.seed)], motor.system,
                         mode=job.suite, speed_rps=speed, seed=job.seed,
                         accel_rps2=protocol.accel_rps2, window_s=protocol.window_s,
                         settle_s=motor.settle_s(job.suite))
    return result.record(motor.name, job.seed, speed, labels[job.speed_index],
                         job.training_seed)


def protocol_knowledge(motor: ProtocolMotor, seed: int, identified: FeedforwardModel | None,
                       protocol: Protocol | ProtocolV1) -> MotorKnowledge:
    """What the drive of a protocol run knows (the oracle-only fields included:
    entries that read them are flagged by their card)."""
    return MotorKnowledge(nominal=motor.nominal, identified=identified,
                          exact=FeedforwardModel.from_motor(motor.system.motor),
                          plant=motor.system,
                          rig=CalibrationRig(motor.system, seed, protocol.accel_rps2))


def _warm_up(system: SystemParams) -> None:
    """Load the compiled kernel and env helpers once, before forking, so that the
    workers inherit them instead of each loading the numba cache again."""
    simulate(system, settings=RunSettings(settle_s=0.0, window_s=0.001), trace=True,
             profile=SpeedProfile(speed_rps=0.5, accel_rps2=1000.0))
    env = StepperDampEnv(motor=system, speed_rps=0.5, measure_from_s=0.0)
    env.reset(seed=0)
    env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    env.run_metrics()


def package_versions() -> dict[str, str]:
    """Versions of this package, Python and the numerical dependencies."""
    from ..version import __version__

    out = {"package": __version__, "python": platform.python_version()}
    for dist, key in (("numpy", "numpy"), ("numba", "numba"), ("gymnasium", "gymnasium"),
                      ("stable-baselines3", "stable-baselines3"), ("torch", "torch")):
        try:
            out[key] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[key] = "not installed"
    return out


def _probe(knowledge: MotorKnowledge) -> MotorKnowledge:
    """Knowledge whose nominal model differs from the exact one, so that an entry's
    estimate can be told apart (on a preset or a custom motor they are equal)."""
    if FeedforwardModel.from_motor(knowledge.nominal.motor) != knowledge.exact:
        return knowledge
    m = knowledge.nominal.motor
    return dataclasses.replace(knowledge, nominal=knowledge.nominal.replace(
        Kd4=m.Kd4 * 1.5 + 1e-6, phi1=-m.phi1 if m.phi1 else 0.5))


def _policy_meta(source: PolicySource, knowledge: MotorKnowledge) -> dict[str, Any]:
    """Oracle flag and the env options of a policy, JSON-ready."""
    policy = source.make()
    options = policy_env_options(policy, knowledge)
    probe = _probe(knowledge)            # the estimate is named on the probe's models
    est = dict(source.make().env_options(probe)).get("estimate", "exact")
    if isinstance(est, FeedforwardModel):
        est = ("identified" if est == probe.identified else
               "nominal" if est == FeedforwardModel.from_motor(probe.nominal.motor) else
               "exact" if est == probe.exact else "model")
    options["estimate"] = est
    card = policy_card(policy)
    if card is not None:
        oracle = card.oracle
    else:
        oracle = est == "exact" and \
            options.get("base_controller", EnvOptions.base_controller) != "none"
    out = {"oracle": bool(oracle), "env_options": options}
    if card is not None:
        out["knowledge"] = card.knowledge()
        out["learned"] = card.learned
    return out


def _suites(source: PolicySource, protocol: Protocol | ProtocolV1
            ) -> tuple[tuple[str, ...], str]:
    """The protocol's suites this policy runs in, and why not in the others."""
    card = policy_card(source.make())
    if card is None:
        return protocol.suites, ""
    return tuple(s for s in protocol.suites if s in card.suites), card.not_in_suites


def run_leaderboard(protocol: Protocol | ProtocolV1, policies: Sequence[str] | None = None, *,
                    workers: int | None = None, progress: bool = True) -> dict[str, Any]:
    """Evaluate policies (registered names, module paths, model files) under ``protocol``.

    ``policies`` defaults to :func:`.registry.default_policy_names`; the
    reference policy (``none``) always runs (it is the reference of every
    ratio). Returns the leaderboard as a JSON-ready dict. Runs are independent
    and deterministic: the result does not depend on ``workers`` (default:
    every core this process may use). If torch is loaded (SB3 policies), it is
    set to one thread in this process too, so that a serial run computes
    exactly what a worker does. Under v1 a learned entry runs every training
    seed it has (:meth:`.registry.PolicySource.factories`) and entries are
    scored per split (:func:`.scoring.make_entry_v1`).
    """
    wall_start = time.perf_counter()
    v1 = isinstance(protocol, ProtocolV1)
    specs = list(dict.fromkeys([REFERENCE_POLICY, *(policies if policies is not None
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

    def progress_bar(total: int, desc: str, unit: str) -> Any:
        if not progress:
            return None
        from tqdm.auto import tqdm

        return tqdm(total=total, desc=desc, unit=unit)

    bar = progress_bar(len(pairs), "identify", "motor")
    init = (motors, {}, protocol, None)
    identified = pool_map(_identify_job, pairs, workers, initializer=_init_worker,
                          initargs=init, max_chunk=16, bar=bar)
    if bar is not None:
        bar.close()
    failures = {pair: m for pair, m in zip(pairs, identified) if isinstance(m, str)}
    identified = [FeedforwardModel.from_motor(motors[i].nominal.motor)
                  if (i, seed) in failures else m for (i, seed), m in zip(pairs, identified)]
    knowledge = {(i, seed): protocol_knowledge(motors[i], seed, model, protocol)
                 for (i, seed), model in zip(pairs, identified)}

    # Options and oracle flag per policy, for the record; the last motor is a drawn
    # one in the full protocol, where nominal, identified and exact all differ.
    meta = {spec: _policy_meta(src, knowledge[pairs[-1]]) for spec, src in sources.items()}
    suites = {spec: _suites(src, protocol) for spec, src in sources.items()}

    jobs = [LeaderboardJob(spec, suite, i, seed, j, ts)
            for spec in specs for ts in sources[spec].factories(pooled=v1)
            for suite in suites[spec][0]
            for i, m in enumerate(motors) for seed in protocol.eval_seeds
            for j in range(len(m.speeds(suite)[0]))]
    bar = progress_bar(len(jobs), "leaderboard", "run")
    # SB3 models are loaded in the parent and inherited by the forked workers.
    results = pool_map(_run_job, jobs, workers, initializer=_init_worker,
                       initargs=(motors, knowledge, protocol, sources), max_chunk=16, bar=bar)
    if bar is not None:
        bar.close()

    by_entry: dict[tuple[str, str], list[dict]] = {}
    for job, res in zip(jobs, results):
        by_entry.setdefault((job.spec, job.suite), []).append(res)
    entries = _v1_entries(protocol, motors, specs, sources, by_entry, meta) if v1 else []
    for suite in protocol.suites if not v1 else ():
        reference = reference_index(by_entry[(REFERENCE_POLICY, suite)])
        suite_entries = [make_entry(sources[spec].name, sources[spec].spec, suite,
                                    by_entry[(spec, suite)], reference, protocol, meta[spec])
                         for spec in specs if (spec, suite) in by_entry]
        suite_entries.sort(key=lambda e: (not math.isfinite(e["headline"]["iqm"]),
                                          e["headline"]["iqm"], e["name"]))
        for rank, e in enumerate(suite_entries, 1):
            e["rank"] = rank
        entries += suite_entries
    identification = [{"motor": motors[i].name, "seed": seed,
                       "model": dataclasses.asdict(m) if m is not None else None,
                       **({"failed": failures[(i, seed)], "fallback": "nominal"}
                          if (i, seed) in failures else {})}
                      for (i, seed), m in zip(pairs, identified)]
    not_run = [{"name": sources[spec].name, "suite": suite, "reason": suites[spec][1]}
               for spec in specs for suite in protocol.suites if suite not in suites[spec][0]]
    out = {"protocol": {**protocol.to_dict(), "motors": [m.to_dict() for m in motors]},
           "versions": package_versions(), "identification": identification,
           "entries": entries}
    if not_run:
        out["not_run"] = not_run
    run_s = sum(r["simulated_s"] for r in results)
    calib = _calibration_seconds(jobs, results)
    out["wall_seconds"] = time.perf_counter() - wall_start
    out["simulated_seconds"] = run_s + calib
    out["simulated_seconds_detail"] = {
        "episodes": run_s, "calibration_rig": calib,
        "note": "identification runs are not counted"}
    return out


def _calibration_seconds(jobs: Sequence[LeaderboardJob], results: Sequence[dict]) -> float:
    """Rig seconds, counted once per (entry, model, suite, motor): a policy reports
    its calibration on every run, but calibrates once per motor and suite."""
    seen: dict[tuple, float] = {}
    for job, r in zip(jobs, results):
        key = (job.spec, job.training_seed, job.suite, job.motor_index)
        seen[key] = max(seen.get(key, 0.0), r.get("calibration_s", 0.0))
    return float(sum(seen.values()))


def _v1_entries(protocol: ProtocolV1, motors: Sequence[ProtocolMotor], specs: Sequence[str],
                sources: dict[str, PolicySource], by_entry: dict[tuple[str, str], list[dict]],
                meta: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """Entries per (suite, split), ranked, with every pair's probability of improvement."""
    split_of = {m.name: m.split for m in motors}
    strata = {m.name: m.family for m in motors}
    entries = []
    for suite in protocol.suites:
        if (REFERENCE_POLICY, suite) not in by_entry:
            continue
        reference = reference_index(by_entry[(REFERENCE_POLICY, suite)])
        for split in protocol.splits:
            group = [make_entry_v1(sources[spec].name, sources[spec].spec, suite, split,
                                   [r for r in by_entry[(spec, suite)]
                                    if split_of[r["motor"]] == split],
                                   reference, protocol, strata,
                                   {**meta[spec], "learned": bool(meta[spec].get("learned"))})
                     for spec in specs if (spec, suite) in by_entry]
            group.sort(key=lambda e: (not math.isfinite(e["headline"]["iqm"]),
                                      e["headline"]["iqm"], e["name"]))
            for rank, e in enumerate(group, 1):
                e["rank"] = rank
            add_probability_of_improvement(group, protocol, strata)
            entries += group
    return entries
