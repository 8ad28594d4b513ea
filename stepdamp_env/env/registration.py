"""Registration of the environments with Gymnasium (``gym.make``, ``gym.make_vec``)."""

from __future__ import annotations

import importlib.metadata

import gymnasium as gym

__all__ = ["ENV_ID", "ENV_ID_V1", "ENV_ID_V2", "ENV_ID_V3", "V2_DEFAULTS", "V3_DEFAULTS", "RESERVED_SEEDS_FROM",
           "DEFAULT_EPISODE_STEPS",
           "ENTRY_POINT_GROUP", "register_envs"]

ENV_ID = "StepperDamp-v0"
ENV_ID_V1 = "StepperDamp-v1"
ENV_ID_V2 = "StepperDamp-v2"
ENV_ID_V3 = "StepperDamp-v3"
#: ``StepperDamp-v2``: v1's env with the defaults of the task the committed per-step
#: agents learn (``stepdamp_agents.task.REFERENCE_TASK``): motors drawn around the
#: presets, resonant speeds with probability 0.75, the damping law's gains set every
#: 10 ms (100 Hz) with four past errors and the visible context, the exact detent
#: model in the feedforward, the protocol's sensors, 1 s episodes (100 steps).
V2_DEFAULTS: dict = {
    "randomize": True, "mode": "open-loop", "base_controller": "ff-delay-comp",
    "estimate": "exact", "action_mode": "damping-gains", "agent_hz": 100.0, "history": 4,
    "context": "visible", "resonance_prob": 0.75, "episode_s": 1.0,
    "overrides": {"current_noise_a": 0.01, "encoder_cpr": 4000},
}
#: ``StepperDamp-v3``: v2's task with the action "gain-phase" (the damping law's
#: velocity-feedback gain and phase, two numbers): no action of its box lost steps
#: on the tested draws (tests/test_env_v3.py), so library-default exploration
#: does not end episodes there.
V3_DEFAULTS: dict = {**V2_DEFAULTS, "action_mode": "gain-phase"}
#: Seeds from here on draw the motors and noise the stepdamp-bench protocols score
#: (``bench.protocol.TRAINING_SEED_LIMIT`` is this value): StepperDamp-v2 warns when
#: reset with one (rl-baselines3-zoo picks such seeds when given no ``--seed``).
RESERVED_SEEDS_FROM = 1_000_000
#: Installed packages name further env ids here (name: the id, value: its entry
#: point), e.g. the agents' ``StepperDampResidual-v0``; registered without importing them.
ENTRY_POINT_GROUP = "stepdamp.envs"
# 0.3 s at the default 1 kHz: the longest default ramp (3 rev/s at 50 rev/s^2)
# takes 60 ms, which leaves at least 240 ms of held speed per episode.
DEFAULT_EPISODE_STEPS = 300


def register_envs() -> None:
    """Register ``StepperDamp-v0`` to ``StepperDamp-v3`` (scalar
    entry point and native vector entry point), and the ids installed packages
    name in the entry-point group :data:`ENTRY_POINT_GROUP`.

    Idempotent: a second call leaves the registry alone, so it never warns.
    v1 owns its time limit (``episode_s``), so its spec has none.
    """
    if ENV_ID_V1 not in gym.registry:
        gym.register(id=ENV_ID_V1, entry_point="stepdamp_env.env.v1:StepperDampV1Env",
                     vector_entry_point="stepdamp_env.env.v1:StepperDampV1VectorEnv")
    for env_id, name in ((ENV_ID_V2, "StepperDampV2"), (ENV_ID_V3, "StepperDampV3")):
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=f"stepdamp_env.env.v1:{name}Env",
                         vector_entry_point=f"stepdamp_env.env.v1:{name}VectorEnv")
    for point in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        if point.name not in gym.registry:
            gym.register(id=point.name, entry_point=point.value)
    if ENV_ID in gym.registry:
        return
    gym.register(
        id=ENV_ID,
        entry_point="stepdamp_env.env.scalar:StepperDampEnv",
        vector_entry_point="stepdamp_env.env.vector:StepperDampVectorEnv",
        max_episode_steps=DEFAULT_EPISODE_STEPS,
    )
