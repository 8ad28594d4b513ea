"""Choose ``plant-bound``'s portfolio on stepdamp-bench v4's dev split, never on a
scored motor.

Runs ``plant-bound``'s rehearsals (no harmonic table) with the nine candidate
laws on every dev cell (``ProtocolV4`` with ``splits=("dev",)``, one process),
then, for each size k, prints the k laws whose best rehearsal is closest to
the best of all nine on every cell: the number of cells more than 1 dB and
0.3 dB worse, and the worst cell (dB). The smallest set that leaves no cell
0.3 dB worse goes into ``stepdamp_baselines.plant_bound.PORTFOLIO``.

Run: ``python scripts/bound_portfolio.py`` (about ten minutes on one core).
"""

from __future__ import annotations

import collections
import itertools
import math
from typing import Any

import stepdamp_baselines.plant_bound as pb
import stepdamp_env.cli  # noqa: F401 (registers the baselines, 'none' among them)
from stepdamp_env.bench import run_leaderboard
from stepdamp_env.bench.protocols.v4 import ProtocolV4
from stepdamp_env.bench.registry import register_policy

CANDIDATES = (("zeta", 0.0), ("zeta", 0.05), ("zeta", 0.1), ("zeta", 0.5), ("zeta", 2.0),
              ("kv", 0.05), ("kv", 0.2), ("kv", 0.5), ("kv", 1.0))


def rehearsals() -> dict[tuple[Any, ...], dict[tuple[str, float], float]]:
    """Per dev cell (motor, rev/s, suite), each candidate law's rehearsed ripple
    (rad/s RMS; absent where the run was lost)."""
    cells: dict[tuple[Any, ...], dict[tuple[str, float], float]] = collections.defaultdict(dict)
    run_episodes = pb.run_episodes

    def recorded(factory, specs, **kw):
        results = run_episodes(factory, specs, **kw)
        law = factory().law
        for spec, r in zip(specs, results):
            if not (r.failed or r.metrics is None):
                key = (spec.knowledge.plant.name, float(spec.speed_rps), kw.get("suite"))
                cells[key][law] = float(r.metrics["rms_velocity_error_rad_s"])
        return results

    pb.run_episodes = recorded
    register_policy("plant-bound-candidates",
                    lambda: pb.PlantBound(CANDIDATES, table_steps=0), kind="baseline")
    run_leaderboard(ProtocolV4(splits=("dev",)), ["plant-bound-candidates"], workers=1,
                    progress=False)
    pb.run_episodes = run_episodes
    return cells


def losses(cells, laws) -> list[float]:
    """Per cell, how much worse (dB) the best of ``laws`` is than the best of all."""
    out = []
    for got in cells.values():
        if not got:
            continue
        best = min(got.values())
        mine = [got[law] for law in laws if law in got]
        out.append(20.0 * math.log10(min(mine) / best) if mine else math.inf)
    return out


def main() -> None:
    cells = rehearsals()
    chosen = collections.Counter(min(got, key=lambda law: (got[law], CANDIDATES.index(law)))
                                 for got in cells.values() if got)
    print(f"{len(cells)} dev cells; best law per cell: {dict(chosen)}")
    for k in range(len(CANDIDATES), 3, -1):
        ranked = sorted(itertools.combinations(CANDIDATES, k), key=lambda laws: (
            sum(x > 1.0 for x in losses(cells, laws)), sum(x > 0.3 for x in losses(cells, laws)),
            max(losses(cells, laws))))
        laws = ranked[0]
        loss = losses(cells, laws)
        print(f"{k} laws {laws}: cells > 1 dB worse {sum(x > 1.0 for x in loss)}, "
              f"> 0.3 dB {sum(x > 0.3 for x in loss)}, worst {max(loss):.3f} dB")


if __name__ == "__main__":
    main()
