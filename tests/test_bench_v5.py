"""stepdamp-bench v5: v4 with the board's envelope as the bound (cross-fitted
over evaluation seeds), on the motor where v4's bound scored below no damping."""

from __future__ import annotations

import dataclasses
import json
import lzma
import math

import pytest

from stepdamp_env.bench.protocols import protocol_for
from stepdamp_env.bench.protocols.v5 import ENVELOPE, envelope_runs
from stepdamp_env.cli import main


def _run(motor: str, speed: float, seed: int, db: float, ts=None) -> dict:
    return {"motor": motor, "speed_rps": speed, "speed_label": "r1", "seed": seed,
            "training_seed": ts, "db": db}


def _score(run: dict) -> float:
    return run["db"]


def test_the_envelope_chooses_each_seeds_run_on_the_other_seeds():
    # A is better on seeds 1 and 2, B on seed 3 alone: seed 3's choice (on 1 and 2)
    # is A, although B's run there scores higher.
    got = envelope_runs(_score, {
        ("a", None): [_run("m", 2.0, 1, 10.0), _run("m", 2.0, 2, 10.0), _run("m", 2.0, 3, 1.0)],
        ("b", None): [_run("m", 2.0, 1, 5.0), _run("m", 2.0, 2, 5.0), _run("m", 2.0, 3, 20.0)]})
    chosen = {r["seed"]: (r["chosen"]["spec"], r["db"]) for r in got}
    # Seed 1: A 5.5 (its mean on 2, 3) against B 12.5: B; seed 2 likewise; seed 3: A.
    assert chosen == {1: ("b", 5.0), 2: ("b", 5.0), 3: ("a", 1.0)}


def test_the_envelope_keeps_trained_models_apart_and_breaks_ties_by_order():
    runs = {("p", 12): [_run("m", 2.0, s, 3.0, 12) for s in (1, 2)],
            ("p", 11): [_run("m", 2.0, s, 3.0, 11) for s in (1, 2)],
            ("none", None): [_run("m", 2.0, s, 0.0) for s in (1, 2)]}
    got = envelope_runs(_score, runs)
    assert [r["chosen"] for r in got] == [{"spec": "p", "training_seed": 11}] * 2
    assert all(r["training_seed"] is None for r in got)          # one row, not five
    assert all("chosen" not in r for c in runs.values() for r in c)   # copies


def test_a_lost_run_is_not_chosen_on_a_score_it_does_not_have():
    got = envelope_runs(_score, {
        ("a", None): [_run("m", 2.0, 1, math.nan), _run("m", 2.0, 2, math.nan)],
        ("b", None): [_run("m", 2.0, 1, -20.0), _run("m", 2.0, 2, -20.0)]})
    assert [r["chosen"]["spec"] for r in got] == ["b", "b"]


def test_one_evaluation_seed_has_no_envelope():
    assert envelope_runs(_score, {("a", None): [_run("m", 2.0, 1, 3.0)]}) == []


def test_v5_is_v4_with_the_envelope_as_its_bound_and_the_later_agents():
    v5, v4 = protocol_for("v5"), protocol_for("v4")
    assert v5.bound_entry == ENVELOPE and v4.bound_entry == "plant-bound"
    from stepdamp_env.bench import default_policy_names

    names = default_policy_names()
    assert set(v5.default_entries(names)) - set(v4.default_entries(names)) == {
        "ppo-moves", "ppo-mid-band-datasheets", "ppo-mid-band-unrelated",
        "ppo-open-loop-unrelated"}
    assert "privileged-bound" not in v5.default_entries(names)
    assert protocol_for("v5", quick=True).eval_seeds == protocol_for("v4", quick=True).eval_seeds


def test_v5s_default_entries_are_its_published_boards_and_a_later_entry_stays_off():
    """The envelope and every paired comparison depend on the board's rows: an
    entry registered after v5 was published must not join its default board."""
    import os

    from stepdamp_env.bench import default_policy_names
    from stepdamp_env.bench.protocols.v5 import PUBLISHED_ENTRIES_V5

    v5 = protocol_for("v5")
    assert v5.default_entries(default_policy_names()) == [
        n for n in default_policy_names() if n in PUBLISHED_ENTRIES_V5]
    assert set(v5.default_entries(default_policy_names())) == set(PUBLISHED_ENTRIES_V5)
    assert v5.default_entries([*default_policy_names(), "a-later-entry"]) == \
        v5.default_entries(default_policy_names())
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with open(os.path.join(root, "docs", "results", "v5", "leaderboard.json")) as fh:
        published = {e["name"] for e in json.load(fh)["entries"]}
    assert published - {"reference", ENVELOPE} == set(PUBLISHED_ENTRIES_V5)


# The reviewer's held-out motor on which v4's plant-bound scored -7.0 dB in the
# mid-band (every law of its portfolio destabilises it; docs/results/agents/
# mid-band-unrelated/heldout/motors.json).
LDO = {"name": "LDO 42STH60-3004MAC", "step_angle_deg": 0.9, "rated_current_A": 3.0,
       "holding_torque_Nm": 0.8, "phase_resistance_ohm": 1.1, "phase_inductance_H": 0.0035,
       "rotor_inertia_kgm2": 1.68e-05}


@pytest.mark.slow
def test_the_envelope_holds_where_plant_bound_fell_below_no_damping(tmp_path, capsys):
    path = tmp_path / "motors.json"
    path.write_text(json.dumps([LDO]))
    out = tmp_path / "board"
    assert main(["leaderboard", "--protocol", "v5", "--quick", "--motors", str(path),
                 "--suite", "mid-band", "--entries", "none", "plant-bound",
                 "velocity-feedback", "--out", str(out), "--no-plots", "--no-progress",
                 "--workers", "1"]) == 0
    board = json.loads((out / "leaderboard.json").read_text())
    db = {e["name"]: e["per_motor_db"][LDO["name"]] for e in board["entries"]}
    assert db["plant-bound"] < db["none"]          # v4's bound fails here
    assert db[ENVELOPE] >= max(db["none"], db["velocity-feedback"])
    (t,) = board["tables"]
    assert t["bound_check"]["entry"] == ENVELOPE and t["bound_check"]["holds"] == 1
    env = next(e for e in board["entries"] if e["name"] == ENVELOPE)
    assert env["privileged"] and env["rank"] is None
    with lzma.open(out / "leaderboard_runs.json.xz", "rt") as fh:
        runs = next(e for e in json.load(fh)["entries"] if e["name"] == ENVELOPE)["runs"]
    assert {r["chosen"]["spec"] for r in runs} <= {"none", "plant-bound", "velocity-feedback"}
    # `report --check` re-runs the envelope's runs as the runs they copy (the last
    # sampled run is the envelope's last).
    capsys.readouterr()
    assert main(["report", str(out), "--check", "--sample", "3"]) == 0
    printed = capsys.readouterr().out
    assert "DIFFERS" not in printed and printed.strip().endswith("checks reproduce")
    assert f"reproduces  {ENVELOPE} mid-band: " in printed       # its choices derived again
    # A recorded choice edited: the check derives it again and says so.
    with lzma.open(out / "leaderboard_runs.json.xz", "rt") as fh:
        raw = json.load(fh)
    run = next(e for e in raw["entries"] if e["name"] == ENVELOPE)["runs"][0]
    run["chosen"] = {"spec": "velocity-feedback" if run["chosen"]["spec"] != "velocity-feedback"
                     else "none", "training_seed": None}
    with lzma.open(out / "leaderboard_runs.json.xz", "wt") as fh:
        json.dump(raw, fh)
    assert main(["report", str(out), "--check", "--sample", "1"]) == 1
    assert f"DIFFERS     {ENVELOPE} mid-band: " in capsys.readouterr().out


def _table(best_db: float, bound_db: float, reference_db: float, beaten_by: float = 0.0):
    """A table of three motors: the reference, a best row and the bound."""
    def row(name, db, **kw):
        return {"name": name, "spec": name, "reference": False, "privileged": False,
                "attenuation_db": {"iqm": db}, "per_motor_db": {m: db for m in "abc"},
                "cells": {"scored": 3, "split": 3}, "rank": None, **kw}
    rival = row("rival", best_db + beaten_by)
    rival["per_motor_db"] = {"a": best_db + beaten_by, "b": best_db, "c": best_db}
    return [row("reference", reference_db, reference=True),
            row("best", best_db, rank=1), row(ENVELOPE, bound_db, privileged=True),
            {**rival, "rank": 2}]


@pytest.mark.parametrize("beaten_by, holds, within", [(0.05, 3, 1), (0.5, 2, 0)])
def test_a_row_within_the_tolerance_does_not_beat_the_envelope(beaten_by, holds, within):
    from stepdamp_env.bench.verdicts import table_facts

    facts = table_facts(protocol_for("v5"), _table(20.0, 20.0, 40.0, beaten_by))
    b = facts["bound_check"]
    assert (b["holds"], len(b["within_tolerance_on"]), b["tolerance_db"]) == (holds, within, 0.1)
    v4 = dataclasses.replace(protocol_for("v4"), bound_entry=ENVELOPE)   # v4's rules
    v4 = table_facts(v4, _table(20.0, 20.0, 40.0, beaten_by))["bound_check"]
    assert v4["holds"] == 2 and "within_tolerance_on" not in v4        # v4 as published


@pytest.mark.parametrize("reference_db, saturated", [(40.0, False), (21.0, True)])
def test_v5_is_saturated_only_near_the_bound_and_the_reference(reference_db, saturated):
    from stepdamp_env.bench.verdicts import table_facts

    facts = table_facts(protocol_for("v5"), _table(20.0, 21.0, reference_db))
    assert facts["saturated"] is saturated, facts["saturated_why"]
    assert facts["reference_gap_db"] == pytest.approx(reference_db - 20.0)
    v4 = dataclasses.replace(protocol_for("v4"), bound_entry=ENVELOPE)   # v4's rules
    assert table_facts(v4, _table(20.0, 21.0, reference_db))["saturated"]
