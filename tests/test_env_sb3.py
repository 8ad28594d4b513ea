"""StepperDamp-v0 with Stable-Baselines3: its env checker, the VecEnv adapter, PPO and SAC."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import stepdamp_env  # noqa: F401
from stepdamp_env.env import ENV_ID, StepperDampVectorEnv
from stepdamp_env.sb3 import StepperDampSB3VecEnv, make_sb3_vec_env


@pytest.mark.parametrize("kwargs", [{}, {"action_mode": "current", "privileged": True,
                                         "mode": "servo"}])
def test_sb3_check_env_passes_without_warnings(kwargs):
    env = gym.make(ENV_ID, **kwargs).unwrapped
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3_check_env(env, warn=True)


def test_adapter_follows_sb3_conventions():
    venv = make_sb3_vec_env(num_envs=3, max_episode_steps=4, speed_rps=1.0,
                            info_keys=("lag_rad",))
    venv.seed(7)
    obs = venv.reset()
    assert obs.shape == (3, 17) and obs.dtype == np.float32
    for k in range(4):
        obs, rew, dones, infos = venv.step(np.zeros((3, 6), np.float32))
        assert rew.dtype == np.float32 and len(infos) == 3 and "lag_rad" in infos[0]
    assert dones.all()
    assert all(info["TimeLimit.truncated"] for info in infos)
    assert infos[0]["terminal_observation"].shape == (17,)
    assert obs[0, 8] == 0.0                          # already reset: command at rest
    with pytest.raises(ValueError, match="SAME_STEP"):
        StepperDampSB3VecEnv(StepperDampVectorEnv(num_envs=2))
    with pytest.raises(ValueError, match="info_keys"):
        make_sb3_vec_env(num_envs=2, info_keys=("nope",))


def test_adapter_seed_reproducible():
    def first_obs(seed):
        venv = make_sb3_vec_env(num_envs=2)
        venv.seed(seed)
        return venv.reset()
    assert np.array_equal(first_obs(3), first_obs(3))
    venv = StepperDampVectorEnv(num_envs=2, autoreset_mode=AutoresetMode.SAME_STEP)
    direct, _ = venv.reset(seed=3)
    assert np.array_equal(direct, first_obs(3))


def test_ppo_trains_a_few_hundred_steps():
    venv = make_sb3_vec_env(num_envs=4, max_episode_steps=50, speed_rps=1.2)
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=1, seed=0,
                device="cpu", policy_kwargs={"net_arch": [32, 32]})
    model.learn(total_timesteps=512)
    obs = venv.reset()
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (4, 6)


def test_sac_trains_a_few_hundred_steps():
    venv = make_sb3_vec_env(num_envs=2, max_episode_steps=50, action_mode="current")
    model = SAC("MlpPolicy", venv, learning_starts=100, batch_size=32, buffer_size=1000,
                train_freq=4, seed=0, device="cpu", policy_kwargs={"net_arch": [32, 32]})
    model.learn(total_timesteps=300)
    assert model.num_timesteps >= 300
