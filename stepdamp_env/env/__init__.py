"""Gymnasium environments of StepperDamp: ``StepperDamp-v0`` (frozen), ``StepperDamp-v1``
and ``StepperDamp-v2`` (v1 with the agents' task as defaults), scalar and native
vector each.

The agent acts as a residual on top of a base controller (the patent's harmonic
feedforward, or none) of one hybrid stepper drive simulated by
:mod:`stepdamp_env.kernel`. The PWM period, current loops and plant keep running
at ``pwm_hz`` (20 kHz for the presets) inside one agent step; the agent decides at
``agent_hz`` (1 kHz by default) and its action is held for the step.

>>> import gymnasium as gym, stepdamp_env
>>> env = gym.make("StepperDamp-v0")                        # doctest: +SKIP
>>> venv = gym.make_vec("StepperDamp-v0", num_envs=64)      # doctest: +SKIP

One engine, two tasks: :mod:`.engine` steps N drives by one compiled call
(:class:`DriveBatch`; :class:`StepperDampBatch` steps reset envs of either
version together); a version is an :class:`EnvTask` that says what an episode
is, what the agent sees, does and earns: v0's is :class:`EpisodeSampler`
(:mod:`.sampler`, with :mod:`.options`, :mod:`.layout` and the per-step numba
helpers :mod:`.compiled`), v1's is :class:`TaskV1` (:mod:`.v1`, with
:mod:`.v1_options` and :mod:`.v1_compiled`). Each version's scalar env is a
batch of one, its vector env a batch of N, so the two agree step for step.
"""

from .layout import (ACTION_NAMES, HARMONIC_COS, HARMONIC_SIN, OBS, OBSERVATION_NAMES,
                     observation_names)
from .options import (DEFAULT_RANDOMIZATION, EnvOptions, default_action_scales,
                      periods_per_agent_step)
from .registration import (DEFAULT_EPISODE_STEPS, ENV_ID, ENV_ID_V1, ENV_ID_V2, ENV_ID_V3,
                           V2_DEFAULTS, V3_DEFAULTS, register_envs)
from .sampler import EpisodeSampler
from .scalar import StepperDampEnv
from .vector import StepperDampVectorEnv
from .engine import DriveBatch, EnvTask, StepperDampBatch
from .v1 import (StepperDampV1Env, StepperDampV1VectorEnv, StepperDampV2Env,
                 StepperDampV2VectorEnv, StepperDampV3Env, StepperDampV3VectorEnv, TaskV1)
from .v1_options import (ACTION_NAMES_V1, CONTEXT_NAMES, GAIN_PHASE_LIMIT_RAD, EnvOptionsV1,
                         MotorUnits, observation_names_v1)
from .wrappers import EpisodeGuard

__all__ = ["ENV_ID", "DEFAULT_EPISODE_STEPS", "DEFAULT_RANDOMIZATION", "EnvOptions",
           "EpisodeSampler", "StepperDampEnv", "StepperDampVectorEnv", "register_envs",
           "OBS", "OBSERVATION_NAMES", "observation_names", "HARMONIC_SIN", "HARMONIC_COS",
           "ACTION_NAMES", "default_action_scales", "periods_per_agent_step", "EpisodeGuard",
           "ENV_ID_V1", "EnvOptionsV1", "MotorUnits", "TaskV1", "DriveBatch", "EnvTask", "StepperDampBatch", "StepperDampV1Env",
           "StepperDampV1VectorEnv", "ENV_ID_V2", "V2_DEFAULTS", "StepperDampV2Env",
           "StepperDampV2VectorEnv", "ENV_ID_V3", "V3_DEFAULTS", "StepperDampV3Env",
           "StepperDampV3VectorEnv", "GAIN_PHASE_LIMIT_RAD", "ACTION_NAMES_V1", "CONTEXT_NAMES",
           "observation_names_v1"]
