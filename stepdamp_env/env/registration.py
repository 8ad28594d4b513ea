"""Registration of the environments with Gymnasium (``gym.make``, ``gym.make_vec``)."""

from __future__ import annotations

import gymnasium as gym

__all__ = ["ENV_ID", "DEFAULT_EPISODE_STEPS", "register_envs"]

ENV_ID = "StepperDamp-v0"
# 0.3 s at the default 1 kHz: the longest default ramp (3 rev/s at 50 rev/s^2)
# takes 60 ms, which leaves at least 240 ms of held speed per episode.
DEFAULT_EPISODE_STEPS = 300


def register_envs() -> None:
    """Register ``StepperDamp-v0`` (scalar entry point and native vector entry point).

    Idempotent: a second call leaves the registry alone, so it never warns.
    """
    if ENV_ID in gym.registry:
        return
    gym.register(
        id=ENV_ID,
        entry_point="stepdamp_env.env.scalar:StepperDampEnv",
        vector_entry_point="stepdamp_env.env.vector:StepperDampVectorEnv",
        max_episode_steps=DEFAULT_EPISODE_STEPS,
    )
