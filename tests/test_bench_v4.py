"""stepdamp-bench v4: paired ranks, evaluation seeds, per-cell eligibility, the
lost-run rule, the catalogue split and the per-table facts."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from stepdamp_env.bench import protocol_motors, run_leaderboard
from stepdamp_env.bench.protocols import protocol_for
from stepdamp_env.bench.protocols.v4 import (ProtocolV4, catalogue_systems, coverage,
                                             evaluation_seeds, quick_protocol_v4)
from stepdamp_env.bench.tables import render_markdown, render_suite_page
from stepdamp_env.cli import main
from stepdamp_env.parallel import default_workers
from stepdamp_env.params import ParameterError


def _run(failed: bool, rms: float | None) -> dict:
    return {"failed": failed, "metrics": None if rms is None else
            {"rms_velocity_error_rad_s": rms}}


def test_a_held_run_never_scores_below_a_lost_run_of_the_same_cell():
    p = ProtocolV4()
    rng = np.random.default_rng(3)
    for _ in range(500):
        none_rms = float(rng.lognormal(0.0, 1.0))
        stand_in = float(rng.lognormal(0.0, 1.0))
        entry_rms = float(none_rms * 10 ** rng.uniform(-3, 3))
        for none in (_run(False, none_rms), _run(True, none_rms), _run(True, None), None):
            lost = p.run_db(_run(True, None), none, stand_in)
            held = p.run_db(_run(False, entry_rms), none, stand_in)
            assert held >= lost, (none, entry_rms)
    # Where `none` held: lost -20 dB, a held run 10x worse than none's -20 dB (the floor).
    assert p.run_db(_run(True, None), _run(False, 1.0), 2.0) == -20.0
    assert p.run_db(_run(False, 10.0), _run(False, 1.0), 2.0) == pytest.approx(-20.0)
    # Where `none` lost: lost 0 dB (no worse than no damping), held at least 0 dB.
    assert p.run_db(_run(True, None), _run(True, 5.0), 2.0) == 0.0
    assert p.run_db(_run(False, 4.0), _run(True, 5.0), 2.0) == 0.0
    assert p.run_db(_run(False, 0.2), _run(True, 5.0), 2.0) == pytest.approx(20.0)
    # No held run of `none` on that motor and seed: no score, held or lost.
    assert math.isnan(p.run_db(_run(False, 0.2), _run(True, 5.0), math.nan))
    assert math.isnan(p.run_db(_run(True, None), _run(True, 5.0), math.nan))


def test_coverage_counts_the_cells_whose_speed_the_training_covered():
    cells = [("a", 1.0), ("a", 2.0), ("b", 3.0), ("b", 10.0)]
    share, covered = coverage([("open-loop", 0.5, 3.0), ("servo", 0.0, 100.0)], "open-loop", cells)
    assert share == 0.75 and covered == {("a", 1.0), ("a", 2.0), ("b", 3.0)}
    assert coverage([], "open-loop", cells) == (0.0, frozenset())
    assert coverage([("open-loop", 0, 1)], "open-loop", [])[0] == 0.0


def test_evaluation_seeds_are_a_count_from_the_training_limit_on():
    assert evaluation_seeds(3) == (1_000_000, 1_000_001, 1_000_002)
    assert ProtocolV4().eval_seeds == evaluation_seeds(3)
    assert quick_protocol_v4().with_eval_seeds(5).eval_seeds == evaluation_seeds(5)
    for bad in (0, 21, 2.5):
        with pytest.raises(ParameterError, match=r"--eval-seeds .* is outside \[1, 20\]"):
            evaluation_seeds(bad)
    with pytest.raises(ParameterError, match="--eval-seeds: .* v3's evaluation seeds are frozen"):
        protocol_for("v3").with_eval_seeds(3)


def test_the_cli_refuses_eval_seeds_on_a_frozen_protocol_in_one_line(tmp_path, capsys):
    assert main(["leaderboard", "--protocol", "v3", "--quick", "--eval-seeds", "2",
                 "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--eval-seeds" in err[0] and "v4" in err[0]


def test_bad_v4_settings_name_the_setting_and_its_range():
    for field, value in (("coverage_min", 0.0), ("rank_confidence", 1.0),
                         ("bound_share_min", 0.0), ("saturation_db", -1.0),
                         ("decisive_share", 0.5), ("min_paired_motors", 0)):
        with pytest.raises(ParameterError, match=field):
            ProtocolV4(**{field: value})
    with pytest.raises(ParameterError, match="catalogue_motors"):
        catalogue_systems(ProtocolV4(), ("no-such-motor",))


def test_the_catalogue_split_holds_the_real_motors_as_their_own_model():
    full = ProtocolV4(splits=("catalogue",))
    systems = catalogue_systems(full)
    assert len(systems) >= 20
    quick = quick_protocol_v4().with_splits(("catalogue",))
    motors = protocol_motors(quick)
    assert [m.name for m in motors] == list(quick.catalogue_motors)
    for m in motors:
        assert m.split == "catalogue" and m.system == m.nominal
        assert m.system.servo.encoder_cpr == 4000      # the file gives none: the protocol's
        assert any(not lbl.startswith("off") for lbl in m.speeds("open-loop").labels)
    with pytest.raises(ParameterError, match="--split custom"):
        quick.with_splits(("custom",))


ENTRIES = ["none", "tuned-constant-gain", "tuned-gain-pair", "plant-bound",
           "ppo-open-loop"]


@pytest.fixture(scope="module")
def board():
    p = quick_protocol_v4().with_suites(("open-loop",))
    return run_leaderboard(p, ENTRIES, workers=2, progress=False)


@pytest.mark.slow
def test_ranks_are_monotone_paired_and_per_seed(board):
    seeds = [str(s) for s in board["protocol"]["eval_seeds"]]
    assert len(seeds) == 2
    tables = {(t["suite"], t["split"]): t for t in board["tables"]}
    assert set(tables) == {("open-loop", s) for s in ("interpolation", "extrapolation",
                                                     "catalogue")}
    for (suite, split), t in tables.items():
        rows = [e for e in board["entries"] if e["suite"] == suite and e["split"] == split]
        ranked = sorted((e for e in rows if e["rank"] is not None),
                        key=lambda e: -e["attenuation_db"]["iqm"])
        assert [e["rank"] for e in ranked] == sorted(e["rank"] for e in ranked)  # no inversion
        assert ranked[0]["rank"] == 1
        for e in ranked:
            assert set(e["rank_by_seed"]) == set(seeds)
            # Nothing the leader beats with P >= 0.95 shares its rank.
            if e["rank"] == 1 and e is not ranked[0]:
                assert ranked[0]["probability_of_improvement"][e["name"]] < 0.95
        for e in rows:
            if e["reference"] or e["privileged"] or e["zero_shot"]:
                assert e["rank"] is None
        # The facts follow from the rows.
        best = max((e for e in ranked if e["spec"] != "none"),
                   key=lambda e: e["attenuation_db"]["iqm"])
        bound = next(e for e in rows if e["name"] == "plant-bound")
        assert t["best"] == best["name"]
        assert t["headroom_db"] == pytest.approx(bound["attenuation_db"]["iqm"]
                                                 - best["attenuation_db"]["iqm"])
        b = t["bound_check"]
        others = [e for e in rows if not (e["reference"] or e["privileged"])]
        beaten = {m for m, v in bound["per_motor_db"].items()
                  if any(o["per_motor_db"].get(m, -math.inf) > v for o in others)}
        assert {x["motor"] for x in b["beaten_on"]} == beaten
        assert b["holds"] == b["motors"] - len(beaten)
        # plant-bound is a bound per motor here (v3's privileged-bound was not,
        # on the catalogue motors).
        assert beaten == set(), (split, b["beaten_on"])
        assert t["rank_stability"]["seeds"] == 2
        if b["holds"] < 0.95 * b["motors"]:
            assert t["saturated"] is None and "bound is beaten" in t["saturated_why"]
        else:
            assert t["saturated"] == (t["headroom_db"] < 3.0 or not t["told_apart"]["bound"])
        assert t["cells"]["scored"] <= t["cells"]["split"]


@pytest.mark.slow
def test_rows_score_the_position_ripple_beside_the_velocity(board):
    for e in board["entries"]:
        pos = e["position_attenuation_db"]
        if e["name"] == "none":
            assert pos["iqm"] == 0.0
        assert set(e["per_motor_position_db"]) <= set(e["per_motor_db"])
        for r in e["runs"]:
            if r["metrics"] is not None:
                assert r["metrics"]["position_ripple_steps"] >= 0.0
    # Damping the velocity ripple damps the position ripple with it.
    rows = {(e["name"], e["split"]): e for e in board["entries"]}
    for split in ("interpolation", "extrapolation", "catalogue"):
        assert rows[("tuned-gain-pair", split)]["position_attenuation_db"]["iqm"] > 10.0
    assert "position ripple (dB)" in render_suite_page(board, "open-loop")


@pytest.mark.slow
def test_learned_rows_carry_their_coverage_and_are_ranked_by_it(board):
    for e in board["entries"]:
        assert 0.0 <= e["coverage"] <= 1.0
        if not e["learned"]:
            assert e["coverage"] == 1.0
        else:
            assert e["zero_shot"] == (e["coverage"] < 0.9)
            if 0.0 < e["coverage"] < 1.0:
                n = e["cells"]["split"]
                assert f"trained on {round(e['coverage'] * n)} of the table's {n} cells" \
                    in " ".join(e["notes"])
    # The catalogue's motors lie partly outside the open-loop agent's training speeds.
    ppo = next(e for e in board["entries"] if e["name"] == "ppo-open-loop"
               and e["split"] == "catalogue")
    assert ppo["coverage"] < 1.0


@pytest.mark.slow
def test_the_board_pages_state_the_table_facts(board):
    md = render_markdown(board)
    assert "| suite, split | best ranked | headroom (dB) |" in md
    assert "paired comparisons" in md
    page = render_suite_page(board, "open-loop")
    assert page.count("Table: cells scored") == 3
    assert "bound holds on" in page


@pytest.mark.slow
def test_v4_on_a_users_motors_runs_and_checks_its_bound_there(tmp_path):
    # Two catalogue motors as a user's --motors file: the custom split.
    import json

    from stepdamp_env.bench.protocols.v4 import CATALOGUE_PATH

    with open(CATALOGUE_PATH, encoding="utf-8") as fh:
        items = [m for m in json.load(fh) if m["name"] in ("qsh4218-35-10-027", "42byghm810")]
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(items))
    out = tmp_path / "board"
    assert main(["leaderboard", "--protocol", "v4", "--quick", "--motors", str(path),
                 "--suite", "open-loop", "--entries", "tuned-gain-pair", "plant-bound",
                 "--eval-seeds", "1", "--out", str(out), "--no-plots", "--no-progress",
                 "--workers", "1"]) == 0
    board = json.loads((out / "leaderboard.json").read_text())
    (t,) = board["tables"]
    assert t["split"] == "custom" and t["bound_check"]["motors"] == 2
    assert t["bound_check"]["holds"] == 2, t["bound_check"]
    assert t["saturated"] is None and "fewer than the 3" in t["saturated_why"]
    assert "bound holds on" in (out / "LEADERBOARD_open-loop.md").read_text()


def test_report_check_reruns_a_board_of_one_split_and_fewer_seeds(tmp_path, capsys):
    """`report --check` rebuilds the protocol with the board's --split and
    --eval-seeds (it once said such a board was of no built-in protocol)."""
    out = tmp_path / "board"
    assert main(["leaderboard", "--quick", "--split", "catalogue", "--eval-seeds", "1",
                 "--suite", "open-loop", "--entries", "none", "--out", str(out), "--no-plots",
                 "--no-progress", "--workers", "1"]) == 0
    capsys.readouterr()
    assert main(["report", str(out), "--check", "--sample", "2"]) == 0
    printed = capsys.readouterr().out
    assert "DIFFERS" not in printed and printed.strip().endswith("checks reproduce")


def test_a_motor_no_entry_scores_says_why_in_the_per_motor_table():
    # A pool dev motor whose mid-band speeds all lie off the suite's headline band
    # (docs/results/ablations: the committed dev board) once printed an empty row.
    import json
    import os

    from stepdamp_env.bench.tables import NO_MOTOR_SCORE, render_per_motor

    path = os.path.join(os.path.dirname(__file__), "..", "docs", "results", "ablations",
                        "mid-band-pool-unrelated", "dev_board", "leaderboard.json")
    with open(path, encoding="utf-8") as fh:
        board = json.load(fh)
    lines = render_per_motor(board, "mid-band", "custom").splitlines()
    row = [ln for ln in lines if ln.startswith("| Stepperonline 17HM08-1204S~6 |")]
    assert row == [f"| Stepperonline 17HM08-1204S~6 | {NO_MOTOR_SCORE} |"]
    assert sum(NO_MOTOR_SCORE in ln for ln in lines) == 1


@pytest.mark.slow
@pytest.mark.skipif(default_workers() < 2, reason="scoring forks only with 2 usable cores")
def test_the_tables_score_alike_here_and_on_forked_workers(monkeypatch):
    """A board of 2 workers scores its tables on forked workers, one of 1 here:
    the same board, bit for bit."""
    from stepdamp_env.bench.protocols import paired
    from stepdamp_env.bench.provenance import board_fingerprint

    forked = []

    def counted(fn, jobs, workers, **kwargs):
        forked.append((fn, len(jobs), workers))
        return pool_map(fn, jobs, workers, **kwargs)

    pool_map = paired.pool_map
    monkeypatch.setattr(paired, "pool_map", counted)
    p = quick_protocol_v4().with_suites(("open-loop", "servo"))
    serial = run_leaderboard(p, ENTRIES, workers=1, progress=False)
    assert forked == []
    two = run_leaderboard(p, ENTRIES, workers=2, progress=False)
    tables = {(e["suite"], e["split"]) for e in two["entries"]}
    assert forked == [(paired._scored_table, len(tables), 2)] and len(tables) >= 4
    assert board_fingerprint(serial) == board_fingerprint(two)
    assert json.dumps(serial["entries"]) == json.dumps(two["entries"])


def test_a_dead_scoring_worker_leaves_the_tables_scored_here(monkeypatch):
    """If a scoring worker dies, the parent scores every table itself (the runs
    are done and must not be lost)."""
    from stepdamp_env.bench.protocols import paired
    from stepdamp_env.parallel import WorkerLostError

    def dies(*args, **kwargs):
        raise WorkerLostError("a worker died")

    monkeypatch.setattr(paired, "pool_map", dies)
    p = quick_protocol_v4()
    tables = [paired.ScoringTable([], {}, {}, frozenset(), 0, "x") for _ in range(3)]
    scored = []
    monkeypatch.setattr(type(p), "score_table", lambda self, t: scored.append(t) or ["row"])
    assert p._score_tables(tables, 2) == [["row"]] * 3 and len(scored) == 3
