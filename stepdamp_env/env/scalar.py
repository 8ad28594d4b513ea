"""The scalar environment ``StepperDamp-v0``."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from ..simulation import merge_accumulators
from . import compiled as C
from .arguments import check_render_mode
from .engine import OneDriveEnv
from .options import OPTIONS_DOC, EnvOptions
from .registration import ENV_ID
from .render import render_episode, trace_rows
from .sampler import EpisodeSampler

__all__ = ["StepperDampEnv"]

TWO_PI = 2.0 * np.pi


class StepperDampEnv(OneDriveEnv, gym.Env):
    __doc__ = """Residual active damping of a hybrid stepper drive (US 7,733,051).

    ## Description

    One episode is one operating point of one drive: a motor (a preset, a motor
    file, or a domain-randomised draw around one), a mode (open loop by default,
    or servo), and a speed command that ramps from rest and is then held. A base
    controller (the patent's harmonic detent feedforward by default) runs in
    the drive; the agent adds a residual to it. Inside one agent step the PWM
    period, the DQ current loops and the plant run at ``pwm_hz`` (20 kHz for the
    presets), so at the default ``agent_hz`` = 1 kHz one step is 20 PWM periods.
    A zero action reproduces the base controller alone, bit for bit.

    ## Action Space

    ``Box(-1, 1, (k,), float32)``, scaled inside and held for one agent step:

    * ``action_mode="harmonic"`` (k = 6): corrections (N*m) to the feedforward's
      sin/cos coefficients of the electrical-angle harmonics 1, 2, 4, in the order
      ds1, dc1, ds2, dc2, ds4, dc4, each ``action * harmonic_scale_nm``;
    * ``action_mode="current"`` (k = 1): a residual q-axis current (A),
      ``action * current_scale_a``;
    * ``action_mode="harmonic+current"`` (k = 7): both, the six harmonic
      corrections first, then the q current.

    An action of the wrong shape, non-finite or outside [-1, 1] raises ValueError.

    ## Observation Space

    ``Box(float32)``, what a drive senses at the last PWM sample of the step,
    scaled to about unit range and clipped to [-10, 10]:

    | idx | observation                                                    |
    |-----|----------------------------------------------------------------|
    | 0   | (theta_cmd - encoder angle) / full step                        |
    | 1   | (omega_cmd - filtered encoder velocity) / held command speed   |
    | 2-7 | sin, cos of the electrical (Park) angle x, of 2x and of 4x     |
    | 8   | omega_cmd / (2*pi*max(speed_range_rps[1], speed_rps))          |
    | 9   | measured id / holding current                                  |
    | 10  | measured iq / holding current                                  |
    | 11- | last action (k entries)                                        |

    With ``privileged=True`` four more entries: true (theta_cmd - theta) / full
    step, (omega_cmd - omega) / held command speed, ia / holding current, ib /
    holding current (true angle, speed, currents at the end of the step).

    ## Rewards

    ``-mean((w_cmd - w)^2) / w_ref^2 - current_penalty * mean(iq_inj^2) / I_hold^2``,
    means over the PWM periods of the step, w_ref the held command speed (rad/s),
    iq_inj the injected q current (feedforward plus residual, A), I_hold the
    holding current. A terminating step also subtracts ``termination_penalty``
    (100: more than the whole return of a healthy default episode, about -0.02 with
    the patent feedforward to -35 undamped at the h = 4 resonance, so ending an
    episode early does not pay). ``info`` holds the step's physics: ``velocity_error_rms_rad_s``,
    ``lag_rad`` (max |theta_cmd - theta|), ``injected_current_rms_a``,
    ``peak_current_a`` and the flags ``step_loss``, ``overcurrent``.

    ## Starting State

    Rotor at rest at 0 rad, command at rest; in open loop the holding current
    already flows. ``reset`` info: ``speed_rps`` and ``target_harmonic`` (h of the
    resonance drawn, 0 for a uniform or fixed speed).

    ## Episode End

    Terminated on step loss (lag past one full step, 2*pi/(4*Nr) rad), on an
    unsafe phase current (past ``current_limit_factor`` = 3 times the holding
    current), or if the simulation stops being finite. Truncated by the
    ``TimeLimit`` after ``max_episode_steps`` = 300 steps (0.3 s at 1 kHz: the
    longest default ramp takes 60 ms, leaving at least 240 ms held). If you
    change ``agent_hz``, pass ``max_episode_steps`` to ``gym.make`` to match.
    Stepping a terminated episode raises ``gymnasium.error.ResetNeeded``; to have
    the same after truncation, wrap the made env:
    ``EpisodeGuard(gym.make("StepperDamp-v0"))`` (gymnasium's ``TimeLimit``
    itself steps on).
    A copy (``pickle``, ``copy.deepcopy``) is a working env with the same future.
    """ + OPTIONS_DOC + """
    ## Version History

    * v0: initial version (``action_mode="harmonic+current"`` added later;
      the other modes are unchanged). Package 0.2: stepping after termination
      raises instead of going on silently; copies work; a system one RK4 step
      per PWM period cannot integrate, or an unstable current loop, is refused
      at reset with the substeps it needs; ``step_trace``; ``EpisodeGuard``
      (rollouts unchanged).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, render_mode: str | None = None, **options: Any) -> None:
        mode = check_render_mode(render_mode, self.metadata["render_modes"])
        self.options = EnvOptions.from_kwargs(options)
        self._sampler = f = EpisodeSampler(self.options)
        self._measuring = self.options.measure_from_s is not None
        self._attach(f, mode)

    @staticmethod
    def task_of(**options: Any) -> EpisodeSampler:
        """The task of ``StepperDampEnv(**options)`` (the options checked), without
        the env: what :meth:`.engine.StepperDampBatch.of_tasks` builds batches of."""
        return EpisodeSampler(EnvOptions.from_kwargs(options))

    # -- public read-outs ------------------------------------------------------
    @property
    def drive_config(self) -> np.ndarray:
        """Copy of the kernel's configuration vector (``kernel.CONFIG``) of this episode."""
        return self._drives.c[0].copy()

    @property
    def sampler(self) -> EpisodeSampler:
        """The episode sampler: nominal system, action layout and scales (read-only)."""
        return self._sampler

    @property
    def task(self) -> EpisodeSampler:
        """The env's task over the engine (:class:`.engine.EnvTask`): its sampler."""
        return self._sampler

    # -- API ----------------------------------------------------------------------
    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self._check_steppable()
        d = self._drives
        d.load(action, (self.task.act_dim,))
        terminated, _ = d.advance_one(self._trace)
        if self._measuring:
            merge_accumulators(self._run_acc, d.acc[0])
        if self.render_mode is not None:
            self._frames.append(trace_rows(self._trace))
        if terminated:
            self._ended = "terminated (step loss, over-current or a non-finite state)"
        return (d.obs[0].copy(), float(d.out[0, C.OUT.REWARD]), terminated, False, d.info(0))

    # -- rendering ------------------------------------------------------------------
    def render(self) -> np.ndarray | None:
        """RGB array (H, W, 3) of velocity error and currents of the episode so far."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass "
                            "render_mode='rgb_array' to the constructor")
            return None
        speed = self._drives.par[0, C.PARAM.W_REF] / TWO_PI
        return render_episode(self._frames, f"{ENV_ID}: {speed:.3g} rev/s, {self.options.mode}")
