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


def _eager_ranks(estimates, per_motor, probability=None, decisive_share=0.95, min_motors=3):
    """paired_ranks' rule with the bootstrap run for every pair (as before 0.18)."""
    names = sorted((k for k in estimates if math.isfinite(estimates[k])),
                   key=lambda k: (-estimates[k], str(k)))

    def beats(j, k):
        t = paired_difference(per_motor.get(j, {}), per_motor.get(k, {}))
        p = (probability or {}).get((j, k), math.nan)
        return t["motors"] >= min_motors and (
            (t["iqm"] > 0.0 and (t["low"] > 0.0 or t["share"] >= decisive_share))
            or p >= decisive_share)

    raw = {k: 1 + sum(beats(j, k) for j in names if j != k) for k in names}
    out, best = {k: None for k in estimates}, 0
    for k in names:
        best = max(best, raw[k])
        out[k] = best
    first = out[names[0]] if names else 1
    return {k: None if v is None else v - first + 1 for k, v in out.items()}


@pytest.mark.parametrize("seed", range(6))
def test_ranks_skip_only_the_bootstraps_that_cannot_change_them(seed):
    # paired_ranks bootstraps a pair only where the IQM, the share and the given
    # probability leave the verdict open: the ranks are those of the eager rule.
    rng = np.random.default_rng(seed)
    scores = _board(rng, rng.uniform(0.0, 4.0, size=7), motors=int(rng.integers(3, 20)))
    est = {k: iqm(list(v.values())) for k, v in scores.items()}
    names = sorted(scores)
    prob = {(a, b): float(rng.uniform()) for a in names for b in names if a != b}
    for p in (None, prob):
        assert paired_ranks(est, scores, probability=p) == _eager_ranks(est, scores, p)
    # Each pair alone, where the rank is the verdict itself (no smoothing hides it).
    open_pairs = 0
    for a in names:
        for b in names:
            if a == b:
                continue
            pair = {a: est[a], b: est[b]}
            assert paired_ranks(pair, scores) == _eager_ranks(pair, scores)
            t = paired_difference(scores[a], scores[b])
            open_pairs += t["iqm"] > 0.0 and t["share"] < 0.95
    assert open_pairs > 0       # some verdicts asked the bootstrap


def test_a_paired_difference_without_its_interval_keeps_the_rest():
    rng = np.random.default_rng(3)
    x = {f"m{i}": float(v) for i, v in enumerate(rng.normal(1.0, 2.0, 12))}
    y = {f"m{i}": float(v) for i, v in enumerate(rng.normal(0.0, 2.0, 12))}
    full, bare = paired_difference(x, y), paired_difference(x, y, interval=False)
    assert math.isnan(bare["low"]) and math.isfinite(full["low"])
    assert {k: v for k, v in full.items() if k != "low"} == \
        {k: v for k, v in bare.items() if k != "low"}
    assert paired_difference(x, y) == full


def test_the_kept_motor_draws_are_a_new_generators_each_time():
    # median_difference and paired_difference keep their level-1 draws (every pair
    # of a table draws the same): each call sees exactly a new default_rng(seed)'s.
    from stepdamp_env.bench.stats import median_difference, widening_factor

    rng = np.random.default_rng(5)
    for motors in (7, 12, 7):
        x = {f"m{i:02d}": float(v) for i, v in enumerate(rng.normal(1.0, 2.0, motors))}
        y = {f"m{i:02d}": float(v) for i, v in enumerate(rng.normal(0.0, 2.0, motors))}
        d = np.array([x[k] - y[k] for k in sorted(x)])
        draws = np.random.default_rng(2000).integers(0, motors, size=(2000, motors))
        low, high = np.quantile(np.median(d[draws], axis=1), [0.025, 0.975])
        est, c = float(np.median(d)), widening_factor(motors, 0.95)
        for _ in range(2):
            got = median_difference(x, y)
            assert got["median"] == est
            assert got["ci"] == [est - c * (est - float(low)), est + c * (float(high) - est)]


def test_the_kept_draws_within_strata_are_a_new_generators_and_read_only():
    from stepdamp_env.bench import stats

    order = [f"m{i}" for i in range(9)]
    strata = {k: ("a", "b", "c")[i % 3] for i, k in enumerate(order)}
    for s in (strata, None):
        kept = stats._fresh_motor_draws(order, s, 7, 300)
        assert np.array_equal(kept, stats._motor_draws(order, s, np.random.default_rng(7), 300))
        assert not kept.flags.writeable
