"""``stepdamp recommend``: which exportable entry to flash on a motor, and what to expect.

:func:`exportable_entries` lists the default entries whose law
:func:`.firmware.entry_law` can write for the motor (no oracle, no learned
agent, no law that changes while it runs); :func:`recommend` runs them with
``none`` on a quick stepdamp-bench v4 board of that motor alone (its custom
split: the protocol's headline speeds and sensors, 4 evaluation seeds by
default) in one suite, and scores each headline run (speed x seed) against
``none``'s run of the same speed and seed by v4's rules
(``ProtocolV4.headline_run_db``; a lost run -20 dB). Per entry: the mean over
those runs (the board's cell of a motor) with a bootstrap interval that
resamples the seeds within each speed, and the count of lost runs. The pick is
the entry with the highest mean among those that lost no headline run (all of
them, if every one lost some); the entries the pick does not beat by the paired
interval (:func:`.stats.paired_difference` over the runs) are named with it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from .. import fixedmath as fm
from ..params import ParameterError, SystemParams
from .firmware import entry_law, firmware_knowledge
from .leaderboard import run_leaderboard
from .policy import policy_card
from .protocols.v4 import quick_protocol_v4
from .registry import default_policy_names, resolve_policy
from .stats import paired_difference

__all__ = ["Recommendation", "exportable_entries", "recommend", "RECOMMEND_SUITES"]

#: The suites a recommendation runs, by the drive's mode.
RECOMMEND_SUITES = {"open-loop": "open-loop", "servo": "servo"}


@dataclass(frozen=True)
class Recommendation:
    """The exportable entries on one motor and the pick (see the module docstring).

    Attributes:
        motor: the motor's name; ``suite``: the suite they ran in;
            ``eval_seeds``: the board's evaluation seeds (runs per speed).
        scores: per entry, the pick first: ``{"name", "mean", "ci", "runs", "lost",
            "by_speed"}``: the attenuation (dB) over the headline runs, its interval
            over the seeds (zero wide where the runs do not depend on the seed, as
            without sensor noise), the runs that lost steps, the mean per speed.
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
        low, high = _mean_interval([db[k] for k in keys], [k[2] for k in keys])
        lost = sum(1 for r in rows[name]["runs"] if r["failed"]
                   and not r["speed_label"].startswith("off"))
        speeds = sorted({k[2] for k in keys})
        by_speed = {v: _mean([db[k] for k in keys if k[2] == v]) for v in speeds}
        scores.append({"name": name, "mean": _mean([db[k] for k in keys]), "ci": [low, high],
                       "runs": len(keys), "lost": lost, "by_speed": by_speed})
    if not scores:
        raise ParameterError(f"no exportable entry could be scored on {system.name!r}")
    scores.sort(key=lambda s: (s["lost"] > 0, -s["mean"], s["name"]))
    pick = scores[0]
    tied = tuple(s["name"] for s in scores[1:]
                 if not paired_difference(per_run[pick["name"]], per_run[s["name"]])["low"] > 0.0)
    return Recommendation(system.name, suite, eval_seeds, tuple(scores), pick, tied)


def _mean(values: Sequence[float]) -> float:
    """The mean in a fixed order (the same bits on every CPU)."""
    x = np.ascontiguousarray(values, dtype=np.float64)
    return float(fm.dot(x, np.full(x.size, 1.0 / x.size)))


def _mean_interval(values: Sequence[float], strata: Sequence[Any], resamples: int = 2000,
                   seed: int = 2000, confidence: float = 0.95) -> tuple[float, float]:
    """Percentile interval of the mean under a bootstrap that resamples within each
    stratum (a speed: its seeds), as many values as it holds."""
    x = np.asarray(values, dtype=np.float64)
    rng = np.random.default_rng(seed)
    groups: dict[Any, list[int]] = {}
    for i, k in enumerate(strata):
        groups.setdefault(k, []).append(i)
    parts = [x[np.asarray(groups[k])[rng.integers(0, len(groups[k]), (resamples, len(groups[k])))]]
             for k in sorted(groups, key=str)]
    sample = np.ascontiguousarray(np.concatenate(parts, axis=1))
    means = fm.weighted_rows(sample, np.full(sample.shape[1], 1.0 / sample.shape[1]))
    alpha = (1.0 - confidence) / 2.0
    low, high = np.quantile(means, [alpha, 1.0 - alpha])
    return float(low), float(high)
