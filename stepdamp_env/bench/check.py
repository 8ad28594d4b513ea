"""``stepdamp report DIR --check``: does a results directory reproduce here?

The board's protocol is rebuilt from what ``leaderboard.json`` records (the
built-in protocols, their quick variants, a suite subset, custom motors, one
split, a count of evaluation seeds); its
motors must come out the same; then a sample of its cells (runs, spread evenly
over every entry, suite and split) is run again, with each sampled motor and
seed identified again, and each record compared bit for bit with the board's.
The board's own fingerprint is checked against its files too (an edited file
is told apart from a run that does not reproduce).
"""

from __future__ import annotations

import dataclasses
import json
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..motorfile import system_from_mapping
from ..params import FeedforwardModel, ParameterError
from .leaderboard import LeaderboardJob, identify_motor, run_cells
from .motors import ProtocolMotor, protocol_motors
from .protocols import protocol_for
from .provenance import board_fingerprint

__all__ = ["protocol_of_board", "job_of_run", "check_board"]


def _same(a: Any, b: Any) -> bool:
    return json.dumps(a, sort_keys=True, allow_nan=True) == \
        json.dumps(b, sort_keys=True, allow_nan=True)


def protocol_of_board(board: Mapping[str, Any]) -> Any:
    """The protocol a board was run under, rebuilt from its record; a one-line
    ``ParameterError`` if no built-in protocol gives that record."""
    recorded = {k: v for k, v in board["protocol"].items() if k != "motors"}
    version = recorded.get("version")
    for quick in (False, True):
        try:
            protocol = protocol_for(str(version), quick)
        except ParameterError:
            break
        if tuple(recorded.get("suites", ())) != tuple(protocol.suites):
            protocol = protocol.with_suites(tuple(recorded.get("suites", ())))
        splits = tuple(recorded.get("splits", ()))
        if splits == ("custom",):
            protocol = protocol.with_custom_motors(
                [system_from_mapping(m["parameters"]) for m in board["protocol"]["motors"]])
        elif len(splits) == 1 and splits != tuple(protocol.to_dict().get("splits", ())):
            protocol = _or_same(protocol, lambda p: p.with_splits(splits))     # --split
        seeds = recorded.get("eval_seeds")
        if isinstance(seeds, list) and seeds != list(protocol.to_dict().get("eval_seeds", seeds)):
            protocol = _or_same(protocol, lambda p: p.with_eval_seeds(len(seeds)))  # --eval-seeds
        if _same(protocol.to_dict(), recorded):
            return protocol
    raise ParameterError(f"the board's protocol (version {version!r}) is none of the built-in "
                         "protocols or their quick variants; it cannot be re-run from the "
                         "command line")


def _or_same(protocol: Any, change: Callable[[Any], Any]) -> Any:
    """``change(protocol)`` (a CLI option the board was run with), or the
    protocol as it is where the option does not apply to it."""
    try:
        return change(protocol)
    except ParameterError:
        return protocol


def _sample(board: Mapping[str, Any], size: int) -> list[tuple[Mapping, Mapping]]:
    """``size`` (entry, run) pairs spread evenly over the board's runs in order."""
    runs = [(e, r) for e in board["entries"] for r in e["runs"]]
    if not runs:
        return []
    picks = np.unique(np.linspace(0, len(runs) - 1, min(size, len(runs))).round().astype(int))
    return [runs[k] for k in picks]


def job_of_run(motors: Sequence[ProtocolMotor], entry: Mapping[str, Any],
               run: Mapping[str, Any]) -> LeaderboardJob:
    """The leaderboard job that computed ``run`` of ``entry``; a one-line
    ``ParameterError`` if the protocol's motors have no such run."""
    names = [m.name for m in motors]
    if run["motor"] not in names:
        raise ParameterError(f"the board has a run on {run['motor']!r}, a motor its protocol "
                             "does not have")
    i = names.index(run["motor"])
    # Labels repeat on a grid (every off-resonance speed is "off"): the speed decides.
    grid = list(zip(*motors[i].speeds(entry["suite"])))
    if (run["speed_rps"], run["speed_label"]) not in grid:
        raise ParameterError(f"the board's run at {run['speed_rps']!r} rev/s "
                             f"({run['speed_label']}) on {run['motor']!r} is not on the "
                             f"protocol's {entry['suite']} grid")
    # A derived row's run (v5's envelope) is a copy of the run it names.
    chosen = run.get("chosen") or {"spec": entry["spec"],
                                   "training_seed": run.get("training_seed")}
    return LeaderboardJob(chosen["spec"], entry["suite"], i, run["seed"],
                          grid.index((run["speed_rps"], run["speed_label"])),
                          chosen["training_seed"])


def check_board(board: Mapping[str, Any], sample: int = 12) -> list[dict[str, Any]]:
    """Per checked item (the file fingerprint, the motors, each sampled cell and
    its identification) a dict: ``what``, ``reproduces`` (bool) and ``detail``."""
    out: list[dict[str, Any]] = []
    recorded = board.get("fingerprint")
    now = board_fingerprint(board)
    out.append({"what": "board fingerprint (the files)",
                "reproduces": recorded is None or recorded == now,
                "detail": "not recorded (a board of an earlier version)" if recorded is None
                else ("" if recorded == now else f"recorded {recorded[:16]}, files {now[:16]}")})
    protocol = protocol_of_board(board)
    motors = protocol_motors(protocol)
    same_motors = _same([m.to_dict() for m in motors], board["protocol"]["motors"])
    out.append({"what": f"motors ({len(motors)})", "reproduces": same_motors,
                "detail": "" if same_motors else "the protocol's motors differ from the board's"})
    if not same_motors:
        return out
    index = {m.name: i for i, m in enumerate(motors)}
    unknown = sorted({r["motor"] for e in board["entries"] for r in e["runs"]} - set(index))
    if unknown:
        raise ParameterError(f"the board has runs on motors its protocol does not have: {unknown}")
    recorded_models = {(x["motor"], x["seed"]): x.get("model") for x in board["identification"]}
    recorded_failures = {(x["motor"], x["seed"]): x.get("failed")
                         for x in board["identification"]}
    out += protocol.check_derived(board["entries"])
    picked = _sample(board, sample)
    identified: dict[tuple[int, int], FeedforwardModel | None] = {}
    for e, r in picked:
        key = (r["motor"], r["seed"])
        pair = (index[r["motor"]], r["seed"])
        if pair in identified:
            continue
        model = identify_motor(protocol, motors[pair[0]], r["seed"], cached=False)
        failed = model if isinstance(model, str) else None
        if failed is not None:                  # v1: the drive keeps its nominal model
            model = FeedforwardModel.from_motor(motors[pair[0]].nominal.motor)
        identified[pair] = model
        ok = _same(dataclasses.asdict(model), recorded_models.get(key)) and \
            _same(failed, recorded_failures.get(key))
        out.append({"what": f"identification {r['motor']} seed {r['seed']}", "reproduces": ok,
                    "detail": "" if ok else "the identified model differs"})
    jobs = [job_of_run(motors, e, r) for e, r in picked]
    for (e, r), got in zip(picked, run_cells(protocol, jobs, identified)):
        if "chosen" in r:               # a copy: the run it names, as the copy records it
            got = {**got, "training_seed": r["training_seed"], "chosen": r["chosen"]}
        ok = _same(got, r)
        where = (f"{e['name']} | {e['suite']}{' | ' + e['split'] if 'split' in e else ''} | "
                 f"{r['motor']} seed {r['seed']} {r['speed_label']} {r['speed_rps']:.4g} rev/s"
                 + (f" model {r['training_seed']}" if "training_seed" in r else ""))
        detail = ""
        if not ok:
            a = (r.get("metrics") or {}).get("rms_velocity_error_rad_s")
            b = (got.get("metrics") or {}).get("rms_velocity_error_rad_s")
            differ = sorted(k for k in {*r, *got} if not _same(r.get(k), got.get(k)))
            inner = sorted(k for k in {*(r.get("metrics") or {}), *(got.get("metrics") or {})}
                           if not _same((r.get("metrics") or {}).get(k),
                                        (got.get("metrics") or {}).get(k)))
            detail = (f"RMS ripple recorded {a!r}, now {b!r}; differs in "
                      f"{', '.join(differ)}" + (f" ({', '.join(inner)})" if inner else ""))
        out.append({"what": where, "reproduces": ok, "detail": detail})
    return out
