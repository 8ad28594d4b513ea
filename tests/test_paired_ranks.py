"""Ranks from paired comparisons over motors (``stats.paired_ranks``, for v4): an
entry shares rank 1 only if nothing beats it by the paired rule, ranks never
invert, and the rule's false-tie and false-separation rates on simulated boards."""

from __future__ import annotations

import math
import os
import sys

import numpy as np
import pytest

from stepdamp_env.bench.stats import (iqm, motor_mean_bootstrap, paired_difference,
                                      paired_ranks, rank_groups)

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "benchmarks"))
import bench_ranks  # noqa: E402


def _board(rng, true_db, motors=16, motor_sd=6.0, noise_sd=1.5):
    return bench_ranks.simulated_scores(rng, tuple(true_db), motors, motor_sd, noise_sd)


def test_an_entry_better_on_every_motor_is_ranked_apart_though_the_intervals_overlap():
    # The v3 audit's case: one entry beats another on 16 of 16 motors by a small
    # margin while the motors spread widely: v3's overlapping intervals tied them.
    rng = np.random.default_rng(1)
    base = rng.normal(20.0, 6.0, 16)
    scores = {"pair": {f"m{i}": float(b + 0.6) for i, b in enumerate(base)},
              "constant": {f"m{i}": float(b) for i, b in enumerate(base)}}
    est = {k: iqm(list(v.values())) for k, v in scores.items()}
    boot = {k: motor_mean_bootstrap(list(v.values()), list(v)) for k, v in scores.items()}
    assert rank_groups([boot["pair"]["iqm"], boot["constant"]["iqm"]],
                       [boot["pair"]["ci"], boot["constant"]["ci"]]) == [1, 1]
    assert paired_ranks(est, scores) == {"pair": 1, "constant": 2}
    t = paired_difference(scores["pair"], scores["constant"])
    assert t["share"] == 1.0 and t["low"] > 0 and t["motors"] == 16


def test_equal_entries_share_a_rank_and_an_entry_against_its_copy_is_not_beaten():
    rng = np.random.default_rng(2)
    scores = _board(rng, (5.0, 5.0))
    scores["copy"] = dict(scores["e0"])
    est = {k: iqm(list(v.values())) for k, v in scores.items()}
    ranks = paired_ranks(est, scores)
    assert ranks["e0"] == ranks["copy"] == 1
    assert paired_difference(scores["e0"], scores["copy"])["share"] == 0.5


@pytest.mark.parametrize("seed", range(6))
def test_ranks_never_invert_and_start_at_one(seed):
    rng = np.random.default_rng(seed)
    true = rng.uniform(0.0, 8.0, 7)
    scores = _board(rng, true, noise_sd=3.0)
    est = {k: iqm(list(v.values())) for k, v in scores.items()}
    est["lost"] = math.nan
    ranks = paired_ranks(est, scores, resamples=500)
    assert ranks["lost"] is None
    order = sorted((k for k in est if ranks[k] is not None), key=lambda k: -est[k])
    got = [ranks[k] for k in order]
    assert got[0] == 1 and got == sorted(got)


def test_the_leader_beating_an_entry_on_95_percent_of_motors_keeps_it_off_rank_1():
    # Per-motor differences noisy enough that the bootstrap bound alone might not
    # separate, but the leader wins on 19 of 20 motors: P(leader better) 0.95.
    d = np.array([0.2] * 19 + [-3.0])
    base = np.linspace(0.0, 30.0, 20)
    scores = {"lead": {f"m{i}": float(b + x) for i, (b, x) in enumerate(zip(base, d))},
              "other": {f"m{i}": float(b) for i, b in enumerate(base)}}
    est = {"lead": 1.0, "other": 0.0}
    assert paired_difference(scores["lead"], scores["other"])["share"] == 0.95
    assert paired_ranks(est, scores)["other"] == 2


def test_a_given_probability_of_improvement_also_decides():
    # Indistinguishable per-motor means, but the board's P says the leader wins.
    scores = {"a": {f"m{i}": float(i) for i in range(6)},
              "b": {f"m{i}": float(i) for i in range(6)}}
    est = {"a": 1.0, "b": 0.5}
    assert paired_ranks(est, scores) == {"a": 1, "b": 1}
    assert paired_ranks(est, scores, probability={("a", "b"): 0.95, ("b", "a"): 0.05}) \
        == {"a": 1, "b": 2}
    assert paired_ranks(est, scores, probability={("a", "b"): 0.94}) == {"a": 1, "b": 1}


def test_too_few_common_motors_decide_nothing():
    scores = {"a": {"m0": 10.0, "m1": 11.0}, "b": {"m0": 0.0, "m1": 1.0, "m2": 2.0}}
    assert paired_ranks({"a": 10.5, "b": 1.0}, scores) == {"a": 1, "b": 1}


@pytest.mark.slow
def test_false_separation_and_false_tie_rates_on_simulated_boards():
    # 16 motors, motor effect sd 6 dB, noise sd 1.5 dB (per-motor difference sd
    # 2.1 dB): equal entries are told apart on about 5 % of boards (the paired
    # rule's level), entries 2 dB apart on most and 4 dB apart on all; v3's
    # interval rule (the motors' spread in every interval) on almost none.
    got = bench_ranks.rates(200, 16, 6.0, 1.5, (0.0, 2.0, 4.0))
    assert got["paired", 0.0] <= 0.08
    assert got["paired", 2.0] >= 0.80
    assert got["paired", 4.0] >= 0.98
    assert got["v3 intervals", 4.0] <= 0.10
