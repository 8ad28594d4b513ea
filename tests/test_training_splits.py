"""Agents trained for the suite they are scored in, selected on the dev split: the
suite tasks, the coverage and suites a model declares, and the splits every
training config records (never a scored one)."""

from __future__ import annotations

import glob
import json
import os

import pytest

torch = pytest.importorskip("torch")

from stepdamp_agents import REFERENCE_DIR  # noqa: E402
from stepdamp_agents.policy import trained_suites, training_coverage  # noqa: E402
from stepdamp_agents.selection import (SCORED_SPLITS, SELECTION_SPLITS,  # noqa: E402
                                       training_splits)
from stepdamp_agents.task import REFERENCE_TASK, SUITE_TASKS, suite_task  # noqa: E402
from stepdamp_agents.train import Args, train  # noqa: E402
from stepdamp_env.bench.protocols import protocol_for  # noqa: E402
from stepdamp_env.bench.protocols.v3 import eligible  # noqa: E402
from stepdamp_env.params import ParameterError  # noqa: E402

torch.set_num_threads(1)


def test_suite_tasks_set_mode_drive_and_speeds():
    servo = suite_task(REFERENCE_TASK, "servo")
    assert servo["mode"] == "servo" and servo["resonance_prob"] == 0.0
    mid = suite_task(REFERENCE_TASK, "mid-band")
    assert mid["overrides"] == {**REFERENCE_TASK["overrides"], "drive_mode": "voltage"}
    assert suite_task(REFERENCE_TASK, "open-loop") == REFERENCE_TASK
    with pytest.raises(ParameterError, match="suite"):
        suite_task(REFERENCE_TASK, "closed-loop")


@pytest.mark.parametrize("suite", ["servo", "mid-band"])
def test_suite_speeds_cover_the_dev_headline_speeds(suite):
    """The training draw covers every dev motor's headline speeds of the suite (the
    split the ranges were chosen on), so a dev score is never zero-shot."""
    config = {"training": {"motors": [], "env_kwargs": suite_task(REFERENCE_TASK, suite)}}
    covered = training_coverage(config)
    assert [c[0] for c in covered] == [suite]
    for m in protocol_for("v3", quick=True).with_splits(["dev"]).with_suites([suite]).motors():
        speeds, labels = m.speeds(suite)
        head = [v for v, lbl in zip(speeds, labels) if not lbl.startswith("off")]
        assert eligible(covered, suite, head), (m.name, head, covered)


@pytest.mark.parametrize("suite", list(SUITE_TASKS))
def test_a_trained_model_records_its_suite_and_splits(tmp_path, suite):
    from stepdamp_agents.per_step import StepAgent

    out = str(tmp_path / suite)
    args = Args(algo="ars", out=out, total_timesteps=200, eval_freq=0, checkpoint_freq=0,
                progress=False, tensorboard=False, suite=suite, envs_per_motor=1,
                extra={"n_delta": 1, "n_top": 1, "env_kwargs": {"agent_hz": 25.0,
                                                                "episode_s": 0.2}})
    train(args)
    with open(os.path.join(out, "final.agent.json"), encoding="utf-8") as fh:
        config = json.load(fh)
    assert config["training"]["suite"] == suite
    assert training_splits(config) == {"motors": "train", "selection": "none"}
    agent = StepAgent(os.path.join(out, "final.zip"))
    assert agent.card.suites == (suite,) == trained_suites(config)
    assert {c[0] for c in agent.card.trained_on} == {suite}


def test_no_committed_model_was_trained_or_selected_on_a_scored_split():
    configs = sorted(glob.glob(os.path.join(REFERENCE_DIR, "*.agent.json")))
    assert configs
    for path in configs:
        with open(path, encoding="utf-8") as fh:
            splits = training_splits(json.load(fh))
        # The datasheet pool's parts (0.19.0): its train part, selection on its dev part.
        assert splits["motors"] in ("train", "pool-train"), path
        assert splits["selection"] in SELECTION_SPLITS + ("none", "pool-dev"), path
        assert not set(splits.values()) & set(SCORED_SPLITS), path


def test_suite_and_dev_selection_need_the_per_step_env():
    with pytest.raises(ParameterError, match="--suite"):
        train(Args(env="StepperDampResidual-v0", algo="ppo", suite="servo", out="unused"))


def test_suite_settings_given_with_set_are_refused():
    with pytest.raises(ParameterError, match=r"--hyperparam env_kwargs \['mode'\]: --suite servo"):
        train(Args(algo="ars", suite="servo", out="unused",
                   extra={"env_kwargs": {"mode": "open-loop"}}))


def test_without_suite_a_model_records_none_and_runs_in_every_suite(tmp_path):
    from stepdamp_agents.per_step import StepAgent

    out = str(tmp_path / "plain")
    train(Args(algo="ars", out=out, total_timesteps=200, eval_freq=0, checkpoint_freq=0,
               progress=False, tensorboard=False, envs_per_motor=1,
               extra={"n_delta": 1, "n_top": 1, "env_kwargs": {"episode_s": 0.2}}))
    agent = StepAgent(os.path.join(out, "final.zip"))
    assert "suite" not in agent.config["training"] and trained_suites(agent.config) is None
    assert agent.card.suites is None                    # every suite


def test_stop_at_db_stops_at_the_first_dev_check_that_reaches_it(tmp_path):
    """``--stop-at-db``: the first dev check during training at or above it ends
    the training (no final check: that check's model is final.zip); each check
    records its own time apart from the training's."""
    out = str(tmp_path / "stop")
    log = train(Args(algo="ppo", out=out, total_timesteps=800, eval_freq=100, checkpoint_freq=0,
                     progress=False, tensorboard=False, suite="open-loop", select_on="dev",
                     stop_at_db=-200.0, envs_per_motor=1,
                     extra={"n_steps": 50, "batch_size": 50,
                            "env_kwargs": {"agent_hz": 25.0, "episode_s": 0.2}}))
    checks = log["evaluations"]
    assert [c["tag"] for c in checks] == ["initial (zero residual = base controller)",
                                          "periodic"]
    assert log["stopped_at_db"] == -200.0 and 100 <= checks[1]["step"] < 800
    assert all(c["check_s"] > 0 and 0 <= c["learn_s"] <= c["wall_s"] for c in checks)
    assert checks[1]["learn_s"] + checks[0]["check_s"] <= checks[1]["wall_s"] + 0.1
    assert os.path.exists(os.path.join(out, "final.zip"))


@pytest.mark.parametrize("value, message", [
    ("x", r"--stop-at-db 'x' is outside its allowed range \[-200, 200\] \(dB\)"),
    ("nan", r"--stop-at-db nan is outside"),
    ("300", r"--stop-at-db 300.0 is outside"),
])
def test_stop_at_db_refuses_what_is_not_a_db_value(value, message):
    from stepdamp_agents.train import main

    with pytest.raises(ParameterError, match=message):
        main(["--algo", "ppo", "--select-on", "dev", "--stop-at-db", value, "--out", "unused"])


def test_stop_at_db_needs_dev_checks_and_an_algorithm_that_stops():
    with pytest.raises(ParameterError, match="--stop-at-db needs --select-on dev"):
        train(Args(algo="ppo", out="unused", stop_at_db=30.0))
    with pytest.raises(ParameterError, match="--stop-at-db is not supported with --algo ars"):
        train(Args(algo="ars", out="unused", stop_at_db=30.0, select_on="dev"))
