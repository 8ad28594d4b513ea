"""Training for v4's moves suite (0.19.0): moves drawn per episode in the env,
the suite's training task, its dev check and coverage, and v4's frozen entries."""

from __future__ import annotations

import copy
import json
import math
import os

import numpy as np
import pytest

from stepdamp_env.params import ParameterError
from stepdamp_env.simulation import RAMPS, ramps_distance_rev

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _moves_env(**extra):
    import gymnasium as gym

    from stepdamp_agents.task import REFERENCE_TASK, suite_task

    return gym.make("StepperDamp-v1", **{**suite_task(REFERENCE_TASK, "moves"), **extra})


def test_drawn_moves_options_are_checked_in_one_line():
    from stepdamp_env.env.scalar import StepperDampEnv

    cases = [
        (dict(ramp="any"), "ramp='any' need profile='move'"),
        (dict(profile="move", speed_rps=1.0, distance_rev=2.0, cruise_s=0.3), "cruise_s=0.3 needs"),
        (dict(cruise_s=0.3), "cruise_s=0.3 needs profile='move'"),
        (dict(profile="move", speed_rps=1.0, cruise_s=-0.1), r"cruise_s=-0.1 is outside .*\[0.0, "),
        (dict(profile="move", speed_rps=1.0, cruise_s=0.3, accel_range_rps2=(100.0, 10.0)),
         r"accel_range_rps2=\(100.0, 10.0\) is outside its allowed range"),
        (dict(profile="move", speed_rps=1.0, cruise_s=0.3, accel_range_rps2=(0.0, 10.0)),
         r"accel_range_rps2=.* <= low <= high <= 1e5"),
        (dict(profile="move", speed_rps=1.0, cruise_s=0.3, accel_range_rps2=5.0),
         "accel_range_rps2 must be a"),
        (dict(profile="move", speed_rps=1.0), r"or give cruise_s"),
        (dict(accel_range_rps2=(25.0, 50.0)), "accel_range_rps2=.* needs profile='move'"),
        (dict(profile="move", speed_rps=1.0, cruise_s=2e4), r"\[0.0, 10000.0\] \(s\)"),
    ]
    for kwargs, message in cases:
        with pytest.raises(ParameterError, match=message) as caught:
            StepperDampEnv(**kwargs)
        assert "\n" not in str(caught.value)


def test_the_default_options_draw_nothing_more():
    """Without the new options an episode draws what it drew before 0.19.0 (the
    v0-v4 fingerprints check the rollouts too)."""
    from stepdamp_env.env import EnvOptionsV1, TaskV1

    for kwargs in ({}, {"profile": "move", "speed_rps": 1.0, "distance_rev": 3.0,
                        "ramp": "s-curve"}):
        task = TaskV1(EnvOptionsV1.from_kwargs(kwargs))
        rng = np.random.default_rng(5)
        before = copy.deepcopy(rng.bit_generator.state)
        ramp, accel = task.draws.draw_move(rng)
        assert rng.bit_generator.state == before
        assert (ramp, accel) == (kwargs.get("ramp", "trapezoid"), task.options.accel_rps2)
        assert task.draws.move_info(ramp, accel) == {}


def test_the_move_draws_come_after_the_episodes_other_draws():
    """With the move drawn or fixed, a seed gives the same motor, speed and
    harmonic; only the drawn options add keys to the reset info."""
    drawn = _moves_env()
    fixed = _moves_env(ramp="trapezoid", accel_range_rps2=None)
    for seed in range(6):
        info_d = drawn.reset(seed=seed)[1]
        info_f = fixed.reset(seed=seed)[1]
        assert {k: info_d[k] for k in info_f} == info_f
        assert set(info_d) - set(info_f) == {"ramp", "accel_rps2"}
        assert "ramp" not in info_f and "accel_rps2" not in info_f


def test_moves_are_drawn_per_episode_and_cruise_for_cruise_s():
    from stepdamp_env.env import EnvOptionsV1, TaskV1
    from stepdamp_agents.task import REFERENCE_TASK, suite_task

    kwargs = suite_task(REFERENCE_TASK, "moves")
    task = TaskV1(EnvOptionsV1.from_kwargs(kwargs))
    lo, hi = kwargs["accel_range_rps2"]
    rng = np.random.default_rng(11)
    draws = [task.draws.draw_move(rng) for _ in range(400)]
    ramps = [r for r, _ in draws]
    accels = np.array([a for _, a in draws])
    assert set(ramps) == set(RAMPS) and 0.4 < ramps.count("s-curve") / len(ramps) < 0.6
    assert lo <= accels.min() and accels.max() <= hi
    # Log-uniform: half of the draws below the geometric mean, a quarter per quartile of log.
    assert 0.43 < np.mean(accels < math.sqrt(lo * hi)) < 0.57
    for speed, (ramp, accel) in zip((0.3, 1.7, 4.2, 9.0), draws):
        prof = task.draws.profile(speed, ramp, accel)
        ramp_s = (0.5 * math.pi if ramp == "s-curve" else 1.0) * speed / accel
        assert prof.distance_rev == pytest.approx(ramps_distance_rev(speed, accel, ramp)
                                                  + 0.3 * speed, rel=1e-12)
        assert prof.duration_s() == pytest.approx(2.0 * ramp_s + 0.3, rel=1e-12)
        assert prof.cruise() == pytest.approx((ramp_s, 0.3), rel=1e-9)


@pytest.mark.parametrize("seed", [3, 4])
def test_a_moves_episode_moves_and_rests_where_its_command_ends(seed):
    env = _moves_env()
    obs, info = env.reset(seed=seed)
    assert info["ramp"] in RAMPS and 25.0 <= info["accel_rps2"] <= 312.5
    zero = np.zeros(env.action_space.shape, dtype=np.float32)
    speeds = []
    while True:
        obs, reward, terminated, truncated, _ = env.step(zero)
        speeds.append(float(obs[8]))                 # speed_command (the command, scaled)
        if terminated or truncated:
            break
    assert not terminated
    # The command cruises (a ramp may end within the first step) and comes back to rest.
    assert max(speeds) > 0.0 and speeds[-1] == 0.0


def test_a_model_trained_for_moves_covers_the_moves_suite_only():
    from stepdamp_agents.policy import trained_suites, training_coverage
    from stepdamp_agents.task import REFERENCE_TASK, suite_task

    config = {"training": {"suite": "moves", "motors": ["patent"],
                           "env_kwargs": suite_task(REFERENCE_TASK, "moves")}}
    ranges = training_coverage(config)
    assert ranges and {s for s, _, _ in ranges} == {"moves"}
    assert trained_suites(config) == ("moves",)
    # The same draw at constant speed covers the open-loop suite.
    config["training"] = {"suite": "open-loop", "motors": ["patent"],
                          "env_kwargs": copy.deepcopy(REFERENCE_TASK)}
    assert [r[1:] for r in training_coverage(config)] == [r[1:] for r in ranges]
    assert {s for s, _, _ in training_coverage(config)} == {"open-loop"}
    # The suite is the env's (mode, drive, command), whatever --suite said.
    config["training"] = {"motors": ["patent"], "env_kwargs": suite_task(REFERENCE_TASK, "moves")}
    assert {s for s, _, _ in training_coverage(config)} == {"moves"}


def test_the_moves_dev_check_is_v4s_and_the_others_stay_v3s():
    from stepdamp_agents.selection import DevValidator

    moves = DevValidator("moves")
    assert moves.version == "v4" and moves.protocol.splits == ("dev",)
    assert moves.protocol.suites == ("moves",)
    assert DevValidator("open-loop").version == "v3"


def test_train_refuses_what_the_moves_task_sets():
    from stepdamp_agents.settings import Args, check_args

    with pytest.raises(ParameterError, match=r"env_kwargs \['profile'\]: --suite moves sets"):
        check_args(Args(suite="moves", select_on="dev",
                        extra={"env_kwargs": {"profile": "constant"}}))
    check_args(Args(suite="moves", select_on="dev", extra={"env_kwargs": {"agent_hz": 25.0}}))
    with pytest.raises(ParameterError, match="--suite moves selects on --select-on dev"):
        check_args(Args(suite="moves"))
    check_args(Args(suite="moves", eval_freq=0))


def test_v4s_default_entries_are_its_published_boards():
    from stepdamp_env.bench.protocols.v4 import PUBLISHED_ENTRIES_V4, full_protocol_v4
    from stepdamp_env.bench.registry import default_policy_names

    chosen = full_protocol_v4().default_entries(default_policy_names())
    assert set(chosen) == set(PUBLISHED_ENTRIES_V4)
    with open(os.path.join(ROOT, "docs", "results", "v4", "leaderboard.json")) as fh:
        published = {e["name"] for e in json.load(fh)["entries"]} - {"reference"}
    assert published == set(PUBLISHED_ENTRIES_V4)


def test_ppo_moves_is_trained_for_the_moves_suite_and_runs_there_only():
    pytest.importorskip("torch")
    from stepdamp_agents import reference_agent, reference_seeds

    assert sorted(reference_seeds("ppo-moves")) == [11, 12, 13, 14, 15]
    agent = reference_agent("ppo-moves")
    assert agent.card.suites == ("moves",)
    assert {s for s, _, _ in agent.card.trained_on} == {"moves"}
    assert agent.firmware_modes == ("open-loop",) and agent.firmware_drives == ("current",)
    training = agent.config["training"]
    assert training["splits"] == {"motors": "train", "selection": "dev"}
    assert training["env_kwargs"]["profile"] == "move" and agent.options["agent_hz"] == 25.0
