"""Compatibility module: the environments live in :mod:`stepdamp_env.env`.

``stepdamp_env.envs:StepperDampEnv`` and ``:StepperDampVectorEnv`` were the
registered entry points of ``StepperDamp-v0`` before 0.2; they keep working.
"""

from .env import (DEFAULT_EPISODE_STEPS, DEFAULT_RANDOMIZATION, ENV_ID, EnvOptions,
                  StepperDampEnv, StepperDampVectorEnv, register_envs)
from .env.compiled import (MAX_ACT_DIM, N_BASE_OBS, N_OUT, N_PAR, N_PRIVILEGED, O_IINJ_RMS, O_LAG, O_NONFINITE, O_OVERCURRENT,
                           O_PEAK_I, O_REWARD, O_STEP_LOSS, O_TERMINATED, O_VEL_RMS,
                           OBS_BOUND, P_ACT_SCALE, P_CUR_PEN, P_FULL_STEP, P_HOLD, P_I_LIMIT,
                           P_SPEED_SCALE, P_TERM_PEN, P_W_REF)

__all__ = ["ENV_ID", "DEFAULT_EPISODE_STEPS", "DEFAULT_RANDOMIZATION", "EnvOptions",
           "StepperDampEnv", "StepperDampVectorEnv", "register_envs", "OBS_BOUND", "N_OUT",
           "MAX_ACT_DIM", "N_BASE_OBS", "N_PRIVILEGED",
           "N_PAR", "O_IINJ_RMS", "O_LAG", "O_NONFINITE", "O_OVERCURRENT", "O_PEAK_I",
           "O_REWARD", "O_STEP_LOSS", "O_TERMINATED", "O_VEL_RMS", "P_ACT_SCALE", "P_CUR_PEN",
           "P_FULL_STEP", "P_HOLD", "P_I_LIMIT", "P_SPEED_SCALE", "P_TERM_PEN", "P_W_REF"]
