"""The native vectorised environment: N drives stepped by one compiled call."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode

from ..params import ParameterError
from . import compiled as C
from .arguments import check_num_threads, check_vector_args
from .options import OPTIONS_DOC, EnvOptions
from .registration import DEFAULT_EPISODE_STEPS
from .sampler import EpisodeSampler
from .vector_base import DriveVectorEnv

__all__ = ["StepperDampVectorEnv"]

TWO_PI = 2.0 * np.pi


class StepperDampVectorEnv(DriveVectorEnv):
    __doc__ = """Native vectorised ``StepperDamp-v0``: N drives stepped by one ``kernel.step_batch``.

    Spaces, rewards and episode ends are those of :class:`StepperDampEnv` (see
    there for every option); the same seeds give the same episodes as N scalar
    environments reset with ``seed + i``. Episodes are truncated after
    ``max_episode_steps`` (300; ``gym.make_vec`` passes the registered value) and
    drives reset automatically: ``autoreset_mode`` NEXT_STEP (default, Gymnasium's
    convention: the step after an episode end resets that drive, its action is
    ignored, reward 0) or SAME_STEP (reset at once, the final observation and info
    in ``infos["final_obs"]``, ``infos["final_info"]``). ``infos`` holds arrays
    ``velocity_error_rms_rad_s``, ``lag_rad``, ``injected_current_rms_a``,
    ``peak_current_a``, ``step_loss``, ``overcurrent`` with ``_key`` masks.
    Rendering is not supported (``render_mode`` must be None).
    ``num_threads`` (default 1) spreads each step's drives over that many of
    numba's threads (``kernel.step_batch_parallel``); a drive's numbers are the
    same for any count.
    """ + OPTIONS_DOC

    out_layout = C.OUT

    def __init__(self, num_envs: int = 1, *, max_episode_steps: int | None = DEFAULT_EPISODE_STEPS,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 render_mode: str | None = None, num_threads: int = 1,
                 **options: Any) -> None:
        mode = check_vector_args(num_envs, autoreset_mode, render_mode)
        threads = check_num_threads(num_threads)
        if max_episode_steps is not None and (
                isinstance(max_episode_steps, bool)
                or not isinstance(max_episode_steps, (int, np.integer)) or max_episode_steps < 1):
            raise ParameterError(f"max_episode_steps={max_episode_steps!r} is outside its "
                                 "allowed range [1, inf) (integer) or None")
        self.options = EnvOptions.from_kwargs(options)
        self._sampler = EpisodeSampler(self.options)
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        drives = self._attach(self._sampler, num_envs, mode, threads, self.options.measure_from_s)
        drives.max_steps[:] = -1 if max_episode_steps is None else int(max_episode_steps)

    @property
    def task(self) -> EpisodeSampler:
        """The envs' task over the engine (:class:`.engine.EnvTask`): the episode
        sampler (nominal system, action layout and scales; read-only)."""
        return self._sampler

    sampler = task              # v0's name of it

    @property
    def speeds_rps(self) -> np.ndarray:
        """The held command speed of each drive's current episode (rev/s); a copy."""
        return self._drives.par[:, C.PARAM.W_REF] / TWO_PI

    @property
    def drive_states(self) -> np.ndarray:
        """Copy of the kernel's state rows (``kernel.STATE``; SI units), one per drive."""
        return self._drives.s.copy()
