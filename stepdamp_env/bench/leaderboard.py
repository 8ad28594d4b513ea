"""The leaderboard: every policy under a protocol, in a process pool, scored and ranked.

:func:`run_leaderboard` identifies each (motor, seed) once (cached on disk per
motor, seed and package version), runs every policy (:mod:`.registry`) on every
motor, seed, suite and speed of the protocol (:mod:`.protocol`, :mod:`.motors`)
with the batched episode runner (:func:`.runner.run_episodes`: the runs of one
entry, model and suite go in batches of up to ``BATCH_RUNS``), scores the runs
against the reference policy (:mod:`.scoring`, :mod:`.stats`) and returns the
board as a JSON-ready dict; :func:`.report.write_outputs` writes it. With a
``resume_dir`` every finished batch is kept there, so an interrupted run started
again with the same arguments picks up where it stopped.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

from ..env.options import EnvOptions
from ..lanes import LANES
from ..identify import identify
from ..io import write_checked_json
from ..parallel import default_workers, pool_map
from ..params import FeedforwardModel, ParameterError, SystemParams
from ..presets import get_preset
from .firmware_board import firmware_field
from .kept import KeptResults
from .motors import ProtocolMotor, protocol_motors
from .policy import MotorKnowledge, policy_card, policy_env_options
from .protocol import REFERENCE_POLICY, REFERENCE_ROW, SUITE_MODE, Protocol
from .provenance import board_fingerprint, code_fingerprint, environment, package_versions
from .registry import PolicySource, default_policy_names, registered_policies, resolve_policy
from .resume import (RESUME_DIR, clear_resume_dir, finish_resume_dir, open_resume_dir,
                     resume_paths, resumed_batch)
from .rig import CalibrationRig
from .runner import (RUN_ERRORS, EpisodeResult, EpisodeSpec, could_not_run, run_episode,
                     run_episodes)
from .warmup import warm_lanes, warm_up

__all__ = ["LeaderboardJob", "LeaderboardBatch", "run_leaderboard", "run_cells",
           "package_versions", "protocol_knowledge", "identify_cached", "identify_motor",
           "code_fingerprint", "BATCH_RUNS", "RESUME_DIR", "open_resume_dir", "clear_resume_dir",
           "finish_resume_dir", "warm_up"]

# Runs of one entry, model and suite stepped together (and kept together on resume).
#: Runs per batch. 1024 against 64: the full v4 board in 262 s instead of 326 s
#: (2 workers, docs/performance.md): fewer Python steps per simulated second and
#: more rows in SIMD lanes; a run's numbers do not depend on its batch.
BATCH_RUNS = 1024


@dataclass(frozen=True)
class LeaderboardJob:
    """One run of the leaderboard (indices into the protocol's motors and grids)."""

    spec: str
    suite: str
    motor_index: int
    seed: int
    speed_index: int
    training_seed: int | None = None      # v1: which of a learned entry's models


@dataclass(frozen=True)
class LeaderboardBatch:
    """Runs of one entry, model and suite that the batched runner steps together."""

    spec: str
    suite: str
    training_seed: int | None
    runs: tuple[tuple[int, int, int], ...]     # (motor_index, seed, speed_index)

    def jobs(self) -> list[LeaderboardJob]:
        return [LeaderboardJob(self.spec, self.suite, i, seed, j, self.training_seed)
                for i, seed, j in self.runs]


# What a worker process needs; set once per process by _init_worker.
_WORKER: dict[str, Any] = {}


def _init_worker(motors: tuple[ProtocolMotor, ...], knowledge: dict, protocol: Protocol,
                 sources: dict[str, PolicySource] | None, runner: str = "batched") -> None:
    _WORKER["runner"] = runner
    _WORKER.pop("code", None)
    _WORKER["motors"] = motors
    _WORKER["knowledge"] = knowledge
    _WORKER["protocol"] = protocol
    _WORKER["sources"] = dict(sources or {})
    _WORKER["suite_motors"] = {}
    if "torch" in sys.modules:     # one thread per process: both cores, no oversubscription
        sys.modules["torch"].set_num_threads(1)


def _source(spec: str) -> PolicySource:
    sources = _WORKER.setdefault("sources", {})
    if spec not in sources:
        sources[spec] = resolve_policy(spec)
    return sources[spec]


def _make(spec: str, training_seed: int | None) -> Any:
    source = _source(REFERENCE_POLICY if spec == REFERENCE_ROW else spec)
    return source.make() if training_seed is None else source.training_seeds[training_seed]()


def identify_cached(system: SystemParams, method: str, seed: int,
                    code: str | None = None) -> FeedforwardModel | str:
    """``identify(system, method=method, noise_seed=seed).model``, or the failure
    as a string ("ErrorType: message"), kept on disk (:class:`.kept.KeptResults`
    "identify") per system, method, seed and code (the package's sources and
    dependency versions; ``code``: their fingerprint if read already):
    identification is deterministic, so a kept model is the one it would compute."""
    kept = KeptResults("identify", code=code)
    key = {"system": system.to_dict(), "method": method, "seed": seed}
    content = kept.get(key)
    try:
        if isinstance(content, dict) and content.get("failed") is not None:
            return str(content["failed"])
        if isinstance(content, dict) and isinstance(content.get("model"), dict):
            return FeedforwardModel(**content["model"])
    except (TypeError, ValueError, ParameterError):     # unreadable: computed again
        pass
    try:
        model: FeedforwardModel | str = identify(system, method=method, noise_seed=seed).model
        entry = {"model": dataclasses.asdict(model), "failed": None}
    except (RuntimeError, ParameterError) as exc:
        model = f"{type(exc).__name__}: {exc}"
        entry = {"model": None, "failed": model}
    kept.put(key, entry)
    return model


def identify_motor(protocol: Protocol, motor: ProtocolMotor, seed: int,
                   cached: bool = True, code: str | None = None) -> FeedforwardModel | str:
    """The model a protocol's drive identifies on ``motor`` with noise ``seed``, or
    the failure as a string. ``cached``: read and keep it in the identification
    cache (:func:`identify_cached`, ``code`` as there); False computes it here and now."""
    system = motor.system
    if system.drive.drive_mode != "current":    # a drive commissions with its current loop
        system = system.replace(drive_mode="current")
    if cached:
        return identify_cached(system, protocol.identification_method, seed, code)
    try:
        return identify(system, method=protocol.identification_method, noise_seed=seed).model
    except (RuntimeError, ParameterError) as exc:
        return f"{type(exc).__name__}: {exc}"


def _identify_job(args: tuple[int, int]) -> FeedforwardModel | str:
    """The identified model, or the reason as a string if identification failed
    and the protocol then leaves the drive its nominal model (else an error)."""
    motor_index, seed = args
    protocol = _WORKER["protocol"]
    if "code" not in _WORKER:       # read once per worker and board, not per motor
        _WORKER["code"] = code_fingerprint()
    model = identify_motor(protocol, _WORKER["motors"][motor_index], seed, code=_WORKER["code"])
    if isinstance(model, str) and not protocol.nominal_on_failed_identification:
        raise ParameterError(f"identification of motor "
                             f"{_WORKER['motors'][motor_index].name!r} (seed {seed}) failed: "
                             f"{model}")
    return model


def _run_batch(batch: LeaderboardBatch) -> list[dict[str, Any]]:
    """The records of a batch's runs."""
    protocol: Protocol = _WORKER["protocol"]
    motors: Sequence[ProtocolMotor] = _WORKER["motors"]
    specs = []
    mode = SUITE_MODE[batch.suite]
    # A motor and its knowledge as the suite (or its reference row) runs them, made
    # once per worker and board: every speed and entry shares them.
    kept = _WORKER["suite_motors"]
    reference = batch.spec == REFERENCE_ROW
    for i, seed, j in batch.runs:
        key = (i, seed, batch.suite, reference)
        if key not in kept:
            motor = motors[i].for_suite(batch.suite)
            knowledge = _WORKER["knowledge"][(i, seed)]
            if reference:               # policy none on the motor without the phenomenon
                motor = protocol.reference_motor(motors[i], batch.suite)
            if motor is not motors[i]:  # the suite's drive mode (v2's mid-band)
                knowledge = protocol_knowledge(motor, seed, knowledge.identified, protocol)
            kept[key] = (motor, knowledge)
        motor, knowledge = kept[key]
        specs.append(EpisodeSpec(knowledge, motor.system, motor.speeds(batch.suite).speeds_rps[j],
                                 seed, motor.settle_s(batch.suite),
                                 **protocol.run_command(motors[i], batch.suite, j)))
    def alone(e: EpisodeSpec) -> EpisodeResult:
        try:
            return run_episode(_make(batch.spec, batch.training_seed), e.knowledge, e.system,
                               mode=mode, speed_rps=e.speed_rps, seed=e.seed,
                               accel_rps2=protocol.accel_rps2 if e.accel_rps2 is None
                               else e.accel_rps2, window_s=protocol.window_s,
                               settle_s=e.settle_s, lag_limit_steps=protocol.lag_limit(),
                               suite=batch.suite, profile=e.profile,
                               distance_rev=e.distance_rev, ramp=e.ramp)
        except RUN_ERRORS as exc:
            return could_not_run(exc)

    if _WORKER.get("runner") == "scalar":     # the reference of the batched runner
        results = [alone(e) for e in specs]
    else:
        try:
            results = run_episodes(lambda: _make(batch.spec, batch.training_seed), specs,
                                   mode=mode, accel_rps2=protocol.accel_rps2,
                                   window_s=protocol.window_s,
                                   lag_limit_steps=protocol.lag_limit(), suite=batch.suite)
        except RUN_ERRORS:
            # An entry that cannot run on one motor stops its batch: each run alone
            # then says which could not (the others give the batch's numbers).
            results = [alone(e) for e in specs]
    records = []
    keep = protocol.run_metrics
    for (i, seed, j), spec, result in zip(batch.runs, specs, results):
        motor = motors[i]
        record = result.record(motor.name, seed, spec.speed_rps,
                               motor.speeds(batch.suite).labels[j], batch.training_seed)
        if keep is not None and record["metrics"] is not None:
            record["metrics"] = {k: record["metrics"][k] for k in keep}
        records.append(record)
    return records


def protocol_knowledge(motor: ProtocolMotor, seed: int, identified: FeedforwardModel | None,
                       protocol: Protocol) -> MotorKnowledge:
    """What the drive of a protocol run knows (the oracle-only fields included:
    entries that read them are flagged by their card)."""
    return MotorKnowledge(nominal=motor.nominal, identified=identified,
                          exact=FeedforwardModel.from_motor(motor.system.motor),
                          plant=motor.system,
                          rig=CalibrationRig(motor.system, seed, protocol.accel_rps2))


def _probe(knowledge: MotorKnowledge) -> MotorKnowledge:
    """Knowledge whose nominal model differs from the exact one, so that an entry's
    estimate can be told apart (on a preset or a custom motor they are equal)."""
    if FeedforwardModel.from_motor(knowledge.nominal.motor) != knowledge.exact:
        return knowledge
    m = knowledge.nominal.motor
    return dataclasses.replace(knowledge, nominal=knowledge.nominal.replace(
        Kd4=m.Kd4 * 1.5 + 1e-6, phi1=-m.phi1 if m.phi1 else 0.5))


def _policy_meta(source: PolicySource, knowledge: MotorKnowledge, protocol: Protocol
                 ) -> dict[str, Any]:
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
        if protocol.records_training_coverage:
            out["trained_on"] = [list(t) for t in card.trained_on]
    return out


def _suites(source: PolicySource, protocol: Protocol
            ) -> tuple[tuple[str, ...], str]:
    """The protocol's suites this policy runs in, and why not in the others."""
    card = policy_card(source.make())
    if card is None or card.suites is None:
        return protocol.suites, ""
    return tuple(s for s in protocol.suites if s in card.suites), card.not_in_suites


def run_leaderboard(protocol: Protocol, policies: Sequence[str] | None = None, *,
                    workers: int | None = None, progress: bool = True,
                    resume_dir: str | None = None,
                    backend: Callable[..., list[Any]] | None = None,
                    runner: str = "batched", fingerprint: bool = True) -> dict[str, Any]:
    """Evaluate policies (registered names, module paths, model files) under ``protocol``.

    ``policies`` defaults to :func:`.registry.default_policy_names`; the
    reference policy (``none``) always runs (it is the reference of every
    ratio). Returns the leaderboard as a JSON-ready dict. Runs are independent
    and deterministic: the result does not depend on ``workers`` (default:
    every core this process may use). If torch is loaded (SB3 policies), it is
    set to one thread in this process too, so that a serial run computes
    exactly what a worker does. Where the protocol pools training seeds
    (``Protocol.pools_training_seeds``) a learned entry runs every training
    seed it has (:meth:`.registry.PolicySource.factories`); the protocol turns
    the runs into ranked entries (:meth:`.protocol.Protocol.entries`).

    ``resume_dir``: where finished batches are kept (see the module docstring);
    a batch found there is not run again. ``backend``: runs the batches in
    place of the local process pool, called as ``pool_map`` is (the Ray
    backend, :mod:`stepdamp_env.ray_backend`). ``runner``: "batched"
    (:func:`.runner.run_episodes`) or "scalar" (each run alone through
    :func:`.runner.run_episode`: the same numbers, slower; the reference of
    ``benchmarks/bench_scale.py`` and of the tests). ``fingerprint`` False:
    the board without its ``"fingerprint"``, which :func:`.report.write_outputs`
    then computes while the runs file compresses (the CLI's way).
    """
    if runner not in ("batched", "scalar"):
        raise ParameterError(f"runner={runner!r} is not one of ['batched', 'scalar']")
    wall_start = time.perf_counter()
    sources = _sources([REFERENCE_POLICY, *(policies if policies is not None
                                            else protocol.default_entries(
                                                default_policy_names()))])
    workers = default_workers() if workers is None else max(1, int(workers))
    run_map = pool_map if backend is None else backend
    # First: drawing a protocol's motors may simulate (v3's grids), so that the
    # kernels compile here in parallel, not serially inside the draw.
    warm_up(get_preset("patent"), workers if backend is None else 1, progress)
    motors = protocol_motors(protocol)
    identified, failures = _identify_all(protocol, motors, run_map, workers, progress)
    knowledge = {pair: protocol_knowledge(motors[pair[0]], pair[1], model, protocol)
                 for pair, model in identified.items()}
    # Options and oracle flag per policy, for the record; the last motor is a drawn
    # one in the full protocol, where nominal, identified and exact all differ.
    last = list(knowledge)[-1]
    meta = {spec: _policy_meta(src, knowledge[last], protocol) for spec, src in sources.items()}
    suites = {spec: _suites(src, protocol) for spec, src in sources.items()}
    batches = _batches(protocol, motors, sources, suites)
    records = _run_batches(protocol, motors, knowledge, sources, batches, run_map, workers,
                           progress, resume_dir, runner,
                           warm=backend is None and runner == "batched")
    # Scoring forks this process: never a Ray driver's (its threads), at most our cores.
    board = _board(protocol, motors, sources, suites, meta, batches, records, identified,
                   failures, 1 if backend is not None else min(workers, default_workers()))
    board["wall_seconds"] = time.perf_counter() - wall_start
    _move_last(board, ("simulated_seconds", "simulated_seconds_detail"))
    board["environment"] = environment()
    board["firmware"] = firmware_field(sources)
    if fingerprint:
        board["fingerprint"] = board_fingerprint(board)
    return board


def canonical_order(specs: Sequence[str]) -> list[str]:
    """The specs once each, registered policies in registry order, then the others
    sorted: a pair's probability and effect are computed one way round (the other
    side is their complement), so the board must not depend on the order given."""
    registry = {name: k for k, name in enumerate(registered_policies())}
    unique = list(dict.fromkeys(specs))
    return sorted((s for s in unique if s in registry), key=registry.__getitem__) + \
        sorted(s for s in unique if s not in registry)


def _sources(specs: Sequence[str]) -> dict[str, PolicySource]:
    """Each policy spec (once, in :func:`canonical_order`) resolved; names must be unique."""
    sources = {spec: resolve_policy(spec) for spec in canonical_order(specs)}
    names = [s.name for s in sources.values()]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ParameterError(f"two policies share the name(s) {dupes}; names must be unique")
    return sources


def _progress_bar(progress: bool, total: int, desc: str, unit: str) -> Any:
    if not progress:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit=unit)


def _identify_all(protocol: Protocol, motors: Sequence[ProtocolMotor],
                  run_map: Callable[..., list[Any]], workers: int, progress: bool
                  ) -> tuple[dict[tuple[int, int], FeedforwardModel], dict[tuple[int, int], str]]:
    """The drive's model per (motor index, evaluation seed), and the failures (whose
    drives keep their nominal model)."""
    pairs = [(i, seed) for i in range(len(motors)) for seed in protocol.eval_seeds]
    bar = _progress_bar(progress, len(pairs), "identify", "motor")
    models = run_map(_identify_job, pairs, workers, initializer=_init_worker,
                     initargs=(motors, {}, protocol, None), max_chunk=16, bar=bar)
    if bar is not None:
        bar.close()
    failures = {pair: m for pair, m in zip(pairs, models) if isinstance(m, str)}
    identified = {(i, seed): FeedforwardModel.from_motor(motors[i].nominal.motor)
                  if (i, seed) in failures else m for (i, seed), m in zip(pairs, models)}
    return identified, failures


def _batches(protocol: Protocol, motors: Sequence[ProtocolMotor],
             sources: dict[str, PolicySource],
             suites: dict[str, tuple[tuple[str, ...], str]]) -> list[LeaderboardBatch]:
    """Every run, in batches of up to ``BATCH_RUNS`` of one entry, model and suite."""
    batches = []
    for suite in protocol.suites:           # the reference rows (v3), before the entries
        if protocol.reference_motor(motors[0], suite) is None:
            continue
        runs = [(i, seed, j) for i, m in enumerate(motors) for seed in protocol.eval_seeds
                for j in range(len(m.speeds(suite).speeds_rps))]
        batches += [LeaderboardBatch(REFERENCE_ROW, suite, None, tuple(runs[k:k + BATCH_RUNS]))
                    for k in range(0, len(runs), BATCH_RUNS)]
    for spec, source in sources.items():
        for ts in source.factories(pooled=protocol.pools_training_seeds):
            for suite in suites[spec][0]:
                runs = [(i, seed, j) for i, m in enumerate(motors) for seed in protocol.eval_seeds
                        for j in range(len(m.speeds(suite).speeds_rps))]
                batches += [LeaderboardBatch(spec, suite, ts, tuple(runs[k:k + BATCH_RUNS]))
                            for k in range(0, len(runs), BATCH_RUNS)]
    return batches


def _run_batches(protocol: Protocol, motors: Sequence[ProtocolMotor],
                 knowledge: dict[tuple[int, int], MotorKnowledge],
                 sources: dict[str, PolicySource], batches: Sequence[LeaderboardBatch],
                 run_map: Callable[..., list[Any]], workers: int, progress: bool,
                 resume_dir: str | None, runner: str, warm: bool = False
                 ) -> list[list[dict[str, Any]]]:
    """Each batch's run records: read from ``resume_dir`` if an interrupted run of
    this very board finished it, else run (and kept there as it finishes).
    ``warm``: compile the SIMD lanes here first if a batch to run may step in them."""
    paths: list[str | None] = [None] * len(batches)
    if resume_dir is not None:
        from ..version import __version__

        header = {"version": __version__, "protocol": protocol.to_dict(),
                  "motors": [m.to_dict() for m in motors],
                  "code": code_fingerprint(),
                  "policies": {spec: src.fingerprint(
                      exclude=(os.path.dirname(os.path.abspath(resume_dir)),))
                      for spec, src in sources.items()}}
        paths = list(resume_paths(resume_dir, batches, header))
    done: list[Any] = [resumed_batch(p, b, motors) if p is not None else None
                       for p, b in zip(paths, batches)]
    # The largest batches first: the last ones to finish are small (less idle time
    # at the end); the order of running changes no number.
    todo = sorted((k for k, d in enumerate(done) if d is None),
                  key=lambda k: -len(batches[k].runs))
    if len(todo) < len(batches):
        print(f"resuming: {len(batches) - len(todo)} of {len(batches)} batches read from "
              f"{resume_dir}", file=sys.stderr)
    if warm and any(len(batches[k].runs) >= LANES for k in todo):
        # The batches' SIMD lanes, compiled once here rather than in every worker.
        warm_lanes(workers, progress)

    def keep(j: int, records: list[dict[str, Any]]) -> None:
        path = paths[todo[j]]
        if path is not None:
            write_checked_json(path, os.path.basename(path)[:-len(".json")], records)

    bar = _progress_bar(progress, len(todo), "leaderboard", "batch")
    # SB3 models are loaded in the parent and inherited by the forked workers.
    ran = run_map(_run_batch, [batches[k] for k in todo], workers, initializer=_init_worker,
                  initargs=(motors, knowledge, protocol, sources, runner), max_chunk=1,
                  bar=bar, on_result=keep)
    if bar is not None:
        bar.close()
    for k, records in zip(todo, ran):
        done[k] = records
    return done


def _board(protocol: Protocol, motors: Sequence[ProtocolMotor],
           sources: dict[str, PolicySource], suites: dict[str, tuple[tuple[str, ...], str]],
           meta: dict[str, dict[str, Any]], batches: Sequence[LeaderboardBatch],
           records: Sequence[list[dict[str, Any]]],
           identified: dict[tuple[int, int], FeedforwardModel],
           failures: dict[tuple[int, int], str], workers: int = 1) -> dict[str, Any]:
    """The board (JSON-ready) from every batch's records, scored on ``workers``
    processes (:meth:`.protocol.Protocol.entries`)."""
    jobs = [job for b in batches for job in b.jobs()]
    results = [r for batch_records in records for r in batch_records]
    by_entry: dict[tuple[str, str], list[dict]] = {}
    for job, res in zip(jobs, results):
        by_entry.setdefault((job.spec, job.suite), []).append(res)
    names = {spec: (src.name, src.spec) for spec, src in sources.items()}
    entries = protocol.entries(names, by_entry, motors, meta, workers=workers)
    identification = [{"motor": motors[i].name, "seed": seed,
                       "model": dataclasses.asdict(m) if m is not None else None,
                       **({"failed": failures[(i, seed)], "fallback": "nominal"}
                          if (i, seed) in failures else {})}
                      for (i, seed), m in identified.items()]
    not_run = [{"name": sources[spec].name, "suite": suite, "reason": suites[spec][1]}
               for spec in sources for suite in protocol.suites if suite not in suites[spec][0]]
    out = {"protocol": {**protocol.to_dict(), "motors": [m.to_dict() for m in motors]},
           "versions": package_versions(), "identification": identification,
           "entries": entries}
    if not_run:
        out["not_run"] = not_run
    tables = protocol.tables(entries)
    if tables:
        out["tables"] = tables
    run_s = sum(r["simulated_s"] for r in results)
    calib = _calibration_seconds(jobs, results)
    out["simulated_seconds"] = run_s + calib
    out["simulated_seconds_detail"] = {
        "episodes": run_s, "calibration_rig": calib,
        "note": "identification runs are not counted"}
    return out


def _move_last(board: dict[str, Any], keys: Sequence[str]) -> None:
    """Move ``keys`` to the end of ``board`` (the key order the board files had)."""
    for key in keys:
        board[key] = board.pop(key)


def run_cells(protocol: Protocol, jobs: Sequence[LeaderboardJob],
              identified: dict[tuple[int, int], FeedforwardModel | None]) -> list[dict[str, Any]]:
    """The records of single leaderboard runs, in this process, exactly as
    :func:`run_leaderboard` computes them (a run does not depend on the batch it
    is stepped in). ``identified``: the drive's model per (motor index, seed)
    of the jobs; ``stepdamp report --check`` re-runs a board's cells with it."""
    motors = protocol_motors(protocol)
    specs = sorted({REFERENCE_POLICY if job.spec == REFERENCE_ROW else job.spec for job in jobs})
    sources = {spec: resolve_policy(spec) for spec in specs}
    knowledge = {pair: protocol_knowledge(motors[pair[0]], pair[1], model, protocol)
                 for pair, model in identified.items()}
    _init_worker(motors, knowledge, protocol, sources)
    return [_run_batch(LeaderboardBatch(job.spec, job.suite, job.training_seed,
                                        ((job.motor_index, job.seed, job.speed_index),)))[0]
            for job in jobs]


def _calibration_seconds(jobs: Sequence[LeaderboardJob], results: Sequence[dict]) -> float:
    """Rig seconds, counted once per (entry, model, suite, motor): a policy reports
    its calibration on every run, but calibrates once per motor and suite."""
    seen: dict[tuple, float] = {}
    for job, r in zip(jobs, results):
        key = (job.spec, job.training_seed, job.suite, job.motor_index)
        seen[key] = max(seen.get(key, 0.0), r.get("calibration_s", 0.0))
    return float(sum(seen.values()))
