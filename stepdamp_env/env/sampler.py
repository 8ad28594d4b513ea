"""``StepperDamp-v0``'s task over the engine (:mod:`.engine`): episode sampling,
observation, action loading, reward and termination.

:class:`EpisodeSampler` is public and read-only: ``env.sampler`` tells a
baseline or an agent the nominal system, the action layout and its physical
scales, the decision period and the model the base controller uses in an
episode, without reaching into the environment. v1's task draws its episodes
with one too, so a seed gives the same motor and speed in v0 and v1.
"""

from __future__ import annotations

import copy
import functools
import math
from typing import Any

import numpy as np
from gymnasium import spaces

from .. import fixedmath as fm
from .. import kernel as K
from ..params import RESONANCE_HARMONICS, FeedforwardModel, SystemParams, predicted_resonances
from ..motorfile import load_system
from ..simulation import (RAMPS, RunSettings, SpeedProfile, build_config, check_integrable,
                          initial_state, ramps_distance_rev)
from . import compiled as C
from .engine import DriveBatch, EnvTask
from .layout import ACTION_NAMES, OBS
from .options import (PHASE_FIELDS, RANDOMIZABLE_FIELDS, EnvOptions, default_action_scales,
                      periods_per_agent_step)

__all__ = ["EpisodeSampler"]

TWO_PI = 2.0 * math.pi


# The spaces of a layout, made once (gymnasium's Box checks its bounds: a tenth of
# an env's construction); each env gets its own copy (its own random generator)
# of bounds that are read-only.
@functools.lru_cache(maxsize=None)
def _observation_box(obs_dim: int, act_dim: int) -> spaces.Box:
    high = np.full(obs_dim, C.OBS_BOUND, dtype=np.float32)
    high[OBS.sin_x:OBS.cos_4x + 1] = 1.0
    high[len(C.OBS):len(C.OBS) + act_dim] = 1.0
    return _read_only(spaces.Box(-high, high, dtype=np.float32))


@functools.lru_cache(maxsize=None)
def _action_box(act_dim: int) -> spaces.Box:
    return _read_only(spaces.Box(-1.0, 1.0, shape=(act_dim,), dtype=np.float32))


def _read_only(box: spaces.Box) -> spaces.Box:
    box.low.flags.writeable = False
    box.high.flags.writeable = False
    return box


class EpisodeSampler(EnvTask):
    """v0's task: draws one episode (system, speed) from a Generator and writes
    its rows; observes, loads actions and reports a step (:class:`.engine.EnvTask`).

    Read-only attributes (properties): ``options``, ``nominal`` (the
    un-randomised system), ``randomization``, ``n_periods`` (PWM periods per
    agent step), ``seconds_per_step``, ``action_mode``, ``action_names``,
    ``action_scales`` (physical size of each action entry at 1.0: N*m or A),
    ``harmonic_scale_nm``, ``current_scale_a``, ``act_dim``, ``obs_dim``,
    ``speed_scale`` (rad/s), ``nominal_estimate``.
    """

    def __init__(self, options: EnvOptions) -> None:
        self._options = o = options
        self._privileged = bool(o.privileged)
        self._nominal: SystemParams = load_system(o.motor, o.overrides)
        # Refused at construction, not at the first reset (a randomised draw can
        # still be refused at its reset).
        top = o.speed_rps if o.speed_rps is not None else min(100.0, max(
            o.speed_range_rps[1], (1.0 + o.resonance_spread)
            * max(self._nominal.predicted_resonances_rps().values())))
        check_integrable(self._nominal, o.substeps, top)
        self._ranges = o.randomization
        drive = self._nominal.drive
        self._n_periods = periods_per_agent_step(drive.pwm_hz, o.agent_hz)
        default_harmonic, default_current = default_action_scales(self._nominal)
        harmonic_scale = default_harmonic if o.harmonic_scale_nm is None else o.harmonic_scale_nm
        current_scale = default_current if o.current_scale_a is None else o.current_scale_a
        self._harmonic_scale_nm = float(harmonic_scale)
        self._current_scale_a = float(current_scale)
        # The kernel's inputs ds1..dc4 and iq are adjacent (U_DS1..U_IQ).
        if o.action_mode == "harmonic":
            self._offset, scales = K.INPUT.DS1, (harmonic_scale,) * 6
        elif o.action_mode == "current":
            self._offset, scales = K.INPUT.IQ, (current_scale,)
        else:
            self._offset, scales = K.INPUT.DS1, (harmonic_scale,) * 6 + (current_scale,)
        self._action_scales = tuple(float(x) for x in scales)
        self._act_dim = len(scales)
        self._obs_dim = len(C.OBS) + self._act_dim + (len(C.PRIVILEGED) if o.privileged else 0)
        hi_speed = max(o.speed_range_rps[1], o.speed_rps or 0.0)
        self._speed_scale = TWO_PI * hi_speed
        self._nominal_estimate = FeedforwardModel.from_motor(self._nominal.motor)
        self._seconds_per_step = self._n_periods / drive.pwm_hz

    # -- read-only view ----------------------------------------------------------
    options = property(lambda self: self._options, doc="The validated options.")
    nominal = property(lambda self: self._nominal, doc="The un-randomised system.")
    n_periods = property(lambda self: self._n_periods, doc="PWM periods per agent step.")
    seconds_per_step = property(lambda self: self._seconds_per_step,
                                doc="Simulated time of one agent step (s).")
    action_scales = property(lambda self: self._action_scales,
                             doc="Physical size of each action entry at 1.0 (N*m or A).")
    harmonic_scale_nm = property(lambda self: self._harmonic_scale_nm,
                                 doc="Size of a harmonic action entry at 1.0 (N*m).")
    current_scale_a = property(lambda self: self._current_scale_a,
                               doc="Size of a q-current action entry at 1.0 (A).")
    act_dim = property(lambda self: self._act_dim, doc="Number of action entries.")
    obs_dim = property(lambda self: self._obs_dim, doc="Number of observation entries.")
    input_offset = property(lambda self: self._offset,
                            doc="Kernel input (U_*) that the first action entry drives.")
    speed_scale = property(lambda self: self._speed_scale,
                           doc="Normaliser of the speed-command observation (rad/s).")
    nominal_estimate = property(lambda self: self._nominal_estimate,
                                doc="The nominal motor's feedforward model.")

    @property
    def randomization(self) -> dict[str, tuple[float, float]]:
        """The randomisation ranges in use ({} when off); a copy."""
        return dict(self._ranges)

    @property
    def action_mode(self) -> str:
        return self._options.action_mode

    @property
    def action_names(self) -> tuple[str, ...]:
        """Names of the action entries (:data:`.layout.ACTION_NAMES`)."""
        return ACTION_NAMES[self._options.action_mode]

    def _set_estimate(self) -> FeedforwardModel | None:
        """The model the options name; None for "exact" (each episode's plant)."""
        est = self._options.estimate
        if isinstance(est, FeedforwardModel):
            return est
        return self._nominal_estimate if est == "nominal" else None

    def episode_estimate(self, system: SystemParams) -> FeedforwardModel:
        """The model the base controller uses in an episode of ``system``."""
        est = self._set_estimate()
        return est if est is not None else FeedforwardModel.from_motor(system.motor)

    # -- spaces ------------------------------------------------------------------
    def observation_space(self) -> spaces.Box:
        return copy.copy(_observation_box(self._obs_dim, self._act_dim))

    def action_space(self) -> spaces.Box:
        return copy.copy(_action_box(self._act_dim))

    # -- drawing -----------------------------------------------------------------
    def draw_system(self, rng: np.random.Generator) -> SystemParams:
        if not self._ranges:
            return self._nominal
        m = self._nominal.motor
        changes: dict[str, float] = {}
        for name in RANDOMIZABLE_FIELDS:
            if name in self._ranges:
                lo, hi = self._ranges[name]
                x = float(rng.uniform(lo, hi))
                changes[name] = x if name in PHASE_FIELDS else getattr(m, name) * x
        return self._nominal.replace(**changes)

    def draw_speed(self, rng: np.random.Generator, system: SystemParams) -> tuple[float, int]:
        """(speed in rev/s, targeted detent harmonic h or 0 for a uniform draw)."""
        o = self._options
        if o.speed_rps is not None:
            return float(o.speed_rps), 0
        if rng.random() < o.resonance_prob:
            h = RESONANCE_HARMONICS[int(rng.integers(len(RESONANCE_HARMONICS)))]
            f = predicted_resonances(system)[h]
            spread = o.resonance_spread
            # Clipped to what a speed command may be (rev/s); in range it is untouched.
            return float(min(max(f * rng.uniform(1.0 - spread, 1.0 + spread), 1e-6), 100.0)), h
        lo, hi = o.speed_range_rps
        return float(rng.uniform(lo, hi)), 0

    def draw_move(self, rng: np.random.Generator) -> tuple[str, float]:
        """(ramp, (peak) acceleration in rev/s^2) of an episode: the options', or
        drawn where they ask (``ramp`` "any", ``accel_range_rps2``), ramp first;
        nothing is drawn otherwise."""
        o = self._options
        ramp = RAMPS[int(rng.integers(len(RAMPS)))] if o.ramp not in RAMPS else o.ramp
        accel = float(o.accel_rps2)
        if o.accel_range_rps2 is not None:
            lo, hi = (float(v) for v in o.accel_range_rps2)
            # fixedmath's exp and log: libm's last bit differs between CPUs.
            accel = float(fm.exp(rng.uniform(fm.log(lo), fm.log(hi))))
        return ramp, accel

    def profile(self, speed_rps: float, ramp: str | None = None,
                accel_rps2: float | None = None) -> SpeedProfile:
        """The episode's command at ``speed_rps`` (the options' profile), with the
        ramp and acceleration :meth:`draw_move` gave (default: the options');
        with ``cruise_s`` the distance is both ramps plus the cruise (rev)."""
        o = self._options
        ramp = o.ramp if ramp is None else ramp
        accel = float(o.accel_rps2 if accel_rps2 is None else accel_rps2)
        distance = o.distance_rev
        if o.cruise_s is not None:
            distance = ramps_distance_rev(speed_rps, accel, ramp) + speed_rps * float(o.cruise_s)
        return SpeedProfile(speed_rps=speed_rps, accel_rps2=accel, kind=o.profile,
                            distance_rev=distance, ramp=ramp)

    def move_info(self, ramp: str, accel_rps2: float) -> dict[str, Any]:
        """What an episode drew of its move, for the reset info ({} if nothing)."""
        o = self._options
        out: dict[str, Any] = {}
        if o.ramp not in RAMPS:
            out["ramp"] = ramp
        if o.accel_range_rps2 is not None:
            out["accel_rps2"] = accel_rps2
        return out

    def window(self) -> tuple[float, float]:
        """The core's metrics window (start, end) in s. Without measure_from_s
        none: the env reads per-step sums only, and the window's lock-in sums
        would cost a sincos per PWM period."""
        o = self._options
        return (math.inf if o.measure_from_s is None else float(o.measure_from_s),
                math.inf if o.measure_until_s is None else float(o.measure_until_s))

    # -- the task ------------------------------------------------------------------
    law_actions = False
    max_episode_steps = None            # the time limit is the env's (gym's TimeLimit)
    param_size = len(C.PARAM)
    out_layout = C.OUT
    extra_rows: dict[str, tuple[int, Any]] = {}
    privileged = property(lambda self: bool(self._options.privileged),
                          doc="Whether the observation ends with the privileged block.")

    def new_episode(self, rng: np.random.Generator, drives: DriveBatch, i: int
                    ) -> tuple[dict[str, Any], SystemParams]:
        """Draw an episode into drive i's rows; returns (reset info, system)."""
        c, s, par = drives.c[i], drives.s[i], drives.par[i]
        o = self._options
        system = self.draw_system(rng)
        speed, h = self.draw_speed(rng, system)
        estimate = self._set_estimate()     # None: the core uses the plant's exact values
        # The sensor noise of the episode: its own stream, drawn after the speed.
        noise_seed = int(rng.integers(2 ** 53))
        ramp, accel = self.draw_move(rng)
        settings = RunSettings(mode=o.mode, base_controller=o.base_controller, substeps=int(o.substeps),
                               estimate=estimate, velocity_estimator=o.velocity_estimator,
                               noise_seed=noise_seed)
        c[:] = build_config(system, self.profile(speed, ramp, accel), settings, *self.window())
        s[:] = initial_state(c)
        par[C.PARAM.FULL_STEP] = system.motor.full_step_rad
        par[C.PARAM.LAG_LIMIT] = o.lag_limit_steps * system.motor.full_step_rad
        par[C.PARAM.W_REF] = TWO_PI * speed
        par[C.PARAM.HOLD] = system.drive.holding_current
        par[C.PARAM.SPEED_SCALE] = self._speed_scale
        par[C.PARAM.I_LIMIT] = o.current_limit_factor * system.drive.holding_current
        par[C.PARAM.CUR_PEN] = o.current_penalty
        par[C.PARAM.TERM_PEN] = o.termination_penalty
        par[C.PARAM.ACT_SCALE:C.PARAM.ACT_SCALE + self._act_dim] = self._action_scales
        return {"speed_rps": speed, "target_harmonic": h, **self.move_info(ramp, accel)}, system

    def observe(self, drives: DriveBatch, rows: slice | None) -> None:
        d = drives.view(rows)
        C.observe(d.s, d.acc, d.a, d.par, C.KERNEL_INDEX, self._privileged, d.obs, d.out)

    def load(self, drives: DriveBatch, a: np.ndarray) -> int:
        return C.load_actions(a, drives.u, drives.acc, drives.par, self._offset)

    def time_s(self, drives: DriveBatch) -> np.ndarray:
        # v0 counts time in PWM periods of the kernel (published runs end on it).
        return drives.s[:, K.STATE.PERIOD] * drives.c[:, K.CONFIG.DT]

    def step_info(self, drives: DriveBatch, i: int) -> dict[str, Any]:
        return C.physics_info(drives.out[i])
