"""What the native vector envs of every version share: N drives of one task in a
:class:`.engine.DriveBatch`, their seeds, the autoreset and a step's bookkeeping.
A version gives its task, the reward column of its outputs and its step infos."""

from __future__ import annotations

from typing import Any, Sequence

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..params import ParameterError, SystemParams
from .arguments import reseed
from .engine import DriveBatch, EnvTask

__all__ = ["DriveVectorEnv", "STEP_INFOS"]

#: The step infos both versions give: (info key, field of the task's OUT layout,
#: whether it is a flag), in this order.
STEP_INFOS = (("velocity_error_rms_rad_s", "VEL_RMS", False), ("lag_rad", "LAG", False),
              ("injected_current_rms_a", "IINJ_RMS", False),
              ("peak_current_a", "PEAK_I", False), ("step_loss", "STEP_LOSS", True),
              ("overcurrent", "OVERCURRENT", True))


class DriveVectorEnv(VectorEnv):
    """A native vector env: a subclass calls :meth:`_attach` in its constructor and
    gives :attr:`out_layout` (its task's per-step outputs) and :attr:`step_infos`."""

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}
    #: The layout of the task's per-step outputs (``compiled.OUT``, ``v1_compiled.OUT``).
    out_layout: Any
    #: The step's infos: (key, OUT field, flag), as :data:`STEP_INFOS`.
    step_infos: tuple[tuple[str, str, bool], ...] = STEP_INFOS
    #: Infos (and autoreset's final_info) exactly as ``SyncVectorEnv`` gives them
    #: (StepperDamp-v2). v0's and v1's keep their own, which their frozen
    #: fingerprints hash: the ended step's physics stay at the top level, no reset
    #: info after an autoreset, ``final_info`` an object array of dicts.
    sync_infos = False

    def _attach(self, task: EnvTask, num_envs: int, mode: AutoresetMode, threads: int,
                measure_from_s: float | None) -> DriveBatch:
        """The drives of ``task``, ``num_envs`` of them, and the spaces (after the
        arguments were checked)."""
        if measure_from_s is not None:
            raise ParameterError("measure_from_s is an option of the scalar env only; allowed "
                                 "here: None")
        self.render_mode = None
        self.metadata = {**type(self).metadata, "autoreset_mode": mode}
        self.autoreset_mode = mode
        n = self.num_envs = int(num_envs)
        self.single_observation_space = task.observation_space()
        self.single_action_space = task.action_space()
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self._drives = DriveBatch(task, n)
        self._drives.num_threads = threads
        self._autoreset = np.zeros(n, dtype=bool)
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._ready = False
        return self._drives

    @property
    def systems(self) -> list[SystemParams | None]:
        """The system of each drive's current episode."""
        return list(self._drives.systems)

    @property
    def num_threads(self) -> int:
        """numba threads each step spreads the drives over (set when built)."""
        return self._drives.num_threads

    def physics_infos(self, out: np.ndarray) -> dict[str, np.ndarray]:
        """A step's infos (each gets its ``_key`` mask) from its outputs."""
        cols = {key: out[:, getattr(self.out_layout, field)] for key, field, _ in self.step_infos}
        return {key: cols[key] != 0.0 if flag else cols[key] for key, _, flag in self.step_infos}

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
        d.load(actions, (self.num_envs, self.task.act_dim))
        terminated, truncated = d.advance()
        # One copy of the outputs; the returned arrays are views of it, never reused.
        out = d.out.copy()
        rewards = out[:, self.out_layout.REWARD]
        if self.sync_infos:
            return self._sync_step(out, rewards, terminated, truncated)
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
            obs = d.obs.copy()
            if done.any():
                final_obs = np.full(self.num_envs, None, dtype=object)
                final_info = np.full(self.num_envs, None, dtype=object)
                for i in np.flatnonzero(done):
                    final_obs[i] = obs[i].copy()
                    final_info[i] = d.info(int(i))
                    self._reset_drive(int(i))
                infos["final_obs"], infos["_final_obs"] = final_obs, done.copy()
                infos["final_info"], infos["_final_info"] = final_info, done.copy()
                obs = d.obs.copy()
        mask = valid.copy()                 # one mask for every key
        for key, value in self.physics_infos(out).items():
            infos[key] = value
            infos["_" + key] = mask
        return obs, rewards, terminated, truncated, infos

    def _sync_step(self, out: np.ndarray, rewards: np.ndarray, terminated: np.ndarray,
                   truncated: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                   np.ndarray, dict[str, Any]]:
        """The autoreset and infos of a step as ``SyncVectorEnv`` makes them
        (``VectorEnv._add_info``): each key an array over the drives with its
        ``_key`` mask, a drive that starts over giving its reset info instead of
        its step's, SAME_STEP's ``final_info`` a dict of such arrays."""
        d = self._drives
        physics = self.physics_infos(out)
        infos: dict[str, Any] = {}
        if self.autoreset_mode == AutoresetMode.NEXT_STEP:
            # Drives that ended last step start over now (their stepped rows are discarded).
            restarted = np.flatnonzero(self._autoreset)
            stepped = ~self._autoreset
            rewards[~stepped] = 0.0
            terminated &= stepped
            truncated &= stepped
            starts = [(int(i), self._reset_drive(int(i))) for i in restarted]
            self._autoreset = terminated | truncated
            _put_rows(infos, physics, stepped)
            for i, info in starts:
                infos = self._add_info(infos, info, i)
            return d.obs.copy(), rewards, terminated, truncated, infos
        done = terminated | truncated
        obs = d.obs.copy()
        _put_rows(infos, physics, ~done)
        for i in np.flatnonzero(done).tolist():
            infos = self._add_info(infos, {"final_obs": obs[i].copy(), "final_info": d.info(i)}, i)
            infos = self._add_info(infos, self._reset_drive(i), i)
        if done.any():
            obs = d.obs.copy()
        return obs, rewards, terminated, truncated, infos

    def render(self) -> None:
        return None


def _put_rows(infos: dict[str, Any], columns: dict[str, np.ndarray], rows: np.ndarray) -> None:
    """Each column as an info of the drives ``rows`` (a mask; zero elsewhere, as
    ``VectorEnv._add_info`` leaves it), with its ``_key`` mask; none if no drive."""
    if not rows.any():
        return
    for key, col in columns.items():
        infos[key] = np.where(rows, col, np.zeros((), dtype=col.dtype))
        infos["_" + key] = rows.copy()
