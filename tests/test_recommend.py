"""``stepdamp recommend`` (issue #52): the exportable entries ranked on a quick board
of one motor, the pick and what to expect from it."""

from __future__ import annotations

import os
import shlex

import pytest

from stepdamp_env.bench.recommend import exportable_entries, recommend
from stepdamp_env.cli import main
from stepdamp_env.motorfile import load_system

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MOTOR = os.path.join(ROOT, "docs", "motors", "17hs4401.json")


def test_the_exportable_entries_are_what_export_can_write():
    names = exportable_entries(load_system(MOTOR))
    assert {"ff-delay-comp", "tuned-constant-gain", "tuned-gain-pair", "velocity-feedback",
            "sensorless-damping"} <= set(names)
    # Not exportable: adaptive, oracles, learned agents, no damping; in servo the
    # open-loop feedback laws (a servo closes its own loop).
    assert not {"none", "adaptive-ff", "repetitive-control", "plant-bound",
                "oracle-floor"} & set(names)
    servo = exportable_entries(load_system(MOTOR), "servo")
    assert "tuned-gain-pair" in servo and not {"velocity-feedback",
                                               "sensorless-damping"} & set(servo)


@pytest.mark.slow
def test_recommend_scores_them_on_the_motor_and_picks_the_best(capsys):
    rec = recommend(load_system(MOTOR), workers=2)
    names = [s["name"] for s in rec.scores]
    assert set(names) <= set(exportable_entries(load_system(MOTOR))) and "none" not in names
    assert rec.pick is rec.scores[0] and rec.pick["lost"] == 0
    assert rec.pick["mean"] == max(s["mean"] for s in rec.scores if s["lost"] == 0)
    assert all(s["ci"][0] - 1e-9 <= s["mean"] <= s["ci"][1] + 1e-9 and s["runs"] >= 6
               and len(s["by_speed"]) == 3 for s in rec.scores)
    # Damping pays on this motor: the pick is far above no damping, with its interval.
    assert rec.pick["ci"][0] > 10.0
    assert main(["recommend", MOTOR, "--no-progress", "--workers", "2"]) == 0
    out = capsys.readouterr().out
    assert f"flash {rec.pick['name']}: expect {rec.pick['mean']:.1f} dB" in out
    assert f"stepdamp export {rec.pick['name']} --motor {shlex.quote(MOTOR)}" in out
    # The suggested grid reaches the top of the motor's range (0.313:3.13 rev/s).
    assert "--speeds 0.313:3.13:0.0939 " in out
