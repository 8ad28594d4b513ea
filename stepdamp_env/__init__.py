"""StepperDamp: active electronic damping of hybrid stepper motors (US 7,733,051)."""

from .interrupts import interrupts_kept

# A Ctrl-C during these imports (the slow part of a command's start) is never lost.
with interrupts_kept():
    from . import numba_inline
    from .numba_cache import use_user_cache_dir

    # Before anything compiles: numba's on-disk cache goes to a per-user directory,
    # never into the installed package (an uninstall could not remove it); numba's
    # inliner copies a callee's blocks with one memo (compiles 3.8x faster, same code).
    use_user_cache_dir()
    numba_inline.apply()

    from .params import (FeedforwardModel, DriveParams, MotorParams, ParameterError, ServoParams,
                         SystemParams, predicted_resonances)
    from .motorfile import load_system
    from .presets import PRESETS, get_preset, preset_names
    from .simulation import RunMetrics, RunResult, RunSettings, SpeedProfile, simulate
    from .env import (StepperDampEnv, StepperDampV1Env, StepperDampV1VectorEnv,
                      StepperDampVectorEnv, register_envs)
    from .version import __version__


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
    "StepperDampV1Env",
    "StepperDampV1VectorEnv",
    "register_envs",
]

# gym.make("StepperDamp-v0") and gym.make("StepperDamp-v1") work after `import stepdamp_env`.
register_envs()
