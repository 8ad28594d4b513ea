"""``stepdamp recommend``: which exportable entry to flash on a motor, and what to expect.

:func:`exportable_entries` lists the default entries whose law
:func:`.firmware.entry_law` can write for the motor (no oracle, no learned or
stateful law); :func:`recommend` runs them with ``none`` on a quick
stepdamp-bench v4 board of that motor alone (its custom split: the protocol's
headline speeds and sensors, 4 evaluation seeds by default) in one suite.
One motor has no spread over motors, so the statistics are over its headline
runs (speed x seed): each run's attenuation against ``none``'s run of the same
speed and seed, as the board scores a run; per entry their IQM with a bootstrap
interval (:func:`.stats.motor_mean_bootstrap`, each run its own unit), and
paired by run against the best (:func:`.stats.paired_difference`). The pick is
the entry with the highest IQM; the entries it does not beat by the paired
interval are reported as tied with it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from ..params import ParameterError, SystemParams
from .firmware import entry_law, firmware_knowledge
from .leaderboard import run_leaderboard
from .policy import policy_card
from .protocols.v4 import quick_protocol_v4
from .registry import default_policy_names, resolve_policy
from .stats import motor_mean_bootstrap, paired_difference

__all__ = ["Recommendation", "exportable_entries", "recommend", "RECOMMEND_SUITES"]

#: The suites a recommendation runs, by the drive's mode.
RECOMMEND_SUITES = {"open-loop": "open-loop", "servo": "servo"}


@dataclass(frozen=True)
class Recommendation:
    """The exportable entries on one motor and the pick (see the module docstring).

    Attributes:
        motor: the motor's name; ``suite``: the suite they ran in;
            ``eval_seeds``: the board's evaluation seeds (runs per speed).
        scores: per entry, best first: ``{"name", "iqm", "ci", "runs", "lost"}``,
            the attenuation (dB) over the headline runs and the runs that lost steps.
        pick: the entry to flash (the first of ``scores``).
        tied: the entries the pick does not beat by the paired interval.
    """

    motor: str
    suite: str
    eval_seeds: int
    scores: tuple[Mapping[str, Any], ...]
    pick: Mapping[str, Any]
    tied: tuple[str, ...]


def exportable_entries(system: SystemParams, mode: str = "open-loop") -> list[str]:
    """The default entries whose law can be exported for ``system`` in ``mode``
    (not oracles: a drive does not know the true plant)."""
    knowledge = firmware_knowledge(system)
    out = []
    for name in default_policy_names():
        card = policy_card(resolve_policy(name).make())
        if name == "none" or (card is not None and (card.oracle or card.learned)):
            continue
        try:
            entry_law(name, knowledge, mode=mode)
        except ParameterError:
            continue
        out.append(name)
    return out


def recommend(system: SystemParams, mode: str = "open-loop", *, eval_seeds: int = 4,
              workers: int | None = None, progress: bool = False) -> Recommendation:
    """Run and rank the exportable entries on ``system`` in the suite of ``mode``."""
    if mode not in RECOMMEND_SUITES:
        raise ParameterError(f"--mode {mode!r} is not one of {list(RECOMMEND_SUITES)}")
    entries = exportable_entries(system, mode)
    if not entries:
        raise ParameterError(f"no entry can be exported for {system.name!r} in {mode}")
    suite = RECOMMEND_SUITES[mode]
    protocol = (quick_protocol_v4().with_custom_motors((system,)).with_suites((suite,))
                .with_eval_seeds(eval_seeds))
    board = run_leaderboard(protocol, ["none", *entries], workers=workers, progress=progress)
    rows = {e["name"]: e for e in board["entries"] if e["suite"] == suite
            and e.get("split") == "custom" and not e.get("reference")}
    none_runs = rows["none"]["runs"]
    per_run = {name: protocol.headline_run_db(rows[name]["runs"], none_runs)
               for name in entries if name in rows and not (rows[name].get("oracle")
                                                            or rows[name].get("privileged"))}
    scores = []
    for name, db in per_run.items():
        if not db:
            continue
        keys = sorted(db, key=str)
        stat = motor_mean_bootstrap([db[k] for k in keys], keys)
        lost = sum(1 for r in rows[name]["runs"] if r["failed"]
                   and not r["speed_label"].startswith("off"))
        scores.append({"name": name, "iqm": stat["iqm"], "ci": stat["ci"], "runs": len(keys),
                       "lost": lost})
    if not scores:
        raise ParameterError(f"no exportable entry could be scored on {system.name!r}")
    scores.sort(key=lambda s: (-s["iqm"], s["name"]))
    pick = scores[0]
    tied = tuple(s["name"] for s in scores[1:]
                 if not paired_difference(per_run[pick["name"]], per_run[s["name"]])["low"] > 0.0)
    return Recommendation(system.name, suite, eval_seeds, tuple(scores), pick, tied)
