"""How often a rank rule ties entries that differ, and separates entries that do not.

Run: ``PYTHONPATH=. python benchmarks/bench_ranks.py [--boards 400] [--motors 16]``.

Simulated boards: ``--motors`` motors whose difficulty differs (a motor effect
N(0, ``--motor-sd`` dB) shared by every entry, as real motors share theirs),
each entry's per-motor score its true score plus that effect plus its own noise
N(0, ``--noise-sd`` dB). For a pair of entries ``delta`` dB apart (0: equal),
the share of boards on which the two get different ranks, under the paired
rule (:func:`stepdamp_env.bench.stats.paired_ranks`, v4) and under v3's rule
(overlapping per-entry intervals share a rank,
:func:`stepdamp_env.bench.stats.rank_groups` of
:func:`stepdamp_env.bench.stats.motor_mean_bootstrap`). At delta 0 that share
is the false-separation rate; at delta > 0, one minus it is the false-tie rate.
"""

from __future__ import annotations

import argparse

import numpy as np


def simulated_scores(rng: np.random.Generator, true_db: tuple[float, ...], motors: int,
                     motor_sd: float, noise_sd: float) -> dict[str, dict[str, float]]:
    """Per-motor scores (dB) of entries ``e0``, ``e1``, ... with the true scores given."""
    effect = rng.normal(0.0, motor_sd, motors)
    return {f"e{i}": {f"m{m}": float(t + effect[m] + rng.normal(0.0, noise_sd))
                      for m in range(motors)} for i, t in enumerate(true_db)}


def separated(scores: dict[str, dict[str, float]], rule: str, seed: int) -> bool:
    """Whether ``e0`` and ``e1`` get different ranks under ``rule``."""
    from stepdamp_env.bench.stats import (iqm, motor_mean_bootstrap, paired_ranks,
                                          rank_groups)

    est = {k: iqm(list(v.values())) for k, v in scores.items()}
    if rule == "paired":
        ranks = paired_ranks(est, scores, resamples=500, seed=seed)
    else:
        boot = {k: motor_mean_bootstrap(list(v.values()), list(v), resamples=500, seed=seed)
                for k, v in scores.items()}
        names = list(scores)
        ranks = dict(zip(names, rank_groups([boot[k]["iqm"] for k in names],
                                            [boot[k]["ci"] for k in names])))
    return ranks["e0"] != ranks["e1"]


def rates(boards: int, motors: int, motor_sd: float, noise_sd: float,
          deltas: tuple[float, ...]) -> dict[tuple[str, float], float]:
    """Share of boards separating the pair, per rule and delta."""
    out = {}
    for rule in ("paired", "v3 intervals"):
        for delta in deltas:
            rng = np.random.default_rng(12345)
            hits = sum(separated(simulated_scores(rng, (delta, 0.0), motors, motor_sd, noise_sd),
                                 rule, b) for b in range(boards))
            out[rule, delta] = hits / boards
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--boards", type=int, default=400)
    parser.add_argument("--motors", type=int, default=16)
    parser.add_argument("--motor-sd", type=float, default=6.0, help="dB")
    parser.add_argument("--noise-sd", type=float, default=1.5, help="dB")
    args = parser.parse_args()
    deltas = (0.0, 0.5, 1.0, 2.0, 4.0)
    got = rates(args.boards, args.motors, args.motor_sd, args.noise_sd, deltas)
    print(f"{args.boards} boards of {args.motors} motors, motor effect sd {args.motor_sd} dB, "
          f"noise sd {args.noise_sd} dB: share of boards where two entries delta dB apart get "
          "different ranks")
    print("rule           " + "".join(f"  delta {d:3.1f}" for d in deltas))
    for rule in ("paired", "v3 intervals"):
        print(f"{rule:15s}" + "".join(f"  {got[rule, d]:9.3f}" for d in deltas))


if __name__ == "__main__":
    main()
