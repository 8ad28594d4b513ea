"""Gymnasium environments of StepperDamp: ``StepperDamp-v0`` (frozen) and ``StepperDamp-v1``
(scalar and native vector each).

The agent acts as a residual on top of a base controller (the patent's harmonic
feedforward, or none) of one hybrid stepper drive simulated by
:mod:`stepdamp_env.kernel`. The PWM period, current loops and plant keep running
at ``pwm_hz`` (20 kHz for the presets) inside one agent step; the agent decides at
``agent_hz`` (1 kHz by default) and its action is held for the step.

>>> import gymnasium as gym, stepdamp_env
>>> env = gym.make("StepperDamp-v0")                        # doctest: +SKIP
>>> venv = gym.make_vec("StepperDamp-v0", num_envs=64)      # doctest: +SKIP

Modules: :mod:`.options` (validated options and their defaults), :mod:`.layout`
(named observation and action entries), :mod:`.sampler` (episode draws, a
read-only view for policies), :mod:`.compiled` (the per-step numba helpers),
:mod:`.scalar`, :mod:`.vector` (:class:`StepperDampVectorEnv` advances all its
drives with one call of :func:`stepdamp_env.kernel.run_batch` and agrees with
the scalar env step for step), :mod:`.registration`.
"""

from .layout import (ACTION_NAMES, HARMONIC_COS, HARMONIC_SIN, OBS, OBSERVATION_NAMES,
                     observation_names)
from .options import DEFAULT_RANDOMIZATION, EnvOptions, default_action_scales
from .registration import DEFAULT_EPISODE_STEPS, ENV_ID, ENV_ID_V1, register_envs
from .sampler import EpisodeSampler
from .scalar import StepperDampEnv
from .vector import StepperDampVectorEnv
from .v1 import DriveBatch, StepperDampV1Env, StepperDampV1VectorEnv, TaskV1
from .v1_options import (ACTION_NAMES_V1, CONTEXT_NAMES, EnvOptionsV1, MotorUnits,
                         observation_names_v1)
from .wrappers import EpisodeGuard

__all__ = ["ENV_ID", "DEFAULT_EPISODE_STEPS", "DEFAULT_RANDOMIZATION", "EnvOptions",
           "EpisodeSampler", "StepperDampEnv", "StepperDampVectorEnv", "register_envs",
           "OBS", "OBSERVATION_NAMES", "observation_names", "HARMONIC_SIN", "HARMONIC_COS",
           "ACTION_NAMES", "default_action_scales", "EpisodeGuard",
           "ENV_ID_V1", "EnvOptionsV1", "MotorUnits", "TaskV1", "DriveBatch", "StepperDampV1Env",
           "StepperDampV1VectorEnv", "ACTION_NAMES_V1", "CONTEXT_NAMES", "observation_names_v1"]
