"""The native vectorised environment: N drives stepped by one compiled call."""

from __future__ import annotations

from typing import Any, Sequence

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..params import ParameterError, SystemParams
from . import compiled as C
from .arguments import check_num_threads, check_vector_args, reseed
from .engine import DriveBatch
from .options import OPTIONS_DOC, EnvOptions
from .registration import DEFAULT_EPISODE_STEPS
from .sampler import EpisodeSampler

__all__ = ["StepperDampVectorEnv"]

TWO_PI = 2.0 * np.pi


class StepperDampVectorEnv(VectorEnv):
    __doc__ = """Native vectorised ``StepperDamp-v0``: N drives stepped by one ``kernel.run_batch``.

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
    numba's threads (``kernel.run_batch_parallel``); a drive's numbers are the
    same for any count.
    """ + OPTIONS_DOC

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

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
        self.render_mode = None
        self.metadata = {**type(self).metadata, "autoreset_mode": mode}
        self.autoreset_mode = mode
        self.options = EnvOptions.from_kwargs(options)
        if self.options.measure_from_s is not None:
            raise ParameterError("measure_from_s is an option of the scalar env only; allowed "
                                 "here: None")
        self._sampler = f = EpisodeSampler(self.options)
        n = self.num_envs = int(num_envs)
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self.single_observation_space = f.observation_space()
        self.single_action_space = f.action_space()
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self._act_shape = (n, f.act_dim)
        self._drives = DriveBatch(f, n)
        self._drives.num_threads = threads
        self._drives.max_steps[:] = -1 if max_episode_steps is None else int(max_episode_steps)
        self._autoreset = np.zeros(n, dtype=bool)
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._ready = False

    @property
    def sampler(self) -> EpisodeSampler:
        """The episode sampler: nominal system, action layout and scales (read-only)."""
        return self._sampler

    @property
    def task(self) -> EpisodeSampler:
        """The envs' task over the engine (:class:`.engine.EnvTask`): its sampler."""
        return self._sampler

    @property
    def systems(self) -> list[SystemParams | None]:
        """The system of each drive's current episode."""
        return list(self._drives.systems)

    @property
    def num_threads(self) -> int:
        """numba threads each step spreads the drives over (set when built)."""
        return self._drives.num_threads

    @property
    def speeds_rps(self) -> np.ndarray:
        """The held command speed of each drive's current episode (rev/s); a copy."""
        return self._drives.par[:, C.PARAM.W_REF] / TWO_PI

    @property
    def drive_states(self) -> np.ndarray:
        """Copy of the kernel's state rows (``kernel.STATE``; SI units), one per drive."""
        return self._drives.s.copy()

    def _reset_drive(self, i: int) -> dict[str, Any]:
        if self._rngs[i] is None:
            self._rngs[i], _ = seeding.np_random(None)
        return self._drives.reset_drive(i, self._rngs[i])

    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        n = self.num_envs
        mask = reseed(self._rngs, seed, options, first=not self._ready)
        speeds = np.zeros(n)
        harm = np.zeros(n, dtype=np.int64)
        for i in np.flatnonzero(mask):
            info = self._reset_drive(int(i))
            speeds[i], harm[i] = info["speed_rps"], info["target_harmonic"]
        self._autoreset[mask] = False
        self._ready = True
        return self._drives.obs.copy(), {"speed_rps": speeds, "_speed_rps": mask.copy(),
                                         "target_harmonic": harm, "_target_harmonic": mask.copy()}

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                          dict[str, Any]]:
        if not self._ready:
            raise gym.error.ResetNeeded("call reset() before step()")
        d = self._drives
        d.load(actions, self._act_shape)
        terminated, truncated = d.advance()
        # One copy of the outputs; the returned arrays are views of it, never reused.
        out = d.out.copy()
        rewards = out[:, C.OUT.REWARD]
        valid = np.ones(self.num_envs, dtype=bool)
        infos: dict[str, Any] = {}
        if self.autoreset_mode == AutoresetMode.NEXT_STEP:
            if self._autoreset.any():
                # These drives ended last step: they start over now (their stepped
                # rows above are discarded).
                valid = ~self._autoreset
                for i in np.flatnonzero(self._autoreset):
                    self._reset_drive(int(i))
                rewards[~valid] = 0.0
                terminated &= valid
                truncated &= valid
            self._autoreset = terminated | truncated
            obs = d.obs.copy()
        else:
            done = terminated | truncated
            obs_now = d.obs.copy()
            if done.any():
                idx = np.flatnonzero(done)
                final_obs = np.full(self.num_envs, None, dtype=object)
                final_info = np.full(self.num_envs, None, dtype=object)
                for i in idx:
                    final_obs[i] = obs_now[i].copy()
                    final_info[i] = d.info(int(i))
                    self._reset_drive(int(i))
                infos["final_obs"], infos["_final_obs"] = final_obs, done.copy()
                infos["final_info"], infos["_final_info"] = final_info, done.copy()
                obs = d.obs.copy()
            else:
                obs = obs_now
        mask = valid.copy()
        infos["velocity_error_rms_rad_s"] = out[:, C.OUT.VEL_RMS]
        infos["_velocity_error_rms_rad_s"] = mask
        infos["lag_rad"] = out[:, C.OUT.LAG]
        infos["_lag_rad"] = mask
        infos["injected_current_rms_a"] = out[:, C.OUT.IINJ_RMS]
        infos["_injected_current_rms_a"] = mask
        infos["peak_current_a"] = out[:, C.OUT.PEAK_I]
        infos["_peak_current_a"] = mask
        infos["step_loss"] = out[:, C.OUT.STEP_LOSS] != 0.0
        infos["_step_loss"] = mask
        infos["overcurrent"] = out[:, C.OUT.OVERCURRENT] != 0.0
        infos["_overcurrent"] = mask
        return obs, rewards, terminated, truncated, infos

    def render(self) -> None:
        return None
