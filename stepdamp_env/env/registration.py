"""Registration of the environments with Gymnasium (``gym.make``, ``gym.make_vec``)."""

from __future__ import annotations

import gymnasium as gym

__all__ = ["ENV_ID", "ENV_ID_V1", "DEFAULT_EPISODE_STEPS", "register_envs"]

ENV_ID = "StepperDamp-v0"
ENV_ID_V1 = "StepperDamp-v1"
# 0.3 s at the default 1 kHz: the longest default ramp (3 rev/s at 50 rev/s^2)
# takes 60 ms, which leaves at least 240 ms of held speed per episode.
DEFAULT_EPISODE_STEPS = 300


def register_envs() -> None:
    """Register ``StepperDamp-v0`` and ``StepperDamp-v1`` (scalar entry point and
    native vector entry point).

    Idempotent: a second call leaves the registry alone, so it never warns.
    v1 owns its time limit (``episode_s``), so its spec has none.
    """
    if ENV_ID_V1 not in gym.registry:
        gym.register(id=ENV_ID_V1, entry_point="stepdamp_env.env.v1:StepperDampV1Env",
                     vector_entry_point="stepdamp_env.env.v1:StepperDampV1VectorEnv")
    if ENV_ID in gym.registry:
        return
    gym.register(
        id=ENV_ID,
        entry_point="stepdamp_env.env.scalar:StepperDampEnv",
        vector_entry_point="stepdamp_env.env.vector:StepperDampVectorEnv",
        max_episode_steps=DEFAULT_EPISODE_STEPS,
    )
