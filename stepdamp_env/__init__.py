"""StepperDamp: active electronic damping of hybrid stepper motors (US 7,733,051)."""

from .params import (FeedforwardModel, DriveParams, MotorParams, ParameterError, ServoParams,
                     SystemParams, load_system, predicted_resonances)
from .presets import PRESETS, get_preset, preset_names
from .simulation import RunMetrics, RunResult, RunSettings, SpeedProfile, simulate
from .env import StepperDampEnv, StepperDampVectorEnv, register_envs

__version__ = "0.1.0"

__all__ = [
    "__version__",
    "DriveParams",
    "FeedforwardModel",
    "MotorParams",
    "ParameterError",
    "PRESETS",
    "RunMetrics",
    "RunResult",
    "RunSettings",
    "ServoParams",
    "SpeedProfile",
    "SystemParams",
    "get_preset",
    "load_system",
    "predicted_resonances",
    "preset_names",
    "simulate",
    "StepperDampEnv",
    "StepperDampVectorEnv",
    "register_envs",
]

# gym.make("StepperDamp-v0") works after `import stepdamp_env`.
register_envs()
