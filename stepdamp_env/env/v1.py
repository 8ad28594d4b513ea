"""``StepperDamp-v1``: the residual damping task in units the motor sets, scalar and vector.

:class:`TaskV1` is the task; both envs advance the engine's
:class:`~.engine.DriveBatch` (N drives, one compiled call per step); the scalar
env is a batch of one, so the two agree step for step by construction.
"""

from __future__ import annotations

import copy
import math
import warnings
from typing import Any, Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode

from .. import fixedmath as fm
from .. import kernel as K
from ..params import FeedforwardModel, SystemParams
from ..motorfile import load_system
from ..response import phasors, torque_paths
from ..simulation import (RunSettings, build_config, initial_state,
                          merge_accumulators)
from . import compiled as C
from . import v1_compiled as V
from .arguments import (check_num_threads, check_render_mode, check_simd, check_vector_args)
from .engine import DriveBatch, EnvTask, OneDriveEnv
from .options import default_action_scales
from .render import render_episode, trace_rows
from .registration import (ENV_ID_V1, ENV_ID_V2, ENV_ID_V3, RESERVED_SEEDS_FROM, V2_DEFAULTS,
                           V3_DEFAULTS)
from .sampler import EpisodeSampler
from .vector_base import STEP_INFOS, DriveVectorEnv
from .v1_options import (ACTION_NAMES_V1, CONTEXT_NAMES, GAIN_PHASE_LIMIT_RAD, OPTIONS_DOC_V1,
                         REWARD_BOUND, EnvOptionsV1, MotorUnits)

__all__ = ["TaskV1", "StepperDampV1Env", "StepperDampV1VectorEnv", "StepperDampV2Env",
           "StepperDampV2VectorEnv", "StepperDampV3Env", "StepperDampV3VectorEnv"]

TWO_PI = 2.0 * math.pi
_FF_COLUMNS = (K.CONFIG.FF_S1, K.CONFIG.FF_C1, K.CONFIG.FF_S2, K.CONFIG.FF_C2, K.CONFIG.FF_S4, K.CONFIG.FF_C4)


class TaskV1(EnvTask):
    """``StepperDamp-v1``'s task over the engine (:class:`.engine.EnvTask`): its
    options, the drive's units, spaces and action scales; observation, action
    loading, reward and termination.

    Read-only. Episodes are drawn by v0's :class:`EpisodeSampler` (``draws``), so a
    seed gives the same motor and speed in v0 and v1.
    """

    param_size = len(V.PARAM)
    out_layout = V.OUT

    def __init__(self, options: EnvOptionsV1) -> None:
        self.options = o = options
        self.draws = EpisodeSampler(o.shared())
        self._nominal_episode_estimate: FeedforwardModel | None = None
        # The drive's datasheet model: given apart from the plant on the leaderboard.
        self.nominal: SystemParams = (self.draws.nominal if o.nominal is None
                                      else load_system(o.nominal))
        self.units = u = MotorUnits.of(self.nominal)
        self.n_periods = self.draws.n_periods
        self.seconds_per_step = self.draws.seconds_per_step
        self.max_episode_steps = o.max_episode_steps
        self.action_names = ACTION_NAMES_V1[o.action_mode]
        self.act_dim = len(self.action_names)
        m = self.nominal.motor
        drive = self.nominal.drive
        kv = 2.0 * o.damping_ratio_scale * m.J * u.wn_rad_s / m.Km
        kr = o.resonant_rate_scale * m.J * u.wn_rad_s * u.wn_rad_s / m.Km
        harmonic, current = self.draws.harmonic_scale_nm, self.draws.current_scale_a
        if o.nominal is not None:
            default_harmonic, default_current = default_action_scales(self.nominal)
            harmonic = default_harmonic if o.harmonic_scale_nm is None else harmonic
            current = default_current if o.current_scale_a is None else current
        self.gain_phase = o.action_mode == "gain-phase"
        if o.action_mode == "damping-gains":
            # (kv, kp) = (cos phi, -sin phi): velocity feedback with a lead of about phi at wn.
            scales = (kv, kv * u.wn_rad_s) + (kr,) * 6
            self.law_actions, self.input_offset = True, K.LAW.KV
        elif self.gain_phase:
            # The (kv, kp) pair of "damping-gains" as a gain and a phase (load_gain_phase).
            scales, self.law_actions, self.input_offset = (kv, kv * u.wn_rad_s), True, K.LAW.KV
        elif o.action_mode == "harmonic":
            scales, self.law_actions, self.input_offset = (harmonic,) * 6, False, K.INPUT.DS1
        elif o.action_mode == "current":
            scales, self.law_actions, self.input_offset = (current,), False, K.INPUT.IQ
        else:
            scales, self.law_actions, self.input_offset = ((harmonic,) * 6 + (current,), False,
                                                           K.INPUT.DS1)
        self.action_scales = tuple(float(x) for x in scales)
        # The high-pass of the position error: corner wn/4 (13 degrees of lead at wn).
        self.law_hp_alpha = 1.0 - fm.exp(-0.25 * u.wn_rad_s / drive.pwm_hz)
        self.law_limit_a = o.law_limit_factor * drive.holding_current
        self.n_context = len(CONTEXT_NAMES) if o.context == "visible" else 0
        self.obs_dim = (len(V.OBS) + self.act_dim + len(V.HISTORY) * o.history
                        + self.n_context + (len(V.PRIVILEGED) if o.privileged else 0))
        self.privileged = bool(o.privileged)
        self.extra_rows = {"history": (len(V.HISTORY) * o.history, np.float32),
                           "ctx": (self.n_context, np.float32)}
        self.cruise_reward = o.reward_window == "cruise"
        if self.cruise_reward:          # each drive's cruise (start, end) in s
            self.extra_rows["cruise"] = (2, np.float64)

    def observation_space(self) -> spaces.Box:
        high = np.full(self.obs_dim, C.OBS_BOUND, dtype=np.float32)
        high[V.OBS.SIN_X:V.OBS.COS_4X + 1] = 1.0
        high[len(V.OBS):len(V.OBS) + self.act_dim] = 1.0
        return spaces.Box(-high, high, dtype=np.float32)

    def action_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, shape=(self.act_dim,), dtype=np.float32)

    def episode_estimate(self, system: SystemParams) -> FeedforwardModel:
        """The detent model the base controller uses in an episode of ``system``."""
        if self.options.nominal is not None and self.options.estimate == "nominal":
            return FeedforwardModel.from_motor(self.nominal.motor)
        if system is self.nominal:                  # not randomised: the same every episode
            if self._nominal_episode_estimate is None:
                self._nominal_episode_estimate = self.draws.episode_estimate(system)
            return self._nominal_episode_estimate
        return self.draws.episode_estimate(system)

    def base_coefficients(self, model: FeedforwardModel, speed_rps: float) -> np.ndarray:
        """The base controller's feedforward sin/cos coefficients (N*m) of an episode
        whose detent model is ``model``."""
        p = phasors(model)
        if self.options.base_controller == "ff-delay-comp":
            p = p / torque_paths(self.nominal, self.options.mode, speed_rps, model)
        out = np.empty(6)
        out[0::2], out[1::2] = p.real, p.imag
        return out

    def context(self, model: FeedforwardModel, speed_rps: float) -> np.ndarray:
        """The visible context of an episode (``CONTEXT_NAMES``) whose detent model is
        ``model``, float32."""
        res = self.nominal.predicted_resonances_rps()
        model = np.asarray(model.coefficients())
        kd = self.units.current_unit_a * self.nominal.motor.Km
        return np.concatenate([[speed_rps / res[h] for h in (4, 2, 1)], model / kd]
                              ).astype(np.float32)

    def new_episode(self, rng: np.random.Generator, drives: DriveBatch, i: int
                    ) -> tuple[dict[str, Any], SystemParams]:
        """Draw an episode into drive i's rows; returns (reset info, system)."""
        c, s, par, law = drives.c[i], drives.s[i], drives.par[i], drives.law[i]
        o, d = self.options, self.draws
        system = d.draw_system(rng)
        speed, h = d.draw_speed(rng, system)
        noise_seed = int(rng.integers(2 ** 53))
        ramp, accel = d.draw_move(rng)
        estimate = self.episode_estimate(system)
        settings = RunSettings(mode=o.mode, base_controller="patent-ff" if o.base_controller != "none"
                               else "none", substeps=int(o.substeps), estimate=estimate,
                               velocity_estimator=o.velocity_estimator, noise_seed=noise_seed)
        profile = d.profile(speed, ramp, accel)
        c[:] = build_config(system, profile, settings, *d.window())
        if self.cruise_reward:
            start, length = profile.cruise()
            drives.extra["cruise"][i] = (start, start + length)
        if o.base_controller == "ff-delay-comp":
            c[list(_FF_COLUMNS)] = self.base_coefficients(estimate, speed)
        s[:] = initial_state(c)
        u, hold = self.units, system.drive.holding_current
        par[V.PARAM.POS_UNIT] = u.position_unit_rad
        par[V.PARAM.VEL_UNIT] = u.velocity_unit_rad_s
        par[V.PARAM.CUR_UNIT] = u.current_unit_a
        par[V.PARAM.SPEED_UNIT] = u.speed_unit_rad_s
        par[V.PARAM.ID_CMD] = hold if o.mode == "open-loop" else 0.0
        par[V.PARAM.FULL_STEP] = system.motor.full_step_rad
        par[V.PARAM.LAG_LIMIT] = o.lag_limit_steps * system.motor.full_step_rad
        par[V.PARAM.HOLD] = hold
        par[V.PARAM.I_LIMIT] = o.current_limit_factor * hold
        par[V.PARAM.CUR_PEN] = o.current_penalty
        par[V.PARAM.ACT_SCALE:V.PARAM.ACT_SCALE + self.act_dim] = self.action_scales
        law[:] = 0.0
        law[K.LAW.HP_ALPHA] = self.law_hp_alpha
        law[K.LAW.LIMIT] = self.law_limit_a
        if self.n_context:
            drives.extra["ctx"][i] = self.context(estimate, speed)
        return {"speed_rps": speed, "target_harmonic": h, **d.move_info(ramp, accel)}, system

    def observe(self, drives: DriveBatch, rows: slice | None) -> None:
        d = drives.view(rows)
        V.observe(d.s, d.acc, d.law, d.a, d.par, C.KERNEL_INDEX, V.LAW_INDEX, d.extra["history"],
                  d.extra["ctx"], self.privileged, C.OBS_BOUND, REWARD_BOUND, d.obs, d.out)
        if self.cruise_reward:
            # The step just run is step t (t counts steps before it): its middle.
            mid = (d.t + 0.5) * self.seconds_per_step
            cruise = d.extra["cruise"]
            d.out[(mid < cruise[:, 0]) | (mid >= cruise[:, 1]), V.OUT.REWARD] = 0.0

    def load(self, drives: DriveBatch, a: np.ndarray) -> int:
        if self.gain_phase:
            return V.load_gain_phase(a, drives.law, self.input_offset, drives.par, drives.acc,
                                     V.LAW_INDEX, GAIN_PHASE_LIMIT_RAD)
        dest = drives.law if self.law_actions else drives.u
        return V.load_actions(a, dest, self.input_offset, drives.par, drives.acc, drives.law,
                              V.LAW_INDEX)

    def end_of_step(self, drives: DriveBatch, terminated: np.ndarray, left: np.ndarray) -> None:
        if terminated.any():
            # The worst reward of every step it did not play: ending early never pays.
            drives.out[terminated, V.OUT.REWARD] -= (
                REWARD_BOUND * (1.0 + drives.par[terminated, V.PARAM.CUR_PEN])
                * np.maximum(left[terminated], 0))

    def step_info(self, drives: DriveBatch, i: int) -> dict[str, Any]:
        out = drives.out[i]
        return {**C.physics_info(out), "damping_current_rms_a": float(out[V.OUT.LAW_RMS]),
                "time_s": float(drives.t[i] * self.seconds_per_step)}




_DOC = """Residual active damping of a hybrid stepper drive (US 7,733,051), version 1.

    ## Description

    One episode is one operating point of one drive, drawn exactly as in
    ``StepperDamp-v0`` (a preset, a motor file or a randomised draw; open loop
    or servo; a speed command that ramps from rest and is then held; the same
    seed gives the same motor and speed in both). A model-based base
    controller runs in the drive (``base_controller``, "ff-delay-comp" by
    default); the agent acts on top of it every ``1/agent_hz`` s (1 ms) while
    the PWM period, current loops, damping law and plant run at ``pwm_hz`` (20
    kHz). A zero action is the base controller alone.

    Units are those the motor sets itself, computed from the drive's nominal
    (datasheet) model, never from the episode's true plant (``env.task.units``,
    :class:`MotorUnits`): the rotor on the spring of its holding current,
    k = Km*I_hold*Nr, wn = sqrt(k/J); Kd = max(Kd1, Kd2, Kd4);
    ``position_unit_rad`` = Kd/k, ``velocity_unit_rad_s`` = wn*Kd/k (0.36 rad/s
    for "patent"), ``current_unit_a`` = Kd/Km (the current that cancels the
    largest detent harmonic).

    ## Action Space

    ``Box(-1, 1, (k,), float32)``, scaled inside, held for one agent step:

    * ``"damping-gains"`` (default, k = 8): gains of a damping law that the
      compiled kernel evaluates every PWM period from the drive's own samples
      (one period old) and adds to the q current, bounded by
      ``law_limit_factor`` * holding current:
      ``iq = kv*Kv*e_w + kp*Kv*wn*hp(e_theta) + sum_h (a_h sin hx + b_h cos hx)``,
      e_w = w_cmd - w_estimate, e_theta = theta_cmd - theta_encoder, hp a
      high-pass at wn/4 (drops the static lag), Kv = 2*``damping_ratio_scale``*J*wn/Km
      (kv = 1 adds a damping ratio of 0.5 to the nominal rotor; (kv, kp) =
      (cos phi, -sin phi) leads by about phi at wn, the high-pass adding a little). Per harmonic h = 1, 2, 4 a
      resonant term: its phasor a_h + j b_h integrates (r<h>_re + j r<h>_im) *
      Kr * e_w * (sin hx + j cos hx), Kr = ``resonant_rate_scale``*J*wn^2/Km,
      and is kept when its gains go back to zero. Names:
      ``kv, kp, r1_re, r1_im, r2_re, r2_im, r4_re, r4_im``.
    * ``"gain-phase"`` (k = 2; StepperDamp-v3's): the velocity-feedback pair of
      "damping-gains" as a gain and a phase: kv = g*cos(phi), kp = -g*sin(phi),
      g = max(``gain``, 0), phi = ``phase`` * pi/4 (a positive phase leads);
      resonant gains 0. Names: ``gain, phase``.
    * ``"harmonic"`` (k = 6), ``"current"`` (k = 1), ``"harmonic+current"`` (k = 7):
      as in v0 (corrections of the feedforward's coefficients, times
      ``harmonic_scale_nm``; a q current, times ``current_scale_a``).

    An action of the wrong shape, non-finite or outside [-1, 1] raises ValueError.

    ## Observation Space

    ``Box(float32)``, what the drive senses at the end of the step, clipped to
    [-10, 10] (typical ranges: base controller at the resonances of randomised
    motors, README "StepperDamp-v1"):

    | idx | name | meaning (unit) |
    |-----|------|----------------|
    | 0 | position_error | (theta_cmd - encoder angle) / position_unit_rad |
    | 1 | velocity_error | (w_cmd - velocity estimate) / velocity_unit_rad_s |
    | 2-7 | sin_x .. cos_4x | sin, cos of the electrical angle x, 2x, 4x |
    | 8 | speed_command | w_cmd / (2*pi * predicted h = 1 resonance speed) |
    | 9 | id_error | (measured id - id command) / current_unit_a |
    | 10 | iq | measured iq / current_unit_a |
    | 11- | last_action_* | the last action (k entries) |

    Then, with ``history=h``, the position and velocity error of the h steps
    before (``position_error_1, velocity_error_1, ...``, newest first; zeros
    before the first step). With ``context="visible"``, what the drive knows
    of the episode (CARL's visible context): the held speed over the three
    predicted resonance speeds of the nominal motor (h = 4, 2, 1), and the
    detent model of ``estimate`` as sin/cos coefficients of x, 2x, 4x over Kd
    (before ff-delay-comp's compensation; shown with ``base_controller="none"``
    too). Context entries are clipped to [-10, 10] like the others. With ``privileged=True`` the true position and velocity error (same
    units) and ia, ib / holding current. Names:
    ``stepdamp_env.env.observation_names_v1(...)``.

    ## Rewards

    ``-min(rms(w_cmd - w)/velocity_unit_rad_s, 10) - current_penalty *
    min(rms(iq_injected)/current_unit_a, 10)``, RMS over the step's PWM
    periods of the true speed error and of the injected q current (base,
    residual and law). With the base controller at a resonance it is of
    order -0.1 per step (median -0.06, mean -0.12, 5th percentile -0.45 on
    randomised motors). Summed over the held part of an episode, minus the
    return divided by the number of steps is about the ripple RMS in
    velocity units; the leaderboard's headline divides that ripple by the
    undamped drive's. A terminating step also loses 10*(1 + current_penalty)
    for every step left in the episode.

    ## Episode End

    Terminated on step loss (lag past one full step), an unsafe phase current
    (past ``current_limit_factor`` times the holding current) or a non-finite
    state. Truncated after ``round(episode_s * agent_hz)`` steps (400); the
    scalar env raises ``gymnasium.error.ResetNeeded`` on a step after either.
    ``info`` (SI units): ``velocity_error_rms_rad_s``, ``lag_rad``,
    ``injected_current_rms_a``, ``damping_current_rms_a``, ``peak_current_a``,
    ``step_loss``, ``overcurrent``, ``time_s``; reset info ``speed_rps``,
    ``target_harmonic``.
    """ + OPTIONS_DOC_V1 + """
    ## Version History

    * v1 (package 0.19): option ``reward_window`` (default "episode": as before).
    * v3 (package 0.18): v2 with ``action_mode`` "gain-phase" (the damping
      law's gain and phase, two numbers; no action of the box lost steps on the
      tested draws): ``gym.make("StepperDamp-v3")``.
    * v2 (package 0.18): this class with the defaults of the committed per-step
      agents' task (``registration.V2_DEFAULTS``: motors drawn around the
      presets, ``agent_hz`` 100, ``history`` 4, ``context`` "visible",
      ``estimate`` "exact", ``resonance_prob`` 0.75, ``episode_s`` 1.0, the
      protocol's sensors): ``gym.make("StepperDamp-v2")``.
    * v1 (package 0.6): option ``nominal`` (default None: as before).
    * v1 (package 0.3): units the motor sets, history, visible context, a
      dimensionless reward, the damping-gains law in the kernel, ff-delay-comp
      as a base controller, the env's own time limit.
    * v0: frozen (``StepperDamp-v0``).
    """


class StepperDampV1Env(OneDriveEnv, gym.Env):
    __doc__ = _DOC

    #: The id its messages name.
    env_id = ENV_ID_V1

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, render_mode: str | None = None, **options: Any) -> None:
        mode = check_render_mode(render_mode, self.metadata["render_modes"])
        self.options = EnvOptionsV1.from_kwargs(options, self.env_id)
        self.task = TaskV1(self.options)
        self._attach(self.task, mode)

    @classmethod
    def task_of(cls, **options: Any) -> TaskV1:
        """The task of ``cls(**options)`` (the options checked), without the env:
        what :meth:`.engine.StepperDampBatch.of_tasks` builds batches of."""
        return TaskV1(EnvOptionsV1.from_kwargs(options, cls.env_id))

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self._check_steppable()
        d = self._drives
        d.load(action, (self.task.act_dim,))
        terminated, truncated = d.advance_one(self._trace)
        if self.options.measure_from_s is not None:
            merge_accumulators(self._run_acc, d.acc[0])
        if self.render_mode is not None:
            self._frames.append(trace_rows(self._trace))
        term, trunc = terminated, truncated
        if term:
            self._ended = "terminated (step loss, over-current or a non-finite state)"
        elif trunc:
            self._ended = "been truncated (time limit)"
        return d.obs[0].copy(), float(d.out[0, V.OUT.REWARD]), term, trunc, d.info(0)

    def render(self) -> np.ndarray | None:
        """RGB array (H, W, 3) of velocity error and currents of the episode so far."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass "
                            "render_mode='rgb_array' to the constructor")
            return None
        return render_episode(self._frames, f"{self.env_id}: {self.speed_rps:.3g} rev/s, "
                              f"{self.options.mode}, {self.options.base_controller}")


class StepperDampV1VectorEnv(DriveVectorEnv):
    __doc__ = """Native vectorised ``StepperDamp-v1``: N drives stepped by one compiled call.

    Spaces, rewards and episode ends are those of :class:`StepperDampV1Env`; the
    same seeds give the same episodes as N scalar envs reset with ``seed + i``,
    step for step. Drives reset automatically: ``autoreset_mode`` NEXT_STEP
    (default: the step after an episode end resets that drive, its action is
    ignored, reward 0) or SAME_STEP (``infos["final_obs"]``,
    ``infos["final_info"]``, an object array of the scalar env's info dicts).
    ``infos`` holds the scalar env's step info as arrays with ``_key`` masks
    (frozen: ``StepperDamp-v2``'s vector env gives ``SyncVectorEnv``'s infos).
    Rendering: None only.
    ``num_threads`` (default 1) spreads each step's drives over that many of
    numba's threads (``kernel.step_batch_parallel``, or groups of 32 drives in
    lanes); a drive's numbers are the same for any count. ``simd`` steps the
    drives in SIMD lanes, LANES (32) at a
    time (:mod:`stepdamp_env.lanes`): the same numbers, 2.3-4x faster per core
    for open-loop current-mode drives with the low-pass velocity estimate (the
    default options); None (default): on from 32 drives up where numba compiles
    for AVX2 or wider.
    """ + OPTIONS_DOC_V1

    #: The id its messages name.
    env_id = ENV_ID_V1
    out_layout = V.OUT
    step_infos = STEP_INFOS[:3] + (("damping_current_rms_a", "LAW_RMS", False),) + STEP_INFOS[3:]

    def __init__(self, num_envs: int = 1, *,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 render_mode: str | None = None, num_threads: int = 1,
                 simd: bool | None = None, **options: Any) -> None:
        mode = check_vector_args(num_envs, autoreset_mode, render_mode)
        threads = check_num_threads(num_threads)
        simd_on = check_simd(simd, int(num_envs))
        self.options = EnvOptionsV1.from_kwargs(options, self.env_id)
        self.task = TaskV1(self.options)
        drives = self._attach(self.task, num_envs, mode, threads, self.options.measure_from_s)
        drives.simd = simd_on

    @property
    def simd(self) -> bool:
        """Whether the drives step in SIMD lanes (set when built)."""
        return self._drives.simd

    @property
    def speeds_rps(self) -> np.ndarray:
        """The held command speed of each drive's current episode (rev/s); a copy."""
        return self._drives.speeds_rps.copy()

    def physics_infos(self, out: np.ndarray) -> dict[str, np.ndarray]:
        return {**super().physics_infos(out),
                "time_s": self._drives.t * self.task.seconds_per_step}


def _with_defaults(defaults: dict[str, Any], options: dict[str, Any]) -> dict[str, Any]:
    """A version's defaults with the given options on top."""
    return {**copy.deepcopy(defaults), **options}


def _warn_reserved(seed: Any, env_id: str) -> None:
    """One warning where a v2 or later env is reset with seeds the benchmark scores with."""
    seeds = seed if isinstance(seed, (list, tuple)) else [seed]
    high = [s for s in seeds if isinstance(s, (int, np.integer)) and s >= RESERVED_SEEDS_FROM]
    if high:
        warnings.warn(f"{env_id} reset with seed {int(high[0])}: seeds from "
                      f"{RESERVED_SEEDS_FROM:,} draw the motors stepdamp-bench scores; train "
                      "on seeds below it (rl-baselines3-zoo: pass --seed)", stacklevel=3)


class StepperDampV2Env(StepperDampV1Env):
    __doc__ = """``StepperDamp-v2``: :class:`StepperDampV1Env` whose defaults are the task
    the committed per-step agents learn (:data:`.registration.V2_DEFAULTS`):
    motors drawn around the presets, resonant speeds with probability 0.75, the
    damping law's eight gains set every 10 ms (``agent_hz`` 100) with four past
    errors (``history``) and the visible context, the exact detent model in the
    feedforward, the protocol's sensors (4000-count encoder, 0.01 A current
    noise), 1 s episodes (100 steps). A given option replaces its default
    (``overrides`` as a whole). Spaces, reward and termination are v1's."""

    env_id = ENV_ID_V2
    #: The version's defaults; a given option replaces one.
    defaults: dict = V2_DEFAULTS

    def __init__(self, render_mode: str | None = None, **options: Any) -> None:
        super().__init__(render_mode=render_mode, **_with_defaults(self.defaults, options))

    @classmethod
    def task_of(cls, **options: Any) -> TaskV1:
        return super().task_of(**_with_defaults(cls.defaults, options))

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        _warn_reserved(seed, self.env_id)
        return super().reset(seed=seed, options=options)


class StepperDampV2VectorEnv(StepperDampV1VectorEnv):
    __doc__ = """Native vectorised ``StepperDamp-v2``: :class:`StepperDampV1VectorEnv`
    with v2's defaults (:class:`StepperDampV2Env`), and infos exactly as
    Gymnasium's ``SyncVectorEnv`` gives them in both autoreset modes: each key an
    array over the drives with its ``_key`` mask; a drive that starts over gives
    its reset info (``speed_rps``, ``target_harmonic``) instead of its step's;
    with SAME_STEP ``final_info`` is a dict of such arrays and ``final_obs`` an
    object array (``tests/test_vector_infos.py``)."""

    env_id = ENV_ID_V2
    defaults: dict = V2_DEFAULTS
    sync_infos = True

    def __init__(self, num_envs: int = 1, **kwargs: Any) -> None:
        vector = {k: kwargs.pop(k) for k in ("autoreset_mode", "render_mode", "num_threads",
                                             "simd") if k in kwargs}
        super().__init__(num_envs, **vector, **_with_defaults(self.defaults, kwargs))

    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        _warn_reserved(seed, self.env_id)
        return super().reset(seed=seed, options=options)


class StepperDampV3Env(StepperDampV2Env):
    __doc__ = """``StepperDamp-v3``: :class:`StepperDampV2Env` with an action whose box
    lost no steps on the tested draws (:data:`.registration.V3_DEFAULTS`): ``action_mode`` "gain-phase", the
    velocity-feedback law's gain and phase, ``Box(-1, 1, (2,))``:
    kv = g*cos(phi), kp = -g*sin(phi) (the "damping-gains" pair) with
    g = max(gain, 0) and phi = phase * pi/4. The zero action is the base
    controller; gain 1 adds a damping ratio of 0.5 to the nominal rotor; a
    positive phase leads. Everything else is v2's. Why: with v2's eight gains,
    library-default exploration noise loses steps (``docs/envs.md``)."""

    env_id = ENV_ID_V3
    defaults: dict = V3_DEFAULTS


class StepperDampV3VectorEnv(StepperDampV2VectorEnv):
    __doc__ = """Native vectorised ``StepperDamp-v3`` (:class:`StepperDampV3Env`), with
    ``SyncVectorEnv``'s infos as :class:`StepperDampV2VectorEnv`."""

    env_id = ENV_ID_V3
    defaults: dict = V3_DEFAULTS

