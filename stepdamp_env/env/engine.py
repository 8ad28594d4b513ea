"""The one stepping engine of the environments: N drives and one task.

An env version is a task (:class:`EnvTask`): what an episode is (motor, speed,
the drive's configuration), what the agent sees (observation), does (how an
action enters the drive) and earns (reward, termination). ``StepperDamp-v0``'s
task is :class:`.sampler.EpisodeSampler`, ``StepperDamp-v1``'s
:class:`.v1.TaskV1`. :class:`DriveBatch` holds the rows of N drives (the
kernel's configuration, state, sums, inputs and damping law; the task's
per-episode constants, observation and outputs) and steps them by one compiled
call; each version's scalar env is a batch of one, its vector env a batch of N,
and :class:`StepperDampBatch` steps reset envs of either version together (the
leaderboard's runner). Every row is stepped alone by the kernel, so a row gives
the same bits in any batch.
"""

from __future__ import annotations

import abc
import math
import os
from types import SimpleNamespace
from typing import Any, Callable, Sequence

import gymnasium as gym
import numba
import numpy as np
from gymnasium.utils import seeding

from .. import kernel as K
from .. import lanes
from ..params import ParameterError, SystemParams
from ..simulation import (RunMetrics, merge_accumulator_rows, metrics_from_accumulators,
                          new_accumulators)
from .actions import action_error, as_action
from .arguments import check_batch_envs

__all__ = ["EnvTask", "DriveBatch", "OneDriveEnv", "StepperDampBatch", "slip_cycles", "batch_step"]


class EnvTask(abc.ABC):
    """An env version over :class:`DriveBatch`. Attributes every task sets:
    ``n_periods`` (PWM periods per agent step), ``seconds_per_step``, ``act_dim``,
    ``obs_dim``, ``input_offset`` (where an action's entries go in the kernel's
    inputs, or in the law's gains when ``law_actions``), ``max_episode_steps``
    (None: no limit of the task's own), ``param_size`` and ``out_layout`` (the
    task's per-episode row and per-step outputs, :mod:`stepdamp_env.fields`
    layouts with ``REWARD``, ``TERMINATED``, ``STEP_LOSS``, ``OVERCURRENT``) and
    ``extra_rows`` (name -> (width, dtype) of any other per-drive rows), and
    ``options`` (the env's checked options, with ``measure_from_s``)."""

    options: Any
    n_periods: int
    seconds_per_step: float
    act_dim: int
    obs_dim: int
    input_offset: int
    law_actions: bool
    max_episode_steps: int | None
    param_size: int
    out_layout: Any
    extra_rows: dict[str, tuple[int, Any]]

    @abc.abstractmethod
    def new_episode(self, rng: np.random.Generator, drives: "DriveBatch", i: int
                    ) -> tuple[dict[str, Any], SystemParams]:
        """Draw an episode into drive i's rows; returns (reset info, system)."""

    @abc.abstractmethod
    def observe(self, drives: "DriveBatch", rows: slice | None) -> None:
        """The rows' (all for None) observations into ``drives.obs``, their step's
        physics and reward into ``drives.out`` (``drives.view(rows)``)."""

    @abc.abstractmethod
    def load(self, drives: "DriveBatch", a: np.ndarray) -> int:
        """Scale the actions ``a`` (n, act_dim) into the drives' inputs and zero
        their step sums; the first bad row (nothing changed then), or -1."""

    def end_of_step(self, drives: "DriveBatch", terminated: np.ndarray,
                    left: np.ndarray) -> None:
        """Adjust ``drives.out`` when drives terminated this step (``terminated``: the
        mask, not all False; ``left``: steps each drive had still to play, for a
        task with a limit). Default: nothing."""

    @abc.abstractmethod
    def step_info(self, drives: "DriveBatch", i: int) -> dict[str, Any]:
        """The physics of drive i's last step (SI units)."""

    def time_s(self, drives: "DriveBatch") -> np.ndarray:
        """Each drive's simulated time in its episode (s). Default: its steps times
        ``seconds_per_step``."""
        return drives.t * self.seconds_per_step

    def layout(self) -> tuple:
        """What drives stepped together must share (equal tuples: one batch)."""
        return (type(self), self.n_periods, self.seconds_per_step, self.law_actions,
                self.input_offset, self.act_dim, self.obs_dim,
                tuple(sorted((k, w) for k, (w, _) in self.extra_rows.items())))


class _ForkState:
    """GNU OpenMP (numba's ``omp`` threading layer) cannot run in a child forked
    after its parent ran it: such a child steps serially (the same bits)."""

    parallel_used = False
    after_parallel = False

    @classmethod
    def child(cls) -> None:
        cls.after_parallel = cls.after_parallel or cls.parallel_used


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_ForkState.child)


def batch_step(simd: bool, parallel: bool) -> Callable[..., Any]:
    """The compiled step of a batch of drives, ``step(configs, states, accs, inputs,
    laws, n_periods)`` (``laws`` None or LAW rows): the kernel's loop
    (:func:`.kernel.step_batch`) or SIMD lanes (:func:`.lanes.step_lanes`), serial or
    on numba's threads. Looked up at each call (a benchmark may wrap one)."""
    return {(False, False): K.step_batch, (False, True): K.step_batch_parallel,
            (True, False): lanes.step_lanes, (True, True): lanes.step_lanes_parallel}[
        (bool(simd), bool(parallel))]


class DriveBatch:
    """N drives of one task: their rows, their resets, their steps."""

    _ROWS = ("c", "s", "acc", "u", "law", "par", "obs", "out", "a", "t", "speeds_rps",
             "max_steps")
    #: numba threads a step spreads the drives over (1: the serial loop); at most
    #: numba's thread count where it steps (an unpickled env may meet fewer).
    num_threads = 1
    #: step the drives in SIMD lanes (:mod:`stepdamp_env.lanes`): the same bits.
    simd = False

    def __init__(self, task: EnvTask, n: int) -> None:
        self.task = task
        self.n = n
        self.c = np.zeros((n, len(K.CONFIG)))
        self.s = np.zeros((n, len(K.STATE)))
        self.acc = np.zeros((n, len(K.ACC)))
        self.u = np.zeros((n, len(K.INPUT)))
        self.law = np.zeros((n, len(K.LAW)))
        self.par = np.zeros((n, task.param_size))
        self.obs = np.zeros((n, task.obs_dim), dtype=np.float32)
        self.out = np.zeros((n, len(task.out_layout)))
        self.a = np.zeros((n, task.act_dim))
        self.t = np.zeros(n, dtype=np.int64)
        self.speeds_rps = np.zeros(n)
        self.systems: list[SystemParams | None] = [None] * n
        # Each drive's episode length in steps (a batch of several envs' drives
        # holds each env's own; -1: none).
        limit = task.max_episode_steps
        self.max_steps = np.full(n, -1 if limit is None else limit, dtype=np.int64)
        self.extra = {k: np.zeros((n, w), dtype=dt) for k, (w, dt) in task.extra_rows.items()}

    def view(self, rows: slice | None) -> Any:
        """The drives' rows (all for None) as views, by the batch's attribute names
        (``c``, ``s``, ``acc``, ``u``, ``law``, ``par``, ``obs``, ``out``, ``a``,
        ``t``, ``extra``)."""
        if rows is None:
            return self
        return SimpleNamespace(extra={k: v[rows] for k, v in self.extra.items()},
                               **{k: getattr(self, k)[rows] for k in self._ROWS})

    @classmethod
    def stack(cls, batches: Sequence["DriveBatch"], rows: Sequence[int] | None = None
              ) -> "DriveBatch":
        """One batch of the drives of ``batches`` (which share the first one's
        layout), or of the ``rows`` of a single batch; arrays are copied."""
        first = batches[0]
        if rows is not None:
            idx = np.asarray(rows, dtype=np.int64)
            arrays = {k: getattr(first, k)[idx] for k in cls._ROWS}
            extra = {k: v[idx] for k, v in first.extra.items()}
            systems = [first.systems[i] for i in rows]
        else:
            arrays = {k: np.concatenate([getattr(b, k) for b in batches]) for k in cls._ROWS}
            extra = {k: np.concatenate([b.extra[k] for b in batches]) for k in first.extra}
            systems = [sys_ for b in batches for sys_ in b.systems]
        out = cls(first.task, len(systems))
        for k, v in arrays.items():
            setattr(out, k, v)
        out.extra = extra
        out.systems = systems
        return out

    def reset_drive(self, i: int, rng: np.random.Generator, task: EnvTask | None = None
                    ) -> dict[str, Any]:
        """A new episode of drive i: drawn by the task (``task``: another of the
        batch's layout, e.g. of another motor or speed), observed once."""
        for rows in self.extra.values():
            rows[i] = 0.0
        info, self.systems[i] = (task or self.task).new_episode(rng, self, i)
        self.u[i] = 0.0
        self.a[i] = 0.0
        self.t[i] = 0
        self.speeds_rps[i] = info["speed_rps"]
        self.acc[i] = 0.0
        self.acc[i, K.ACC.COUNT_ALL] = 1.0
        self.task.observe(self, slice(i, i + 1))
        return info

    def load(self, actions: Any, shape: tuple[int, ...]) -> None:
        """Check the actions (of ``shape``: (n, k), or (k,) for one drive) and let
        the task put them into the drives."""
        a = as_action(actions, shape).reshape(self.n, self.task.act_dim)
        if self.task.load(self, a) >= 0:
            raise action_error(actions, shape)
        self.a[:] = a

    def _step_drives(self, trace: np.ndarray | None) -> None:
        """The kernel's step of every drive, then the task's observation. ``trace``
        (one drive only) gets its PWM periods, one row each."""
        n = self.task.n_periods
        # Without gain actions the law stays off: the kernel's plain loop.
        if trace is not None and len(trace):
            if self.task.law_actions:
                K.run_periods_law(self.c[0], self.s[0], self.acc[0], self.u[0], self.law[0], n,
                                  trace, 1)
            else:
                K.run_periods(self.c[0], self.s[0], self.acc[0], self.u[0], n, trace, 1)
        elif (self.num_threads > 1 and self.n > (lanes.LANES if self.simd else 1)
              and not _ForkState.after_parallel):
            # (In lanes, one group of LANES drives is one thread's work.)
            before = numba.get_num_threads()
            numba.set_num_threads(min(self.num_threads, numba.config.NUMBA_NUM_THREADS))
            try:
                self._batch_step(n, parallel=True)
            finally:
                numba.set_num_threads(before)
            _ForkState.parallel_used = True
        else:
            self._batch_step(n, parallel=False)
        self.task.observe(self, None)
        self.t += 1

    def _batch_step(self, n: int, parallel: bool) -> None:
        """``n`` PWM periods of every drive (:func:`batch_step`), with the task's
        damping law if it has one."""
        step = batch_step(self.simd, parallel)
        step(self.c, self.s, self.acc, self.u, self.law if self.task.law_actions else None, n)

    def advance(self) -> tuple[np.ndarray, np.ndarray]:
        """Run one agent step of every drive; returns (terminated, truncated) masks."""
        self._step_drives(None)
        terminated = self.out[:, self.task.out_layout.TERMINATED] != 0.0
        # max_steps < 0 (no limit of the task's own) never truncates.
        left = self.max_steps - self.t
        if terminated.any():
            self.task.end_of_step(self, terminated, left)
        truncated = (left <= 0) & (self.max_steps >= 0) & ~terminated
        return terminated, truncated

    def advance_one(self, trace: np.ndarray) -> tuple[bool, bool]:
        """:meth:`advance` for a batch of one (a scalar env), with Python flags;
        ``trace`` gets its PWM periods, one row each (zero rows: none kept)."""
        self._step_drives(trace)
        if self.out[0, self.task.out_layout.TERMINATED] != 0.0:
            self.task.end_of_step(self, np.ones(1, dtype=bool), self.max_steps - self.t)
            return True, False
        limit = int(self.max_steps[0])
        return False, 0 <= limit <= int(self.t[0])

    def info(self, i: int) -> dict[str, Any]:
        return self.task.step_info(self, i)


def slip_cycles(state: np.ndarray, system: SystemParams | None) -> float:
    """(theta_cmd - theta) of a drive's state in electrical cycles (2*pi/Nr rad)."""
    if system is None:
        return 0.0
    lag = state[K.STATE.THETA_CMD] - state[K.STATE.THETA]
    return float(lag * system.motor.Nr / (2.0 * math.pi))


class OneDriveEnv:
    """What a scalar env of any version reads off its drive, a :class:`DriveBatch`
    of one (``_drives``), with its ``task``, its trace rows (``_trace``), its
    window's metric sums (``_run_acc``), ``system`` and ``options``."""

    task: EnvTask
    _drives: DriveBatch
    _trace: np.ndarray
    _run_acc: np.ndarray
    system: SystemParams | None

    #: Why the episode is over ("terminated (...)", "been truncated (...)"), None while
    #: it runs.
    _ended: str | None

    def _attach(self, task: EnvTask, render_mode: str | None) -> None:
        """The env's drive for ``task`` (a DriveBatch of one), its spaces and an
        episode not yet started (``render_mode`` checked already)."""
        self.render_mode = render_mode
        self.observation_space = task.observation_space()
        self.action_space = task.action_space()
        self._drives = DriveBatch(task, 1)
        self._trace = np.zeros((task.n_periods if render_mode else 0, len(K.TRACE)))
        self._run_acc = new_accumulators()
        self._frames: list[np.ndarray] = []     # render: each step's trace rows
        self.system = None
        self._ready = False
        self._ended = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)            # gym.Env's: seeds np_random
        self._frames = []
        info = self._drives.reset_drive(0, self.np_random)
        self.system = self._drives.systems[0]
        self._run_acc[:] = 0.0
        self._ready = True
        self._ended = None
        return self._drives.obs[0].copy(), info

    def _check_steppable(self) -> None:
        if not self._ready:
            raise gym.error.ResetNeeded("call reset() before step()")
        if self._ended is not None:
            raise gym.error.ResetNeeded(f"the episode has {self._ended}; call reset() before "
                                        "step()")

    @property
    def drive_state(self) -> np.ndarray:
        """Copy of the kernel's state vector (``kernel.STATE``; SI units)."""
        return self._drives.s[0].copy()

    @property
    def slip_cycles(self) -> float:
        """How far the rotor trails its command, in electrical cycles (2*pi/Nr rad, four
        full steps): a whole number of them is steps lost for good."""
        return slip_cycles(self._drives.s[0], self._drives.systems[0])

    @property
    def speed_rps(self) -> float:
        """The held command speed of the current episode (rev/s; 0 before reset)."""
        return float(self._drives.speeds_rps[0])

    @property
    def seconds_per_step(self) -> float:
        """Simulated time of one agent step (s)."""
        return self.task.seconds_per_step

    @property
    def time_s(self) -> float:
        """Simulated time since the episode started (s)."""
        return float(self.task.time_s(self._drives)[0])

    @property
    def step_trace(self) -> np.ndarray:
        """The PWM periods of the last step, one row each (columns ``kernel.TRACE``:
        time (s), angles (rad), speeds (rad/s), currents (A), voltages (V)).

        Recorded only with a ``render_mode``; otherwise an empty (0, len(TRACE)) array.
        """
        return self._trace.copy()

    @property
    def drive_batch(self) -> DriveBatch:
        """A copy of this env's drive (a :class:`DriveBatch` of one), as
        :class:`StepperDampBatch` stacks it."""
        return DriveBatch.stack([self._drives])

    @property
    def window_sums(self) -> np.ndarray:
        """A copy of the run's metric sums since ``measure_from_s`` (``kernel.ACC``)."""
        return self._run_acc.copy()

    def run_metrics(self) -> RunMetrics:
        """The simulation core's metrics of the episode so far, over the window
        that opens at ``measure_from_s`` (lag, current peak: whole episode).

        Needs ``measure_from_s``; raises ``ValueError`` if the window is empty.
        """
        if self.options.measure_from_s is None:            # type: ignore[attr-defined]
            raise ParameterError("run_metrics() needs the option measure_from_s")
        if self.system is None:
            raise gym.error.ResetNeeded("call reset() before run_metrics()")
        return metrics_from_accumulators(self._run_acc, self.system, self.speed_rps)


class StepperDampBatch:
    """Reset envs of one version and layout stepped together: one compiled call
    per step for all of them (the batched episode runner's drive).

    Each row continues its env's episode exactly as the env's own ``step`` would,
    bit for bit; the envs are left as they were. The envs must share the task's
    layout (:meth:`EnvTask.layout`: action mode, agent rate, observation) and
    measure (``measure_from_s``); motors, speeds, seeds and windows may differ.
    Rows end for good: :meth:`keep` drops the others.
    """

    @staticmethod
    def layout_of(env: Any) -> tuple:
        """What envs stepped together must share (equal tuples: one batch)."""
        return env.task.layout()

    #: Step in SIMD lanes (:mod:`stepdamp_env.lanes`, the same bits) while the batch
    #: holds LANES rows or more: None (default) where numba compiles for AVX2 or
    #: wider (:func:`lanes.simd_by_default`), or True / False.
    simd: bool | None = None

    def __init__(self, envs: Sequence[Any] = (), *, drives: DriveBatch | None = None) -> None:
        """``envs``: reset envs of one layout, or ``drives``: the rows of fresh
        episodes (their window sums zero; :meth:`of_tasks` makes them)."""
        if drives is None:
            check_batch_envs(envs, self.layout_of, "StepperDampBatch")
            drives = DriveBatch.stack([env.drive_batch for env in envs])
            run = np.stack([env.window_sums for env in envs])
        else:
            run = np.zeros((drives.n,) + new_accumulators().shape)
        self._d, self._run = drives, run
        self._lanes = (lanes.simd_by_default(lanes.LANES) if self.simd is None
                       else bool(self.simd))

    @classmethod
    def of_tasks(cls, tasks: Sequence[EnvTask], seeds: Sequence[int]) -> "StepperDampBatch":
        """The batch of envs of ``tasks`` (their ``task``) reset with ``seeds``,
        built without the envs (a tenth of a millisecond less per row on the
        board): row i holds what ``StepperDampBatch([env])`` of such an env
        holds, bit for bit. The tasks must share a layout and measure."""
        if not tasks or len(tasks) != len(seeds):
            raise ValueError("StepperDampBatch.of_tasks needs one seed per task, at least one")
        layout = tasks[0].layout()
        if any(t.layout() != layout or t.options.measure_from_s is None for t in tasks):
            raise ValueError("StepperDampBatch needs tasks of one layout (action mode, agent "
                             "rate, observation), each with measure_from_s set")
        drives = DriveBatch(tasks[0], len(tasks))
        for i, (task, seed) in enumerate(zip(tasks, seeds)):
            drives.reset_drive(i, seeding.np_random(seed)[0], task)
        return cls(drives=drives)

    @property
    def obs(self) -> np.ndarray:
        """(n, obs_dim) float32: the rows' latest observations."""
        return self._d.obs

    @property
    def systems(self) -> list[SystemParams | None]:
        return self._d.systems

    @property
    def speeds_rps(self) -> np.ndarray:
        return self._d.speeds_rps

    @property
    def time_s(self) -> np.ndarray:
        """Each row's simulated time (s), as the env's ``time_s``."""
        return self._d.task.time_s(self._d)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance every row one agent step; returns the masks (terminated,
        step_loss, overcurrent) of this step."""
        d = self._d
        d.load(actions, (d.n, d.task.act_dim))
        d.simd = self._lanes and d.n >= lanes.LANES
        terminated, _ = d.advance()
        merge_accumulator_rows(self._run, d.acc)
        out = d.task.out_layout
        return (terminated, d.out[:, out.STEP_LOSS] != 0.0, d.out[:, out.OVERCURRENT] != 0.0)

    def slip_cycles(self, i: int) -> float:
        """Row i's slip in electrical cycles, as the env's ``slip_cycles``."""
        return slip_cycles(self._d.s[i], self._d.systems[i])

    def run_metrics(self, i: int) -> RunMetrics:
        """Row i's metrics, as the env's ``run_metrics()``."""
        return metrics_from_accumulators(self._run[i], self._d.systems[i],
                                         float(self._d.speeds_rps[i]))

    def keep(self, rows: np.ndarray) -> None:
        """Keep only ``rows`` (indices into the current rows, in order)."""
        self._d = DriveBatch.stack([self._d], rows)
        self._run = self._run[rows]
