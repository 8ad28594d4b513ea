"""Training on the motors people have (0.19.0): StepperDamp-v1's ``reward_window``,
``stepdamp train --motor-pool datasheets``, its dev selection on the pool's dev
part and its coverage."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stepdamp_env.params import ParameterError

MOVES = dict(motor="patent", randomize=True, profile="move", ramp="any", cruise_s=0.3,
             accel_range_rps2=(25.0, 312.5), agent_hz=100.0, episode_s=1.0)


def _rollout(seed, **kwargs):
    from stepdamp_env.env import StepperDampV1Env

    env = StepperDampV1Env(**kwargs)
    _, info = env.reset(seed=seed)
    rewards, ends = [], []
    for _ in range(env.task.max_episode_steps):
        _, r, term, trunc, step = env.step(np.zeros(env.action_space.shape, np.float32))
        rewards.append(r)
        ends.append(step["time_s"])
        if term or trunc:
            break
    return env, info, np.array(rewards), np.array(ends)


@pytest.mark.parametrize("seed", [3, 8])
def test_a_cruise_reward_is_the_episode_reward_inside_the_cruise_and_zero_outside(seed):
    env, info, full, ends = _rollout(seed, **MOVES)
    _, info_c, cruise, ends_c = _rollout(seed, reward_window="cruise", **MOVES)
    assert info == info_c and np.array_equal(ends, ends_c)
    profile = env.task.draws.profile(info["speed_rps"], info["ramp"], info["accel_rps2"])
    start, length = profile.cruise()
    mid = ends - 0.5 * env.task.seconds_per_step
    inside = (mid >= start) & (mid < start + length)
    assert 0 < inside.sum() < len(inside)
    assert np.array_equal(cruise[inside], full[inside])      # the same run, bit for bit
    assert np.all(cruise[~inside] == 0.0)
    # The ramps are where the whole episode's reward is largest: not what is scored.
    assert full[~inside].min() < full[inside].min()


def test_at_a_constant_speed_the_cruise_starts_at_the_end_of_the_ramp():
    kwargs = dict(motor="patent", speed_rps=2.0, accel_rps2=20.0, agent_hz=100.0, episode_s=0.3)
    _, _, full, ends = _rollout(1, **kwargs)
    _, _, cruise, _ = _rollout(1, reward_window="cruise", **kwargs)
    ramp_s = 2.0 / 20.0
    held = ends - 0.005 >= ramp_s
    assert np.array_equal(cruise[held], full[held]) and np.all(cruise[~held] == 0.0)


def test_a_bad_reward_window_is_refused_in_one_line():
    from stepdamp_env.env import StepperDampV1Env

    with pytest.raises(ParameterError, match=r"reward_window='move' is not one of "
                                             r"\['episode', 'cruise'\]") as caught:
        StepperDampV1Env(reward_window="move")
    assert "\n" not in str(caught.value)


def _args(**kwargs):
    from stepdamp_agents.settings import Args

    return Args(**{"algo": "ppo", "suite": "moves", "select_on": "dev", **kwargs})


def test_the_datasheet_pool_needs_v1_and_dev_selection():
    from stepdamp_agents.settings import check_args

    check_args(_args(motor_pool="datasheets"))
    check_args(_args(motor_pool="datasheets", select_on="validation", suite=None, eval_freq=0))
    for bad, flag in ((dict(motor_pool="datasheets", select_on="validation", suite=None),
                       "--motor-pool"), (dict(motor_pool="pool"), "--motor-pool"),
                      (dict(motor_pool="datasheets", motors=("patent",)), "--presets"),
                      (dict(pool_motors=8), "--pool-motors"),
                      (dict(pool_dev_sensors="motor-file"), "--pool-dev-sensors")):
        with pytest.raises(ParameterError) as caught:
            check_args(_args(**bad))
        assert "\n" not in str(caught.value) and flag in str(caught.value)


def test_pool_training_motors_come_from_the_train_part_by_seed():
    from stepdamp_agents.train import training_motors
    from stepdamp_env.motorpool import pool_motors

    a = training_motors(_args(motor_pool="datasheets", seed=11, pool_motors=8))
    assert a == training_motors(_args(motor_pool="datasheets", seed=11, pool_motors=8))
    assert a != training_motors(_args(motor_pool="datasheets", seed=12, pool_motors=8))
    train = {m["name"] for m in pool_motors("train")}
    assert len(a) == 8 and all(m["name"].rsplit("~", 1)[0] in train for m in a)
    assert training_motors(_args(seed=11)) == tuple(_args().motors)


def test_pool_selection_runs_v4_on_the_pools_dev_motors():
    from stepdamp_agents.selection import POOL_DEV_DRAW, DevValidator
    from stepdamp_env.motorpool import pool_motors

    v = DevValidator("moves", motor_pool="datasheets")
    assert v.version == "v4" and v.protocol.splits == ("custom",)
    dev = {m["name"] for m in pool_motors("dev")}
    names = [s.name for s in v.protocol.custom_motors]
    assert len(names) == POOL_DEV_DRAW["count"] == 12
    assert all(n.rsplit("~", 1)[0] in dev for n in names)
    # Without the pool: v3's dev split where v3 has the suite, as before.
    assert DevValidator("open-loop").version == "v3"
    assert DevValidator("open-loop", motor_pool="datasheets").version == "v4"
    unrelated = {m["name"] for m in pool_motors("dev", "datasheets-unrelated")}
    names = [s.name for s in DevValidator("mid-band", "datasheets-unrelated")
             .protocol.custom_motors]
    assert len(names) == 12 and all(n.rsplit("~", 1)[0] in unrelated for n in names)
    with pytest.raises(ParameterError, match=r"^motor_pool='pool' is not one of \['presets', "
                                             r"'datasheets', 'datasheets-unrelated'\]$"):
        DevValidator("mid-band", "pool")


def test_pool_dev_motors_have_the_boards_sensors_unless_told_otherwise():
    # The dev check once ran the pool's dev motors without current noise while a
    # board on the same motors (--motors) and the scored catalogue have the
    # protocol's 0.01 A: 27.4 dB at a check, 22.7 on the board.
    from stepdamp_agents.selection import DevValidator
    from stepdamp_env.bench.protocols import protocol_for

    v4 = protocol_for("v4")
    assert v4.current_noise_a > 0.0
    board = DevValidator("open-loop", "datasheets-unrelated").protocol.custom_motors
    old = DevValidator("open-loop", "datasheets-unrelated", "motor-file").protocol.custom_motors
    assert all(s.to_dict()["current_noise_a"] == v4.current_noise_a
               and s.to_dict()["encoder_cpr"] == v4.encoder_cpr for s in board)
    assert all(s.to_dict()["current_noise_a"] == 0.0 for s in old)
    assert [s.name for s in board] == [s.name for s in old]
    with pytest.raises(ParameterError, match=r"^pool_dev_sensors='clean' is not one of "
                                             r"\['protocol', 'motor-file'\]$"):
        DevValidator("open-loop", "datasheets-unrelated", "clean")


def test_coverage_of_pool_training_is_each_motors_resonances():
    from stepdamp_agents.policy import training_coverage
    from stepdamp_env.motorfile import load_system
    from stepdamp_env.motorpool import draw_datasheets

    motors = list(draw_datasheets(4, 3))
    kwargs = {"mode": "open-loop", "profile": "move", "resonance_prob": 0.75,
              "speed_range_rps": (0.25, 0.3), "resonance_spread": 0.1}
    cover = training_coverage({"training": {"env_kwargs": kwargs, "motors": motors}})
    assert cover and {s for s, _, _ in cover} == {"moves"}
    for m in motors:
        for f in load_system(m).predicted_resonances_rps().values():
            assert any(lo <= f <= hi for _, lo, hi in cover)
    lows = [lo for _, lo, _ in cover]
    assert math.isclose(min(lows), 0.25)


def test_committed_pool_models_saw_only_the_pools_train_part():
    import glob
    import json
    import os

    from stepdamp_agents import REFERENCE_DIR
    from stepdamp_env.motorpool import pool_motors

    found = 0
    for path in sorted(glob.glob(os.path.join(REFERENCE_DIR, "*.agent.json"))):
        with open(path, encoding="utf-8") as fh:
            training = json.load(fh)["training"]
        if training.get("motor_pool", "presets") == "presets":
            continue
        found += 1
        train = {m["name"] for m in pool_motors("train", training["motor_pool"])}
        assert training["splits"] == {"motors": "pool-train", "selection": "pool-dev"}, path
        assert all(m["name"].rsplit("~", 1)[0] in train for m in training["motors"]), path
    assert found >= 5
