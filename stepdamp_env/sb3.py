"""Stable-Baselines3 adapter: the native vectorised StepperDamp env as an SB3 ``VecEnv``.

SB3 ships no adapter for Gymnasium vector environments, and its ``DummyVecEnv``
would step N scalar envs one by one. :class:`StepperDampSB3VecEnv` drives a
:class:`~stepdamp_env.env.StepperDampVectorEnv` (all drives in one compiled
call) in SAME_STEP autoreset mode, which is SB3's convention: a finished drive
is reset within the step, its last observation goes to
``infos[i]["terminal_observation"]`` and ``infos[i]["TimeLimit.truncated"]``
tells a time-out from a real end.

>>> from stable_baselines3 import PPO
>>> from stepdamp_env.sb3 import make_sb3_vec_env
>>> venv = make_sb3_vec_env(num_envs=16, action_mode="harmonic")   # doctest: +SKIP
>>> PPO("MlpPolicy", venv).learn(10_000)                           # doctest: +SKIP
"""

from __future__ import annotations

from typing import Any, Iterable, Sequence

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env.base_vec_env import (VecEnv, VecEnvIndices,
                                                           VecEnvStepReturn)

from .env import DEFAULT_EPISODE_STEPS, StepperDampV1VectorEnv, StepperDampVectorEnv

__all__ = ["StepperDampSB3VecEnv", "make_sb3_vec_env", "make_sb3_vec_env_v1"]


class StepperDampSB3VecEnv(VecEnv):
    """SB3 ``VecEnv`` view of a :class:`StepperDampVectorEnv` or
    :class:`StepperDampV1VectorEnv` (SAME_STEP autoreset).

    Args:
        venv: the native vector env; it must use ``autoreset_mode=SAME_STEP``
            (:func:`make_sb3_vec_env` builds one).
        info_keys: per-step physical quantities copied into each drive's info dict
            (e.g. ``("velocity_error_rms_rad_s",)``); empty by default because N
            dicts per step cost time.
    """

    def __init__(self, venv: StepperDampVectorEnv | StepperDampV1VectorEnv,
                 info_keys: Sequence[str] = ()) -> None:
        if not isinstance(venv, (StepperDampVectorEnv, StepperDampV1VectorEnv)):
            raise ValueError("venv must be a StepperDampVectorEnv or StepperDampV1VectorEnv, got "
                             f"{type(venv).__name__}")
        if venv.autoreset_mode != AutoresetMode.SAME_STEP:
            raise ValueError("venv must use autoreset_mode=AutoresetMode.SAME_STEP (SB3 resets "
                             f"within the step), got {venv.autoreset_mode}")
        allowed = ("velocity_error_rms_rad_s", "lag_rad", "injected_current_rms_a",
                   "peak_current_a", "step_loss", "overcurrent")
        if isinstance(venv, StepperDampV1VectorEnv):
            allowed += ("damping_current_rms_a",)
        bad = sorted(set(info_keys) - set(allowed))
        if bad:
            raise ValueError(f"info_keys: unknown key(s) {bad}; allowed: {list(allowed)}")
        self.venv = venv
        self.info_keys = tuple(info_keys)
        self._actions: np.ndarray | None = None
        super().__init__(venv.num_envs, venv.single_observation_space,
                         venv.single_action_space)
        self.render_mode = None

    def reset(self) -> np.ndarray:
        seeds = self._seeds
        seed: Any = None if all(s is None for s in seeds) else list(seeds)
        obs, _ = self.venv.reset(seed=seed)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        obs, rewards, terminated, truncated, infos = self.venv.step(self._actions)
        self._actions = None
        dones = terminated | truncated
        out_infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        # A drive that ended has its last step's info in final_info where the env
        # gives SyncVectorEnv's infos (StepperDamp-v2, SAME_STEP); v0's and v1's keep
        # it at the top level.
        final = infos.get("final_info")
        for key in self.info_keys:
            live = infos.get(key)
            ended = final.get(key) if isinstance(final, dict) else None
            for i in range(self.num_envs):
                source = ended if ended is not None and dones[i] else live
                if source is not None:
                    out_infos[i][key] = source[i]
        if dones.any():
            final_obs = infos["final_obs"]
            for i in np.flatnonzero(dones):
                out_infos[i]["terminal_observation"] = final_obs[i]
                out_infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
        return obs, rewards.astype(np.float32), dones, out_infos

    def close(self) -> None:
        self.venv.close()

    # The drives are not separate objects: attributes and methods are the vector env's.
    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        value = getattr(self.venv, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None,
                   **method_kwargs: Any) -> list[Any]:
        result = getattr(self.venv, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None
                       ) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None for _ in range(self.num_envs)]

    def _get_indices(self, indices: VecEnvIndices) -> Iterable[int]:
        return super()._get_indices(indices)


def make_sb3_vec_env(num_envs: int = 16, max_episode_steps: int | None = DEFAULT_EPISODE_STEPS,
                     info_keys: Sequence[str] = (), **options: Any) -> StepperDampSB3VecEnv:
    """A native StepperDamp vector env of ``num_envs`` drives wrapped for SB3.

    ``options`` are the environment's (see :class:`stepdamp_env.env.StepperDampEnv`).
    """
    venv = StepperDampVectorEnv(num_envs=num_envs, max_episode_steps=max_episode_steps,
                                autoreset_mode=AutoresetMode.SAME_STEP, **options)
    return StepperDampSB3VecEnv(venv, info_keys=info_keys)


def make_sb3_vec_env_v1(num_envs: int = 16, info_keys: Sequence[str] = (),
                        **options: Any) -> StepperDampSB3VecEnv:
    """A native ``StepperDamp-v1`` vector env of ``num_envs`` drives wrapped for SB3
    (its time limit is its own ``episode_s``)."""
    venv = StepperDampV1VectorEnv(num_envs=num_envs, autoreset_mode=AutoresetMode.SAME_STEP,
                                  **options)
    return StepperDampSB3VecEnv(venv, info_keys=info_keys)
