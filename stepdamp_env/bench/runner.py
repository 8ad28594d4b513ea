"""The episode runner: a policy on a motor at one speed, measured as the protocol says.

:func:`run_episode` runs one episode in a scalar env (the figures, the training
validator and the tests use it)::

    result = run_episode(policy, knowledge, system, mode="open-loop", speed_rps=0.67,
                         seed=1_000_000)
    result.metrics["rms_velocity_error_rad_s"]

:func:`run_episodes` runs many episodes of one policy and suite together (the
leaderboard's): their drives advance in one compiled call per agent step and
the policy acts for all of them at once (:class:`.policy.BatchPolicy`); every
episode gives what :func:`run_episode` gives, bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from ..env.registration import ENV_ID_V1
from ..env.engine import StepperDampBatch
from ..env.scalar import StepperDampEnv
from ..env.v1 import StepperDampV1Env
from ..params import ParameterError, SystemParams
from ..simulation import (DEFAULT_ACCEL_RPS2, RunSettings, SpeedProfile,
                          default_settle_s, measuring_window)
from .policy import (MotorKnowledge, Policy, batch_policy, policy_context, policy_env_id,
                     policy_env_options)

__all__ = ["EpisodeResult", "EpisodeSpec", "run_episode", "run_episodes", "episode_window",
           "move_window",
           "RUN_ERRORS", "could_not_run",
           "lost_steps"]


@dataclass
class EpisodeResult:
    """What one run gives.

    Attributes:
        terminated: the env ended the episode (step loss, over-current, non-finite).
        termination: "step_loss", "overcurrent", "non_finite" or "".
        failed: terminated, or the core's metrics report a step loss.
        steps: agent steps taken.
        window_start_s, window_s: the measuring window (s).
        metrics: the simulation core's metrics over the window
            (``RunMetrics.to_dict()``), None if the run ended before it opened.
        trace: what ``on_step`` collected (empty without it).
        calibration_s: simulated seconds the policy spent calibrating on its
            rig before the run (its ``calibration_s`` after reset; not scored).
        simulated_s: simulated seconds the episode ran (ramp, settling, window).
        slip_cycles: with a lag limit (stepdamp-bench v3), how far the rotor
            trails its command at the end, in electrical cycles (2*pi/Nr rad);
            None otherwise (and left out of the record).
        error: why the entry could not run at all ("" when it ran; left out of
            the record then): :func:`could_not_run`.
    """

    terminated: bool
    termination: str
    failed: bool
    steps: int
    window_start_s: float
    window_s: float
    metrics: dict[str, Any] | None
    trace: list[Any] = field(default_factory=list)
    calibration_s: float = 0.0
    simulated_s: float = 0.0
    slip_cycles: float | None = None
    error: str = ""

    def record(self, motor: str, seed: int, speed_rps: float, speed_label: str,
               training_seed: int | None = None) -> dict[str, Any]:
        """The leaderboard's record of the run: where it ran (and the training seed
        of the model, for learned entries), then :meth:`to_dict`."""
        where: dict[str, Any] = {"motor": motor, "seed": seed, "speed_rps": speed_rps,
                                 "speed_label": speed_label}
        if training_seed is not None:
            where["training_seed"] = training_seed
        return {**where, **self.to_dict()}

    def to_dict(self) -> dict[str, Any]:
        """What the run gave (without the trace)."""
        out = {"terminated": self.terminated, "termination": self.termination,
               "failed": self.failed, "steps": self.steps,
               "window_start_s": self.window_start_s, "window_s": self.window_s,
               "metrics": self.metrics, "calibration_s": self.calibration_s,
               "simulated_s": self.simulated_s}
        if self.slip_cycles is not None:
            out["slip_cycles"] = self.slip_cycles
        if self.error:
            out["error"] = self.error
        return out


#: What an entry raises when it cannot run on a motor: a parameter outside its law's
#: range (its law cannot be made for it). Any other exception is a bug and stops
#: the board with its one-line message.
RUN_ERRORS = (ParameterError,)


def could_not_run(exc: BaseException) -> EpisodeResult:
    """The result of a run the entry could not start or finish because it raised
    (:data:`RUN_ERRORS`): lost, with the error as its one-line reason."""
    text = " ".join(str(exc).split())
    return EpisodeResult(terminated=True, termination="error", failed=True, steps=0,
                         window_start_s=0.0, window_s=0.0, metrics=None,
                         error=f"{type(exc).__name__}: {text}"[:300])


def lost_steps(terminated: bool, metrics: dict[str, Any] | None, slip: float | None,
               mode: str = "open-loop") -> bool:
    """Whether a run failed: it terminated, or (no lag limit) the core saw a lag past
    one full step, or (a lag limit: v3) in open loop the rotor ends a whole
    electrical cycle away from its command (|slip| rounds to 1 or more: the
    steps it lost; a recoverable lag is no loss). In servo the drive commutates
    on the encoder angle, so the rotor cannot slip whole cycles: with a lag
    limit only a termination (over-current, a non-finite state) is a loss."""
    if terminated:
        return True
    if slip is None:
        return metrics is not None and bool(metrics["step_loss"])
    return mode == "open-loop" and abs(slip) >= 0.5


def episode_window(system: SystemParams, speed_rps: float, accel_rps2: float,
                   window_s: float, settle_s: float | None = None) -> tuple[float, float]:
    """(start, length) of the measuring window in s: ``settle_s`` (default: the
    core's settling) after the ramp, ``window_s`` rounded up to whole periods of
    the first detent harmonic."""
    return measuring_window(system, SpeedProfile(speed_rps=speed_rps, accel_rps2=accel_rps2),
                            RunSettings(window_s=window_s, settle_s=settle_s))


def move_window(system: SystemParams, profile: SpeedProfile, settle_s: float | None = None
                ) -> tuple[float, float, float]:
    """A point-to-point move's (window start, window length, run end) in s:
    the window is its cruise at top speed (from the end of the first ramp, so
    what the ramp through lower resonances excites is measured), the run ends
    ``settle_s`` (default: the core's settling) after the move. A move too
    short to reach its top speed has no cruise to measure: a one-line error."""
    settle = default_settle_s(system) if settle_s is None else float(settle_s)
    start, length = profile.cruise()
    if not length > 0.0:
        ramps = profile.speed_rps * profile.ramp_s
        raise ParameterError(f"distance_rev={profile.distance_rev!r} never reaches the top speed "
                             f"{profile.speed_rps!r} rev/s: nothing to measure; allowed "
                             f"|distance_rev| > {abs(ramps):.6g} rev (both ramps)")
    return start, length, profile.duration_s() + settle


@dataclass(frozen=True)
class EpisodeSpec:
    """Where one episode of :func:`run_episodes` runs (see :func:`run_episode`
    for the fields; ``accel_rps2`` None: the batch's)."""

    knowledge: MotorKnowledge
    system: SystemParams
    speed_rps: float
    seed: int
    settle_s: float | None = None
    measure_from_s: float | None = None
    until_s: float | None = None
    profile: str = "constant"
    distance_rev: float = 0.0
    accel_rps2: float | None = None
    ramp: str = "trapezoid"


def _env_setup(policy: Any, spec: EpisodeSpec, mode: str, accel_rps2: float, window_s: float,
               lag_limit_steps: float | None = None
               ) -> tuple[type, dict[str, Any], float, float, float, dict[str, Any]]:
    """The episode's env class and its options, window (start, length), end time and
    the policy's options."""
    system = spec.system
    if spec.accel_rps2 is not None:
        accel_rps2 = spec.accel_rps2
    options = policy_env_options(policy, spec.knowledge)
    protocol_options: dict[str, Any] = {} if lag_limit_steps is None else \
        {"lag_limit_steps": lag_limit_steps}
    slack = 0.5 / system.drive.pwm_hz   # time_s is a float multiple of the period
    if spec.profile == "move":
        profile = SpeedProfile(speed_rps=spec.speed_rps, accel_rps2=accel_rps2,
                               kind=spec.profile, distance_rev=spec.distance_rev,
                               ramp=spec.ramp)
        start, length, end = move_window(system, profile, spec.settle_s)
        end -= slack
        protocol_options.update(profile=spec.profile, ramp=spec.ramp,
                                distance_rev=spec.distance_rev, measure_until_s=start + length)
    else:
        start, length = episode_window(system, spec.speed_rps, accel_rps2, window_s,
                                       spec.settle_s)
        if spec.measure_from_s is not None:
            start, length = float(spec.measure_from_s), float(window_s)
        end = start + length - slack
    if spec.until_s is not None:
        end = spec.until_s
    kwargs = dict(motor=system, mode=mode, speed_rps=spec.speed_rps, accel_rps2=accel_rps2,
                  measure_from_s=start, **options, **protocol_options)
    if policy_env_id(policy) == ENV_ID_V1:
        kwargs.update(nominal=spec.knowledge.nominal, episode_s=end + 1.0)
        return StepperDampV1Env, kwargs, start, length, end, options
    return StepperDampEnv, kwargs, start, length, end, options


def _make_env(policy: Any, spec: EpisodeSpec, mode: str, accel_rps2: float, window_s: float,
              render: str | None, lag_limit_steps: float | None = None
              ) -> tuple[Any, float, float, float, dict[str, Any]]:
    """The episode's env (not reset), window (start, length), end time and options."""
    env_class, kwargs, start, length, end, options = _env_setup(
        policy, spec, mode, accel_rps2, window_s, lag_limit_steps)
    return env_class(render_mode=render, **kwargs), start, length, end, options


def run_episode(policy: Policy, knowledge: MotorKnowledge, system: SystemParams, *,
                mode: str, speed_rps: float, seed: int,
                accel_rps2: float = DEFAULT_ACCEL_RPS2, window_s: float = 0.3,
                settle_s: float | None = None, measure_from_s: float | None = None,
                until_s: float | None = None,
                on_step: Callable[[StepperDampEnv, np.ndarray, float], Any] | None = None,
                pwm_trace: bool = False, lag_limit_steps: float | None = None,
                suite: str | None = None, profile: str = "constant",
                distance_rev: float = 0.0, ramp: str = "trapezoid") -> EpisodeResult:
    """Run ``policy`` in ``StepperDamp-v0`` (or in ``StepperDamp-v1`` if its
    ``env_id`` says so: the drive's ``nominal`` model is then the knowledge's) on
    the true plant ``system``.

    The env gets the policy's options (checked, :func:`policy_env_options`),
    is reset with ``seed`` (which also seeds the sensor noise), the policy is
    reset with its :class:`PolicyContext` and stepped until the agent step in
    which the simulated time reaches the end of the measuring window (or
    ``until_s``), or until the env terminates. The window opens a settling time
    after the ramp (:func:`episode_window`) unless ``measure_from_s`` says
    when; ``settle_s`` replaces the core's settling (stepdamp-bench v1 sets each
    motor's own). ``on_step(env, observation, window_start_s)`` is called after every
    step; what it returns (if not None) is kept in ``trace``. With
    ``pwm_trace`` the env records every PWM period of a step
    (``env.step_trace``) for ``on_step`` to read; the run is otherwise the same.
    ``lag_limit_steps`` (stepdamp-bench v3): the env's lag limit, and the run
    is judged by its final slip (:func:`lost_steps`). ``suite``: the policy's
    ``PolicyContext.suite`` (None: the one of ``mode`` on the nominal drive).
    ``profile`` "move": a point-to-point move of ``distance_rev`` at up to
    ``speed_rps`` with ``ramp`` "trapezoid" or "s-curve" (``accel_rps2`` its
    ramps' peak acceleration),
    measured over its cruise and run until ``settle_s`` after it ends
    (:func:`move_window`; ``window_s`` and ``measure_from_s`` do not apply).
    """
    spec = EpisodeSpec(knowledge, system, speed_rps, seed, settle_s, measure_from_s, until_s,
                       profile, float(distance_rev), ramp=ramp)
    env, start, length, end, options = _make_env(policy, spec, mode, accel_rps2, window_s,
                                                 "rgb_array" if pwm_trace else None,
                                                 lag_limit_steps)
    obs, _ = env.reset(seed=seed)
    policy.reset(policy_context(options, knowledge, mode, speed_rps, accel_rps2, suite,
                                window_s, settle_s, lag_limit_steps, profile,
                                float(distance_rev), ramp))
    steps, terminated, reason = 0, False, ""
    trace: list[Any] = []
    while env.time_s < end:
        obs, _, terminated, _, info = env.step(policy.act(obs))
        steps += 1
        if on_step is not None:
            item = on_step(env, obs, start)
            if item is not None:
                trace.append(item)
        if terminated:
            reason = ("step_loss" if info["step_loss"] else
                      "overcurrent" if info["overcurrent"] else "non_finite")
            break
    time_s = env.time_s
    try:
        metrics: dict[str, Any] | None = env.run_metrics().to_dict()
    except ValueError:                  # terminated before the window opened
        metrics = None
    slip = env.slip_cycles if lag_limit_steps is not None else None
    env.close()
    return EpisodeResult(terminated=bool(terminated), termination=reason,
                         failed=lost_steps(bool(terminated), metrics, slip, mode),
                         steps=steps, window_start_s=start, window_s=length, metrics=metrics,
                         trace=trace, calibration_s=float(getattr(policy, "calibration_s", 0.0)),
                         simulated_s=float(time_s), slip_cycles=slip)


def run_episodes(make_policy: Callable[[], Any], specs: Sequence[EpisodeSpec], *, mode: str,
                 accel_rps2: float = DEFAULT_ACCEL_RPS2, window_s: float = 0.3,
                 lag_limit_steps: float | None = None,
                 suite: str | None = None) -> list[EpisodeResult]:
    """One episode per spec, all of one policy and suite, stepped together.

    ``make_policy()`` gives a fresh policy: a :class:`.policy.BatchPolicy`
    acts for every episode at once, any other is run as one fresh instance
    per episode (:class:`.policy.ScalarPolicies`). Episodes whose envs differ
    in layout (e.g. a motor with another PWM rate) run in separate batches.
    Each result equals ``run_episode(make_policy(), ...)`` of its spec, bit
    for bit (no ``on_step`` trace); the results come back in the specs' order.
    """
    policy = batch_policy(make_policy)
    n = len(specs)
    tasks, ends, windows, contexts = [], np.zeros(n), [], []
    for i, spec in enumerate(specs):
        # The env's task only: its batch row is what the env reset with the seed holds.
        env_class, kwargs, start, length, end, options = _env_setup(
            policy, spec, mode, accel_rps2, window_s, lag_limit_steps)
        tasks.append(env_class.task_of(**kwargs))
        ends[i] = end
        windows.append((start, length))
        contexts.append(policy_context(
            options, spec.knowledge, mode, spec.speed_rps,
            accel_rps2 if spec.accel_rps2 is None else spec.accel_rps2, suite, window_s,
            spec.settle_s, lag_limit_steps, spec.profile, spec.distance_rev, spec.ramp))
    calibration = getattr(policy, "row_calibration_s", None)
    results: list[EpisodeResult | None] = [None] * n
    groups: dict[tuple, list[int]] = {}
    for i, task in enumerate(tasks):
        groups.setdefault(task.layout(), []).append(i)
    for members in groups.values():
        # One batch: its runs are rows 0..k-1 of one reset_batch; they leave as they end.
        index = np.asarray(members, dtype=np.int64)
        policy.reset_batch([contexts[i] for i in members])
        batch = StepperDampBatch.of_tasks([tasks[i] for i in members],
                                          [specs[i].seed for i in members])
        rows = np.arange(len(members))
        ends_rows = ends[index]
        no = np.zeros(len(members), dtype=bool)
        # Every row steps until it leaves: a row's step count is the batch's at its end.
        n_steps = 0

        def finish(done: np.ndarray, terminated: np.ndarray, step_loss: np.ndarray,
                   overcurrent: np.ndarray) -> None:
            """Record the runs ``done`` (a mask over the batch's current rows) and drop them."""
            nonlocal rows, ends_rows, no
            time_s = batch.time_s
            for j in np.flatnonzero(done).tolist():
                row, i = int(rows[j]), int(index[rows[j]])
                term = bool(terminated[j])
                reason = ("" if not term else "step_loss" if step_loss[j] else
                          "overcurrent" if overcurrent[j] else "non_finite")
                try:
                    metrics: dict[str, Any] | None = batch.run_metrics(j).to_dict()
                except ValueError:          # terminated before the window opened
                    metrics = None
                slip = batch.slip_cycles(j) if lag_limit_steps is not None else None
                cal = float(calibration(row)) if calibration is not None else \
                    float(getattr(policy, "calibration_s", 0.0))
                results[i] = EpisodeResult(
                    terminated=term, termination=reason,
                    failed=lost_steps(term, metrics, slip, mode),
                    steps=n_steps, window_start_s=windows[i][0], window_s=windows[i][1],
                    metrics=metrics, calibration_s=cal, simulated_s=float(time_s[j]),
                    slip_cycles=slip)
            keep = np.flatnonzero(~done)
            batch.keep(keep)
            rows, ends_rows, no = rows[keep], ends_rows[keep], no[keep]

        while len(rows):
            # As run_episode: a run steps while its time is before its end, and ends
            # at once when it terminates.
            over = batch.time_s >= ends_rows
            if over.any():
                finish(over, no, no, no)
                if not len(rows):
                    break
            actions = policy.act_batch(batch.obs.copy(), rows)
            terminated, step_loss, overcurrent = batch.step(actions)
            n_steps += 1
            if terminated.any():
                finish(terminated, terminated, step_loss, overcurrent)
    return [r for r in results if r is not None]
