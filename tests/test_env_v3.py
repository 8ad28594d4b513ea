"""StepperDamp-v3: v2's task with the "gain-phase" action, whose box lost no steps on the tested draws."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import stepdamp_env  # noqa: F401  (registers the envs)
from stepdamp_env import fixedmath as fm
from stepdamp_env.env import (GAIN_PHASE_LIMIT_RAD, V3_DEFAULTS, StepperDampV1Env,
                              StepperDampV2Env, StepperDampV3Env, StepperDampV3VectorEnv)

MOTOR_FILE = "docs/motors/17hs4401.json"    # a catalogue motor of the docs, not a scored one
EPISODE_SEEDS = range(500_000, 500_032)     # training seeds


def _rewards(env: gym.Env, seed: int, actions) -> list[float]:
    env.reset(seed=seed)
    out = []
    for a in actions:
        _, r, term, trunc, _ = env.step(a)
        out.append(r)
        if term or trunc:
            break
    return out


def test_v3_is_registered_passes_the_checkers_and_warns_on_the_benchmarks_seeds():
    env = gym.make("StepperDamp-v3")
    assert isinstance(env.unwrapped, StepperDampV3Env)
    assert env.action_space.shape == (2,) and env.observation_space.shape == (30,)
    assert env.unwrapped.task.action_names == ("gain", "phase")
    assert isinstance(gym.make_vec("StepperDamp-v3", num_envs=2,
                                   vectorization_mode="vector_entry_point"), StepperDampV3VectorEnv)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(gym.make("StepperDamp-v3").unwrapped)
        sb3_check_env(StepperDampV3Env(), warn=True)
    with pytest.warns(UserWarning, match="StepperDamp-v3 reset with seed 1000000"):
        StepperDampV3Env().reset(seed=1_000_000)


def test_v3_is_v2_with_the_gain_phase_action():
    assert gym.make("StepperDamp-v3").unwrapped.options == \
        StepperDampV1Env(**V3_DEFAULTS).options
    assert StepperDampV3Env().options == StepperDampV2Env(action_mode="gain-phase").options
    assert StepperDampV3Env(agent_hz=50.0).options.history == 4


@pytest.mark.parametrize("gain, phase", [(1.0, 0.5), (0.3, -1.0), (0.7, 1.0)])
def test_gain_phase_is_the_damping_gains_pair_of_that_gain_and_phase(gain, phase):
    """kv = g*cos(phi), kp = -g*sin(phi): the same rewards, bit for bit, as v2 given
    that pair with its resonant gains at zero."""
    s, c = fm.sincos(phase * GAIN_PHASE_LIMIT_RAD)
    pair = np.zeros(8)
    pair[0], pair[1] = gain * c, -gain * s
    v3 = _rewards(StepperDampV3Env(), 7, [np.array([gain, phase])] * 30)
    v2 = _rewards(StepperDampV2Env(), 7, [pair] * 30)
    assert v3 == v2 and len(v3) == 30
    assert abs(s - math.sin(phase * math.pi / 4)) < 1e-15


def test_zero_and_negative_gains_are_the_base_controller():
    base = _rewards(StepperDampV2Env(), 3, [np.zeros(8)] * 40)
    assert _rewards(StepperDampV3Env(), 3, [np.zeros(2)] * 40) == base
    assert _rewards(StepperDampV3Env(), 3, [np.array([-0.8, 0.4])] * 40) == base


@pytest.mark.parametrize("bad", [[1.01, 0.0], [0.0, -1.5], [math.nan, 0.0], [0.5]])
def test_a_bad_action_is_one_line_naming_the_range(bad):
    env = StepperDampV3Env()
    env.reset(seed=1)
    with pytest.raises(ValueError, match=r"action must be finite with shape \(2,\).*\[-1, 1\]"):
        env.step(np.array(bad))


def _episodes(kwargs: dict, policy, n: int = len(EPISODE_SEEDS)) -> tuple[np.ndarray, int]:
    """Returns and the count of terminated episodes under ``policy(rng) -> (n, k)``."""
    env = gym.make_vec(kwargs.pop("env_id", "StepperDamp-v3"), num_envs=n,
                       vectorization_mode="vector_entry_point", **kwargs)
    env.reset(seed=list(EPISODE_SEEDS)[:n])
    rng = np.random.default_rng(0)
    total, done, ended = np.zeros(n), np.zeros(n, bool), np.zeros(n, bool)
    while not done.all():
        _, r, term, trunc, _ = env.step(policy(rng))
        total += np.where(done, 0.0, r)
        ended |= term & ~done
        done |= term | trunc
    return total, int(ended.sum())


@pytest.mark.slow
@pytest.mark.parametrize("motor", [None, MOTOR_FILE])
def test_no_action_in_the_box_loses_steps(motor):
    """The corners held and random bang-bang switching between them never end an
    episode (step loss or over-current), on motors drawn around the presets and
    around a datasheet motor; a moderate lead (0.5, 0.5) beats the base controller."""
    n = len(EPISODE_SEEDS)
    kwargs = {} if motor is None else {"motor": motor}
    base, _ = _episodes(dict(kwargs), lambda rng: np.zeros((n, 2)))
    for corner in ([1.0, 1.0], [1.0, -1.0], [1.0, 0.0], [0.5, 0.5]):
        total, ended = _episodes(dict(kwargs), lambda rng, c=corner: np.tile(c, (n, 1)))
        assert ended == 0, corner
    total, ended = _episodes(dict(kwargs), lambda rng: rng.choice([-1.0, 1.0], (n, 2)))
    assert ended == 0
    total, ended = _episodes(dict(kwargs), lambda rng: np.tile([0.5, 0.5], (n, 1)))
    assert total.mean() > base.mean() + 2.0


@pytest.mark.slow
def test_the_phase_limit_is_what_keeps_the_box_safe():
    """The same gain with a lead of pi/2 (outside v3's box, as v2's damping-gains
    pair kv = 0, kp = -0.75) loses steps on some of the same episodes."""
    n = len(EPISODE_SEEDS)
    pair = np.zeros((n, 8))
    pair[:, 1] = -0.75
    _, ended = _episodes({"env_id": "StepperDamp-v2"}, lambda rng: pair)
    assert ended > 0
