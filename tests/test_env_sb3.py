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


def test_adapter_gives_the_same_infos_over_v1_and_v2_vector_envs():
    """v2's vector env gives SyncVectorEnv's infos (the ended step's in final_info);
    the adapter's per-drive info dicts are v1's all the same."""
    from stepdamp_env.env import StepperDampV1VectorEnv, StepperDampV2VectorEnv
    from stepdamp_env.env.registration import V2_DEFAULTS

    keys = ("lag_rad", "damping_current_rms_a")
    options = {**V2_DEFAULTS, "episode_s": 0.03}
    a = StepperDampSB3VecEnv(StepperDampV1VectorEnv(3, autoreset_mode=AutoresetMode.SAME_STEP,
                                                    **options), info_keys=keys)
    b = StepperDampSB3VecEnv(StepperDampV2VectorEnv(3, autoreset_mode=AutoresetMode.SAME_STEP,
                                                    episode_s=0.03), info_keys=keys)
    a.seed(3)
    b.seed(3)
    np.testing.assert_array_equal(a.reset(), b.reset())
    for _ in range(3):                  # 3 steps of 10 ms: the episodes end on the last
        act = np.full((3, 8), 0.2, np.float32)
        (oa, ra, da, ia), (ob, rb, db, ib) = a.step(act), b.step(act)
        np.testing.assert_array_equal(oa, ob)
        assert (ra == rb).all() and (da == db).all()
        for x, y in zip(ia, ib):
            assert sorted(x) == sorted(y)
            assert all(np.array_equal(x[k], y[k]) for k in x)
    assert da.all()
