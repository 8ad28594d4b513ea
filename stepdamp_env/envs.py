"""Gymnasium environments of StepperDamp: ``StepperDamp-v0`` (scalar and native vector).

The agent acts as a residual on top of a base controller (the patent's harmonic
feedforward, or none) of one hybrid stepper drive simulated by
:mod:`stepdamp_env.kernel`. The PWM period, current loops and plant keep running
at ``pwm_hz`` (20 kHz for the presets) inside one agent step; the agent decides at
``agent_hz`` (1 kHz by default) and its action is held for the step.

>>> import gymnasium as gym, stepdamp_env
>>> env = gym.make("StepperDamp-v0")                        # doctest: +SKIP
>>> venv = gym.make_vec("StepperDamp-v0", num_envs=64)      # doctest: +SKIP

The vector implementation (:class:`StepperDampVectorEnv`) advances all its drives
with one call of :func:`stepdamp_env.kernel.run_batch`; for the same seeds it
agrees with the scalar one (:class:`StepperDampEnv`) step for step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numba import njit

from . import kernel as K
from .params import (FeedforwardModel, ParameterError, SystemParams, load_system,
                     predicted_resonances)
from .simulation import (VELOCITY_ESTIMATORS, RunMetrics, RunSettings, SpeedProfile,
                         build_config, initial_state, merge_accumulators,
                         metrics_from_accumulators, new_accumulators)

__all__ = [
    "ENV_ID",
    "DEFAULT_EPISODE_STEPS",
    "DEFAULT_RANDOMIZATION",
    "EnvOptions",
    "StepperDampEnv",
    "StepperDampVectorEnv",
    "register_envs",
]

ENV_ID = "StepperDamp-v0"
# 0.3 s at the default 1 kHz: the longest default ramp (3 rev/s at 50 rev/s^2)
# takes 60 ms, which leaves at least 240 ms of held speed per episode.
DEFAULT_EPISODE_STEPS = 300
TWO_PI = 2.0 * math.pi
# Bound of the scaled observations (other than sin/cos and the last action):
# states past it are clipped; a healthy drive stays well inside.
OBS_BOUND = 10.0

# Default domain randomisation: multiplicative factors drawn uniformly in
# [low, high] for the magnitudes, absolute values (rad) drawn uniformly for the phases.
DEFAULT_RANDOMIZATION: dict[str, tuple[float, float]] = {
    "R": (0.8, 1.25),
    "L": (0.8, 1.25),
    "Km": (0.85, 1.15),
    "J": (0.5, 2.0),
    "Kd1": (0.5, 1.5),
    "Kd2": (0.5, 1.5),
    "Kd4": (0.5, 1.5),
    "Fs": (0.5, 1.5),
    "phi1": (-math.pi, math.pi),
    "phi2": (-math.pi, math.pi),
}
_SCALED_FIELDS = ("R", "L", "Km", "J", "D", "Kd1", "Kd2", "Kd4", "Fs")
_PHASE_FIELDS = ("phi1", "phi2")
_RANDOM_ORDER = _SCALED_FIELDS + _PHASE_FIELDS     # fixed draw order: determinism

_MODES = ("open-loop", "servo")
_BASE_CONTROLLERS = ("patent-ff", "none")
_ACTION_MODES = ("harmonic", "current", "harmonic+current")


# ---------------------------------------------------------------------------
# Options
# ---------------------------------------------------------------------------
def _bad(name: str, value: Any, allowed: str) -> ParameterError:
    return ParameterError(f"{name}={value!r} is outside its allowed range {allowed}")


def _number(name: str, value: Any, low: float, high: float, *, low_open: bool = False,
            high_open: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ParameterError(f"{name} must be a number, got {value!r}")
    v = float(value)
    ok = math.isfinite(v) and (v > low if low_open else v >= low) and \
        (v < high if high_open else v <= high)
    if not ok:
        raise _bad(name, value, f"{'(' if low_open else '['}{low}, {high}{')' if high_open else ']'}")
    return v


def _choice(name: str, value: Any, choices: Sequence[str]) -> str:
    if value not in choices:
        raise ParameterError(f"{name}={value!r} is not one of {list(choices)}")
    return value


def _pair(name: str, value: Any) -> tuple[float, float]:
    try:
        low, high = value
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be a (low, high) pair, got {value!r}") from None
    return _number(f"{name}[0]", low, -1e9, 1e9), _number(f"{name}[1]", high, -1e9, 1e9)


@dataclass(frozen=True)
class EnvOptions:
    """Validated constructor options of ``StepperDamp-v0``; see :class:`StepperDampEnv`."""

    motor: Any = "patent"
    overrides: Mapping[str, Any] | None = None
    randomize: bool | Mapping[str, tuple[float, float]] = False
    mode: str = "open-loop"
    base_controller: str = "patent-ff"
    estimate: str | FeedforwardModel = "exact"
    speed_rps: float | None = None
    speed_range_rps: tuple[float, float] = (0.25, 3.0)
    resonance_prob: float = 0.5
    resonance_spread: float = 0.1
    accel_rps2: float = 50.0
    action_mode: str = "harmonic"
    agent_hz: float = 1000.0
    harmonic_scale_nm: float | None = None
    current_scale_a: float | None = None
    current_penalty: float = 0.1
    termination_penalty: float = 100.0
    current_limit_factor: float = 3.0
    privileged: bool = False
    substeps: int = 1
    velocity_estimator: str = "lowpass"
    measure_from_s: float | None = None

    @classmethod
    def from_kwargs(cls, kwargs: Mapping[str, Any]) -> "EnvOptions":
        """Options from keyword arguments; unknown names raise ``ValueError``."""
        allowed = list(cls.__dataclass_fields__)
        unknown = sorted(set(kwargs) - set(allowed))
        if unknown:
            raise ParameterError(f"unknown option(s) {unknown} for {ENV_ID}; allowed: {allowed}")
        return cls(**kwargs)

    def __post_init__(self) -> None:
        _choice("mode", self.mode, _MODES)
        _choice("base_controller", self.base_controller, _BASE_CONTROLLERS)
        _choice("action_mode", self.action_mode, _ACTION_MODES)
        if not isinstance(self.estimate, FeedforwardModel):
            if self.estimate not in ("exact", "nominal"):
                raise ParameterError(f"estimate={self.estimate!r} is not one of ['exact', "
                                     "'nominal'] or a FeedforwardModel")
        if self.speed_rps is not None:
            _number("speed_rps", self.speed_rps, 0.0, 100.0, low_open=True)
        lo, hi = _pair("speed_range_rps", self.speed_range_rps)
        if not 0.0 < lo <= hi <= 100.0:
            raise _bad("speed_range_rps", self.speed_range_rps, "0 < low <= high <= 100 (rev/s)")
        _number("resonance_prob", self.resonance_prob, 0.0, 1.0)
        _number("resonance_spread", self.resonance_spread, 0.0, 0.9)
        _number("accel_rps2", self.accel_rps2, 0.0, 1e5, low_open=True)
        _number("agent_hz", self.agent_hz, 0.0, 1e6, low_open=True)
        if self.harmonic_scale_nm is not None:
            _number("harmonic_scale_nm", self.harmonic_scale_nm, 0.0, 100.0, low_open=True)
        if self.current_scale_a is not None:
            _number("current_scale_a", self.current_scale_a, 0.0, 100.0, low_open=True)
        _number("current_penalty", self.current_penalty, 0.0, 1e6)
        _number("termination_penalty", self.termination_penalty, 0.0, 1e9)
        _number("current_limit_factor", self.current_limit_factor, 1.0, 100.0, low_open=True)
        if not isinstance(self.privileged, (bool, np.bool_)):
            raise ParameterError(f"privileged must be True or False, got {self.privileged!r}")
        _choice("velocity_estimator", self.velocity_estimator, tuple(VELOCITY_ESTIMATORS))
        if self.measure_from_s is not None:
            _number("measure_from_s", self.measure_from_s, 0.0, 1e6)
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, (int, np.integer)) \
                or not 1 <= self.substeps <= 1000:
            raise _bad("substeps", self.substeps, "[1, 1000] (integer)")
        if self.overrides is not None and not isinstance(self.overrides, Mapping):
            raise ParameterError(f"overrides must be a mapping of parameter names to values, "
                                 f"got {self.overrides!r}")
        if not isinstance(self.randomize, (bool, np.bool_)):
            if not isinstance(self.randomize, Mapping):
                raise ParameterError("randomize must be True, False or a mapping "
                                     f"{{field: (low, high)}}, got {self.randomize!r}")
            unknown = sorted(set(self.randomize) - set(_RANDOM_ORDER))
            if unknown:
                raise ParameterError(f"randomize: unknown field(s) {unknown}; allowed: "
                                     f"{list(_RANDOM_ORDER)}")
            for name, rng in self.randomize.items():
                lo, hi = _pair(f"randomize[{name!r}]", rng)
                if name in _PHASE_FIELDS:
                    ok = -TWO_PI <= lo <= hi <= TWO_PI
                    allowed = "-2*pi <= low <= high <= 2*pi (rad)"
                else:
                    ok = 0.0 < lo <= hi <= 100.0
                    allowed = "0 < low <= high <= 100 (factor)"
                if not ok:
                    raise _bad(f"randomize[{name!r}]", rng, allowed)

    @property
    def randomization(self) -> dict[str, tuple[float, float]]:
        """The ranges in use ({} when off)."""
        if isinstance(self.randomize, Mapping):
            return {k: tuple(map(float, v)) for k, v in self.randomize.items()}
        return dict(DEFAULT_RANDOMIZATION) if self.randomize else {}


# ---------------------------------------------------------------------------
# Compiled per-step helpers. They depend on no other module's compiled code
# (the kernel's layout indices come in as an array), so their on-disk cache
# cannot go stale when the kernel changes.
# ---------------------------------------------------------------------------
_jit = njit(cache=True, error_model="numpy")

# Per-drive episode constants (float64 row).
P_FULL_STEP = 0     # one full step (rad)
P_W_REF = 1         # |held command speed| (rad/s): normaliser of velocity errors
P_HOLD = 2          # holding current (A): normaliser of currents
P_SPEED_SCALE = 3   # normaliser of the speed command (rad/s)
P_I_LIMIT = 4       # unsafe phase current (A)
P_CUR_PEN = 5       # weight of the injected-current penalty
P_TERM_PEN = 6      # penalty on termination
P_ACT_SCALE = 7     # first of MAX_ACT_DIM columns: physical size of action entry j = 1.0 (N*m or A)
MAX_ACT_DIM = 7
N_PAR = P_ACT_SCALE + MAX_ACT_DIM

# Per-step physical outputs (float64 row).
O_REWARD = 0
O_VEL_RMS = 1       # rms of w_cmd - w over the step's PWM samples (rad/s)
O_LAG = 2           # max |theta_cmd - theta| over the step (rad)
O_IINJ_RMS = 3      # rms injected q current (feedforward + residual) (A)
O_PEAK_I = 4        # max |phase current| (A)
O_STEP_LOSS = 5
O_OVERCURRENT = 6
O_NONFINITE = 7
O_TERMINATED = 8
N_OUT = 9

# Where the helpers find things in the kernel's state and accumulator vectors.
_IX = np.array([K.S_THETA_FB, K.S_OMEGA_FB, K.S_THETA_CMD, K.S_OMEGA_CMD, K.S_ID_MEAS,
                K.S_IQ_MEAS, K.S_PARK_ANGLE, K.S_THETA, K.S_OMEGA, K.S_IA, K.S_IB,
                K.A_SUM_E2_ALL, K.A_COUNT_ALL, K.A_SUM_IFF2_ALL, K.A_MAX_LAG,
                K.A_MAX_CURRENT], dtype=np.int64)
N_BASE_OBS = 11
N_PRIVILEGED = 4


@_jit
def _clip(x, bound):
    if x > bound:
        return bound
    if x < -bound:
        return -bound
    return x


@_jit
def _store(obs, i, j, value, bound):
    """Write ``value`` clipped to +-bound into obs[i, j]; a non-finite one as 0.
    Returns whether it was non-finite."""
    if not math.isfinite(value):
        obs[i, j] = 0.0
        return True
    obs[i, j] = _clip(value, bound)
    return False


@_jit
def _load_actions(a, u, acc, par, offset):
    """Scale the action rows ``a`` into the input rows ``u`` and zero ``acc``.

    Returns the first row that is not finite or has an entry outside [-1, 1]
    (nothing is changed then), or -1. Rows are indexed in place: per-row views
    would cost more than the arithmetic.
    """
    n, k = a.shape
    for i in range(n):
        for j in range(k):
            x = a[i, j]
            if not (-1.0 <= x <= 1.0):      # also catches NaN
                return i
    for i in range(n):
        for j in range(k):
            u[i, offset + j] = a[i, j] * par[i, 7 + j]
        for j in range(acc.shape[1]):
            acc[i, j] = 0.0
    return -1


@_jit
def _observe(s, acc, a, par, ix, privileged, obs, out):
    """Scaled observation of each drive (row) into ``obs``, its step's physics into ``out``."""
    bound = 10.0
    for i in range(s.shape[0]):
        full_step, w_ref, hold = par[i, 0], par[i, 1], par[i, 2]
        theta_fb, omega_fb = s[i, ix[0]], s[i, ix[1]]
        theta_cmd, omega_cmd = s[i, ix[2]], s[i, ix[3]]
        angle = s[i, ix[6]]
        s1, c1 = math.sin(angle), math.cos(angle)
        s2, c2 = 2.0 * s1 * c1, c1 * c1 - s1 * s1
        s4, c4 = 2.0 * s2 * c2, c2 * c2 - s2 * s2
        vals = (
            (theta_cmd - theta_fb) / full_step,
            (omega_cmd - omega_fb) / w_ref,
            s1, c1, s2, c2, s4, c4,
            omega_cmd / par[i, 3],
            s[i, ix[4]] / hold,
            s[i, ix[5]] / hold,
        )
        nonfinite = False
        for j in range(11):
            nonfinite |= _store(obs, i, j, vals[j], bound)
        k = 11
        for j in range(a.shape[1]):
            obs[i, k] = a[i, j]
            k += 1
        if privileged:
            pv = ((theta_cmd - s[i, ix[7]]) / full_step, (omega_cmd - s[i, ix[8]]) / w_ref,
                  s[i, ix[9]] / hold, s[i, ix[10]] / hold)
            for j in range(4):
                nonfinite |= _store(obs, i, k + j, pv[j], bound)

        n = max(acc[i, ix[12]], 1.0)
        e2 = acc[i, ix[11]] / n
        i2 = acc[i, ix[13]] / n
        lag = acc[i, ix[14]]
        peak = acc[i, ix[15]]
        step_loss = lag > full_step
        overcurrent = peak > par[i, 4]
        # A non-finite plant ends the episode; the reward stays finite.
        if not (math.isfinite(e2) and math.isfinite(i2) and math.isfinite(lag)
                and math.isfinite(peak)):
            nonfinite = True
        terminated = step_loss or overcurrent or nonfinite
        reward = -(e2 / (w_ref * w_ref)) - par[i, 5] * i2 / (hold * hold)
        if not math.isfinite(reward):
            reward = -1.0
        if terminated:
            reward -= par[i, 6]
        out[i, 0] = reward
        out[i, 1] = math.sqrt(e2) if math.isfinite(e2) else math.inf
        out[i, 2] = lag
        out[i, 3] = math.sqrt(i2) if math.isfinite(i2) else math.inf
        out[i, 4] = peak
        out[i, 5] = 1.0 if step_loss else 0.0
        out[i, 6] = 1.0 if overcurrent else 0.0
        out[i, 7] = 1.0 if nonfinite else 0.0
        out[i, 8] = 1.0 if terminated else 0.0


# ---------------------------------------------------------------------------
# Episode construction (shared by both implementations)
# ---------------------------------------------------------------------------
class _EpisodeFactory:
    """Draws one episode (system, speed) from a Generator and writes its arrays."""

    def __init__(self, options: EnvOptions) -> None:
        self.options = o = options
        self.nominal: SystemParams = load_system(o.motor, o.overrides)
        self.ranges = o.randomization
        drive = self.nominal.drive
        ratio = drive.pwm_hz / o.agent_hz
        self.n_periods = int(round(ratio))
        if abs(ratio - self.n_periods) > 1e-9 * ratio or self.n_periods < 1:
            raise ParameterError(
                f"agent_hz={o.agent_hz!r} must divide pwm_hz={drive.pwm_hz!r} into a whole "
                "number (>= 1) of PWM periods per agent step; allowed range: pwm_hz/k, k = 1, 2, ...")
        m = self.nominal.motor
        harmonic_scale = o.harmonic_scale_nm
        if harmonic_scale is None:
            harmonic_scale = 2.0 * max(m.Kd1, m.Kd2, m.Kd4)
            if harmonic_scale <= 0.0:
                harmonic_scale = 0.02 * m.Km * drive.holding_current
        current_scale = o.current_scale_a
        if current_scale is None:
            current_scale = 0.25 * drive.holding_current
        self.harmonic_scale_nm = float(harmonic_scale)
        self.current_scale_a = float(current_scale)
        # The kernel's inputs ds1..dc4 and iq are adjacent (U_DS1..U_IQ).
        if o.action_mode == "harmonic":
            self.offset, scales = K.U_DS1, (harmonic_scale,) * 6
        elif o.action_mode == "current":
            self.offset, scales = K.U_IQ, (current_scale,)
        else:
            self.offset, scales = K.U_DS1, (harmonic_scale,) * 6 + (current_scale,)
        self.act_dim = len(scales)
        self.action_scales = tuple(float(x) for x in scales)
        self.action_scale = self.action_scales[0]
        self.obs_dim = N_BASE_OBS + self.act_dim + (N_PRIVILEGED if o.privileged else 0)
        hi_speed = max(o.speed_range_rps[1], o.speed_rps or 0.0)
        self.speed_scale = TWO_PI * hi_speed
        self.nominal_estimate = FeedforwardModel.from_motor(m)
        self.damping = o.base_controller
        self.seconds_per_step = self.n_periods / drive.pwm_hz

    def observation_space(self) -> spaces.Box:
        n_act = self.act_dim
        high = np.full(self.obs_dim, OBS_BOUND, dtype=np.float32)
        high[2:8] = 1.0
        high[N_BASE_OBS:N_BASE_OBS + n_act] = 1.0
        return spaces.Box(-high, high, dtype=np.float32)

    def action_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, shape=(self.act_dim,), dtype=np.float32)

    def draw_system(self, rng: np.random.Generator) -> SystemParams:
        if not self.ranges:
            return self.nominal
        m = self.nominal.motor
        changes: dict[str, float] = {}
        for name in _RANDOM_ORDER:
            if name in self.ranges:
                lo, hi = self.ranges[name]
                x = float(rng.uniform(lo, hi))
                changes[name] = x if name in _PHASE_FIELDS else getattr(m, name) * x
        return self.nominal.replace(**changes)

    def draw_speed(self, rng: np.random.Generator, system: SystemParams) -> tuple[float, int]:
        """(speed in rev/s, targeted detent harmonic h or 0 for a uniform draw)."""
        o = self.options
        if o.speed_rps is not None:
            return float(o.speed_rps), 0
        if rng.random() < o.resonance_prob:
            h = (4, 2, 1)[int(rng.integers(3))]
            f = predicted_resonances(system)[h]
            spread = o.resonance_spread
            return float(min(f * rng.uniform(1.0 - spread, 1.0 + spread), 100.0)), h
        lo, hi = o.speed_range_rps
        return float(rng.uniform(lo, hi)), 0

    def new_episode(self, rng: np.random.Generator, c: np.ndarray, s: np.ndarray,
                    par: np.ndarray) -> tuple[dict[str, Any], SystemParams]:
        """Draw an episode into the rows ``c``, ``s``, ``par``; returns (reset info, system)."""
        o = self.options
        system = self.draw_system(rng)
        speed, h = self.draw_speed(rng, system)
        if isinstance(o.estimate, FeedforwardModel):
            estimate = o.estimate
        elif o.estimate == "nominal":
            estimate = self.nominal_estimate
        else:
            estimate = None                 # the plant's exact values
        # The sensor noise of the episode: its own stream, drawn after the speed.
        noise_seed = int(rng.integers(2 ** 53))
        settings = RunSettings(mode=o.mode, damping=self.damping, substeps=int(o.substeps),
                               estimate=estimate, velocity_estimator=o.velocity_estimator,
                               noise_seed=noise_seed)
        profile = SpeedProfile(speed_rps=speed, accel_rps2=o.accel_rps2)
        # Without measure_from_s no metrics window: the env reads per-step sums
        # only, and the window's lock-in sums would cost a sincos per PWM period.
        window = math.inf if o.measure_from_s is None else float(o.measure_from_s)
        c[:] = build_config(system, profile, settings, window_start_s=window)
        s[:] = initial_state(c)
        par[P_FULL_STEP] = system.motor.full_step_rad
        par[P_W_REF] = TWO_PI * speed
        par[P_HOLD] = system.drive.holding_current
        par[P_SPEED_SCALE] = self.speed_scale
        par[P_I_LIMIT] = o.current_limit_factor * system.drive.holding_current
        par[P_CUR_PEN] = o.current_penalty
        par[P_TERM_PEN] = o.termination_penalty
        par[P_ACT_SCALE:P_ACT_SCALE + self.act_dim] = self.action_scales
        return {"speed_rps": speed, "target_harmonic": h}, system

    def initial_observation(self, s: np.ndarray, par: np.ndarray, obs: np.ndarray) -> None:
        """Observation before the first step into ``obs``; arguments are (1, n) rows."""
        acc = np.zeros((1, K.N_ACC))
        acc[0, K.A_COUNT_ALL] = 1.0
        _observe(s, acc, np.zeros((1, self.act_dim), dtype=np.float32), par, _IX,
                 bool(self.options.privileged), obs, np.zeros((1, N_OUT)))


def _action_error(action: Any, shape: tuple[int, ...]) -> ValueError:
    try:
        arr = np.asarray(action, dtype=np.float64)
        got = f"shape {arr.shape}"
        if arr.shape == shape:
            got += (", non-finite values" if not np.all(np.isfinite(arr))
                    else f", values in [{arr.min():.6g}, {arr.max():.6g}]")
    except (TypeError, ValueError):
        got = f"{type(action).__name__} {action!r}"
    return ValueError(f"action must be finite with shape {shape} and every entry in "
                      f"[-1, 1]; got {got}")


def _as_action(action: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``action`` as a float array of ``shape`` (values are checked by the compiled step)."""
    if type(action) is np.ndarray and action.shape == shape and \
            (action.dtype == np.float32 or action.dtype == np.float64):
        return action
    try:
        arr = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError):
        raise _action_error(action, shape) from None
    if arr.shape != shape:
        raise _action_error(action, shape)
    return np.ascontiguousarray(arr)


_DOC_OPTIONS = """
    ## Arguments

    All are keyword arguments with defaults; an unknown name or a value out of
    its range raises ``ValueError`` naming it.

    * ``motor`` ("patent"): preset name (``stepdamp_env.preset_names()``), path of a
      motor JSON file, flat mapping or ``SystemParams``; ``overrides`` (None): flat
      field overrides applied to it (``SystemParams.replace``).
    * ``randomize`` (False): domain randomisation. ``True`` uses
      ``DEFAULT_RANDOMIZATION``: R and L scaled by U(0.8, 1.25), Km by U(0.85, 1.15),
      J by U(0.5, 2.0), Kd1, Kd2, Kd4 and Fs by U(0.5, 1.5), phases phi1 and phi2
      drawn U(-pi, pi) rad; a mapping ``{field: (low, high)}`` over R, L, Km, J, D,
      Kd1, Kd2, Kd4, Fs (factors) and phi1, phi2 (rad) gives your own ranges. Each
      episode's motor is validated through ``SystemParams``.
    * ``mode`` ("open-loop"): "open-loop" (eqs. 7-8) or "servo" (eqs. 14-15).
    * ``base_controller`` ("patent-ff"): "patent-ff" (harmonic detent feedforward) or
      "none".
    * ``estimate`` ("exact"): the base controller's motor model: "exact" (the
      episode's plant), "nominal" (the un-randomised motor) or a
      ``FeedforwardModel`` (an identified set), to pose model mismatch on purpose.
    * ``speed_rps`` (None): a fixed command speed (rev/s, > 0); None draws one per
      episode: with probability ``resonance_prob`` (0.5) one of the three predicted
      resonant speeds (h = 4, 2, 1, equally likely, of the episode's motor) times
      U(1 - ``resonance_spread``, 1 + ``resonance_spread``) (0.1), else
      U(``speed_range_rps``) ((0.25, 3.0) rev/s).
    * ``accel_rps2`` (50.0): ramp acceleration (rev/s^2) from rest to the command,
      which is then held.
    * ``action_mode`` ("harmonic"): see Action Space.
    * ``agent_hz`` (1000.0): decision rate (Hz); ``pwm_hz/agent_hz`` must be a whole
      number of PWM periods.
    * ``harmonic_scale_nm`` (None -> 2*max(Kd1, Kd2, Kd4) of the nominal motor,
      0.024 N*m for "patent"), ``current_scale_a`` (None -> 0.25*holding current
      of the nominal motor, 0.475 A for "patent"): physical size of action 1.0.
    * ``current_penalty`` (0.1), ``termination_penalty`` (100.0),
      ``current_limit_factor`` (3.0): see Rewards and Episode End.
    * ``privileged`` (False): append the true states to the observation.
    * ``substeps`` (1): RK4 plant steps per PWM period.
    * ``velocity_estimator`` ("lowpass"): the drive's encoder velocity estimate,
      "lowpass" (difference + first-order low-pass, the patent's) or "kalman".
    * ``measure_from_s`` (None; scalar env only): open the simulation core's
      measuring window at this time (s) so that ``env.run_metrics()`` returns the
      core's metrics of the episode (used by the leaderboard).
    * Sensor noise and offsets are motor-file fields (``current_noise_a``,
      ``current_offset_a``, ``current_offset_b``, via ``overrides``); each
      episode draws its own noise seed.
"""


class StepperDampEnv(gym.Env):
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
    """ + _DOC_OPTIONS + """
    ## Version History

    * v0: initial version (``action_mode="harmonic+current"`` added later;
      the other modes are unchanged).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, render_mode: str | None = None, **options: Any) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ParameterError(f"render_mode={render_mode!r} is not one of "
                                 f"{[None] + self.metadata['render_modes']}")
        self.render_mode = render_mode
        self.options = EnvOptions.from_kwargs(options)
        self._factory = f = _EpisodeFactory(self.options)
        self.observation_space = f.observation_space()
        self.action_space = f.action_space()
        self._act_shape = (f.act_dim,)
        self._n = f.n_periods
        self._offset = f.offset
        self._privileged = bool(self.options.privileged)
        self._measuring = self.options.measure_from_s is not None
        # One-row 2-D arrays for the compiled helpers, 1-D views of them for the kernel.
        self._c2 = np.zeros((1, K.N_CONFIG))
        self._s2 = np.zeros((1, K.N_STATE))
        self._acc2 = np.zeros((1, K.N_ACC))
        self._u2 = np.zeros((1, K.N_INPUT))
        self._par2 = np.zeros((1, N_PAR))
        self._a2 = np.zeros((1, f.act_dim))
        self._obs2 = np.zeros((1, f.obs_dim), dtype=np.float32)
        self._out2 = np.zeros((1, N_OUT))
        self._c, self._s, self._acc, self._u = self._c2[0], self._s2[0], self._acc2[0], self._u2[0]
        self._par, self._obs, self._out = self._par2[0], self._obs2[0], self._out2[0]
        self._trace = np.zeros((self._n if render_mode else 0, K.N_TRACE))
        self._history: list[np.ndarray] = []
        self._run_acc = new_accumulators()
        self.system: SystemParams | None = None
        self._speed_rps = 0.0
        self._ready = False

    # -- public read-outs ------------------------------------------------------
    @property
    def drive_state(self) -> np.ndarray:
        """Copy of the kernel's state vector (``kernel.S_*``; SI units)."""
        return self._s.copy()

    @property
    def drive_config(self) -> np.ndarray:
        """Copy of the kernel's configuration vector (``kernel.C_*``) of this episode."""
        return self._c.copy()

    @property
    def seconds_per_step(self) -> float:
        """Simulated time of one agent step (s)."""
        return self._factory.seconds_per_step

    @property
    def time_s(self) -> float:
        """Simulated time since the episode started (s)."""
        return float(self._s[K.S_PERIOD] * self._c[K.C_DT])

    def run_metrics(self) -> RunMetrics:
        """The simulation core's metrics of the episode so far, over the window
        that opens at ``measure_from_s`` (lag, current peak: whole episode).

        Needs ``measure_from_s``; raises ``ValueError`` if the window is empty.
        """
        if not self._measuring:
            raise ParameterError("run_metrics() needs the option measure_from_s")
        if self.system is None:
            raise gym.error.ResetNeeded("call reset() before run_metrics()")
        return metrics_from_accumulators(self._run_acc, self.system, self._speed_rps)

    # -- API ----------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        info, self.system = self._factory.new_episode(self.np_random, self._c, self._s,
                                                      self._par)
        self._u[:] = 0.0
        self._factory.initial_observation(self._s2, self._par2, self._obs2)
        self._history = []
        self._run_acc[:] = 0.0
        self._speed_rps = info["speed_rps"]
        self._ready = True
        return self._obs.copy(), info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._ready:
            raise gym.error.ResetNeeded("call reset() before step()")
        self._a2[0] = _as_action(action, self._act_shape)
        if _load_actions(self._a2, self._u2, self._acc2, self._par2, self._offset) >= 0:
            raise _action_error(action, self._act_shape)
        K.run_periods(self._c, self._s, self._acc, self._u, self._n, self._trace, 1)
        if self._measuring:
            merge_accumulators(self._run_acc, self._acc)
        out = self._out
        _observe(self._s2, self._acc2, self._a2, self._par2, _IX, self._privileged, self._obs2,
                 self._out2)
        if self.render_mode is not None:
            self._record()
        terminated = out[O_TERMINATED] != 0.0
        info = {"velocity_error_rms_rad_s": float(out[O_VEL_RMS]),
                "lag_rad": float(out[O_LAG]),
                "injected_current_rms_a": float(out[O_IINJ_RMS]),
                "peak_current_a": float(out[O_PEAK_I]),
                "step_loss": bool(out[O_STEP_LOSS]), "overcurrent": bool(out[O_OVERCURRENT])}
        return self._obs.copy(), float(out[O_REWARD]), bool(terminated), False, info

    # -- rendering ------------------------------------------------------------------
    def _record(self) -> None:
        tr = self._trace
        # t, velocity error, ia, ib, injected iq: every PWM period of the step.
        self._history.append(np.stack([tr[:, K.T_T], tr[:, K.T_OMEGA_CMD] - tr[:, K.T_OMEGA],
                                       tr[:, K.T_IA], tr[:, K.T_IB], tr[:, K.T_IQ_FF]]))

    def render(self) -> np.ndarray | None:
        """RGB array (H, W, 3) of velocity error and currents of the episode so far."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass "
                            "render_mode='rgb_array' to the constructor")
            return None
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        fig = Figure(figsize=(6.4, 4.8), dpi=80)
        canvas = FigureCanvasAgg(fig)
        ax1, ax2 = fig.subplots(2, 1, sharex=True)
        if self._history:
            h = np.concatenate(self._history, axis=1)
            t_ms = 1e3 * h[0]
            ax1.plot(t_ms, h[1], lw=0.8)
            ax2.plot(t_ms, h[2], lw=0.8, label="ia")
            ax2.plot(t_ms, h[3], lw=0.8, label="ib")
            ax2.plot(t_ms, h[4], lw=0.8, label="iq injected")
            ax2.legend(loc="upper right", fontsize=7)
        speed = self._par[P_W_REF] / TWO_PI
        ax1.set_title(f"{ENV_ID}: {speed:.3g} rev/s, {self.options.mode}", fontsize=9)
        ax1.set_ylabel("w_cmd - w (rad/s)")
        ax2.set_ylabel("current (A)")
        ax2.set_xlabel("t (ms)")
        fig.tight_layout()
        canvas.draw()
        return np.asarray(canvas.buffer_rgba())[..., :3].copy()


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
    """ + _DOC_OPTIONS

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, *, max_episode_steps: int | None = DEFAULT_EPISODE_STEPS,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 render_mode: str | None = None, **options: Any) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) \
                or not 1 <= num_envs <= 1_000_000:
            raise ParameterError(f"num_envs={num_envs!r} is outside its allowed range "
                                 "[1, 1000000] (integer)")
        if max_episode_steps is not None and (
                isinstance(max_episode_steps, bool)
                or not isinstance(max_episode_steps, (int, np.integer)) or max_episode_steps < 1):
            raise ParameterError(f"max_episode_steps={max_episode_steps!r} is outside its "
                                 "allowed range [1, inf) (integer) or None")
        try:
            mode = AutoresetMode(autoreset_mode)
        except ValueError:
            raise ParameterError(f"autoreset_mode={autoreset_mode!r} is not one of "
                                 f"{[m.value for m in AutoresetMode]}") from None
        if mode == AutoresetMode.DISABLED:
            raise ParameterError("autoreset_mode='Disabled' is not supported; allowed: "
                                 "NextStep, SameStep")
        if render_mode is not None:
            raise ParameterError(f"render_mode={render_mode!r}: the vector environment does "
                                 "not render; allowed: None (render a scalar env instead)")
        self.render_mode = None
        self.metadata = {**type(self).metadata, "autoreset_mode": mode}
        self.autoreset_mode = mode
        self.options = EnvOptions.from_kwargs(options)
        if self.options.measure_from_s is not None:
            raise ParameterError("measure_from_s is an option of the scalar env only; allowed "
                                 "here: None")
        self._factory = f = _EpisodeFactory(self.options)
        n = self.num_envs = int(num_envs)
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self.single_observation_space = f.observation_space()
        self.single_action_space = f.action_space()
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self._act_shape = (n, f.act_dim)
        self._steps_per_call = f.n_periods
        self._offset = f.offset
        self._privileged = bool(self.options.privileged)
        self._c = np.zeros((n, K.N_CONFIG))
        self._s = np.zeros((n, K.N_STATE))
        self._acc = np.zeros((n, K.N_ACC))
        self._u = np.zeros((n, K.N_INPUT))
        self._par = np.zeros((n, N_PAR))
        self._obs = np.zeros((n, f.obs_dim), dtype=np.float32)
        self._out = np.zeros((n, N_OUT))
        self._t = np.zeros(n, dtype=np.int64)
        self._autoreset = np.zeros(n, dtype=bool)
        self._all = np.ones(n, dtype=bool)
        self._rngs: list[np.random.Generator | None] = [None] * n
        self.systems: list[SystemParams | None] = [None] * n
        self._ready = False

    @property
    def drive_states(self) -> np.ndarray:
        """Copy of the kernel's state rows (``kernel.S_*``; SI units), one per drive."""
        return self._s.copy()

    def _reset_drive(self, i: int) -> dict[str, Any]:
        rng = self._rngs[i]
        if rng is None:
            rng, _ = seeding.np_random(None)
            self._rngs[i] = rng
        info, self.systems[i] = self._factory.new_episode(rng, self._c[i], self._s[i],
                                                          self._par[i])
        self._u[i] = 0.0
        self._t[i] = 0
        self._factory.initial_observation(self._s[i:i + 1], self._par[i:i + 1],
                                          self._obs[i:i + 1])
        return info

    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        n = self.num_envs
        if seed is None:
            seeds: list[int | None] = [None] * n
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = list(seed)
            if len(seeds) != n:
                raise ParameterError(f"seed: a list of seeds must have num_envs={n} entries, "
                                     f"got {len(seeds)}")
        mask = self._all
        if options and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"], dtype=bool)
            if mask.shape != (n,):
                raise ParameterError(f"options['reset_mask'] must have shape ({n},), got "
                                     f"{mask.shape}")
        if seed is not None or not self._ready:
            # Gymnasium's convention: seed i seeds drive i; None draws fresh entropy
            # only where no generator exists yet.
            for i, sd in enumerate(seeds):
                if mask[i] and (sd is not None or self._rngs[i] is None):
                    self._rngs[i], _ = seeding.np_random(sd)
        speeds = np.zeros(n)
        harm = np.zeros(n, dtype=np.int64)
        for i in np.flatnonzero(mask):
            info = self._reset_drive(int(i))
            speeds[i], harm[i] = info["speed_rps"], info["target_harmonic"]
        self._autoreset[mask] = False
        self._ready = True
        return self._obs.copy(), {"speed_rps": speeds, "_speed_rps": mask.copy(),
                                  "target_harmonic": harm, "_target_harmonic": mask.copy()}

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                          dict[str, Any]]:
        if not self._ready:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = _as_action(actions, self._act_shape)
        bad = _load_actions(a, self._u, self._acc, self._par, self._offset)
        if bad >= 0:
            raise _action_error(actions, self._act_shape)
        K.run_batch(self._c, self._s, self._acc, self._u, self._steps_per_call)
        out = self._out
        _observe(self._s, self._acc, a, self._par, _IX, self._privileged, self._obs, out)
        self._t += 1
        # One copy of the outputs; the returned arrays are views of it, never reused.
        out = out.copy()
        rewards = out[:, O_REWARD]
        terminated = out[:, O_TERMINATED] != 0.0
        if self.max_episode_steps is None:
            truncated = np.zeros(self.num_envs, dtype=bool)
        else:
            truncated = (self._t >= self.max_episode_steps) & ~terminated
        valid = self._all
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
            obs = self._obs.copy()
        else:
            done = terminated | truncated
            obs_now = self._obs.copy()
            if done.any():
                idx = np.flatnonzero(done)
                final_obs = np.full(self.num_envs, None, dtype=object)
                final_info = np.full(self.num_envs, None, dtype=object)
                for i in idx:
                    final_obs[i] = obs_now[i].copy()
                    final_info[i] = self._single_info(int(i))
                    self._reset_drive(int(i))
                infos["final_obs"], infos["_final_obs"] = final_obs, done.copy()
                infos["final_info"], infos["_final_info"] = final_info, done.copy()
                obs = self._obs.copy()
            else:
                obs = obs_now
        mask = valid.copy()
        infos["velocity_error_rms_rad_s"] = out[:, O_VEL_RMS]
        infos["_velocity_error_rms_rad_s"] = mask
        infos["lag_rad"] = out[:, O_LAG]
        infos["_lag_rad"] = mask
        infos["injected_current_rms_a"] = out[:, O_IINJ_RMS]
        infos["_injected_current_rms_a"] = mask
        infos["peak_current_a"] = out[:, O_PEAK_I]
        infos["_peak_current_a"] = mask
        infos["step_loss"] = out[:, O_STEP_LOSS] != 0.0
        infos["_step_loss"] = mask
        infos["overcurrent"] = out[:, O_OVERCURRENT] != 0.0
        infos["_overcurrent"] = mask
        return obs, rewards, terminated, truncated, infos

    def _single_info(self, i: int) -> dict[str, Any]:
        out = self._out[i]
        return {"velocity_error_rms_rad_s": float(out[O_VEL_RMS]), "lag_rad": float(out[O_LAG]),
                "injected_current_rms_a": float(out[O_IINJ_RMS]),
                "peak_current_a": float(out[O_PEAK_I]), "step_loss": bool(out[O_STEP_LOSS]),
                "overcurrent": bool(out[O_OVERCURRENT])}

    def render(self) -> None:
        return None


def register_envs() -> None:
    """Register ``StepperDamp-v0`` (scalar entry point and native vector entry point).

    Idempotent: a second call leaves the registry alone, so it never warns.
    """
    if ENV_ID in gym.registry:
        return
    gym.register(
        id=ENV_ID,
        entry_point="stepdamp_env.envs:StepperDampEnv",
        vector_entry_point="stepdamp_env.envs:StepperDampVectorEnv",
        max_episode_steps=DEFAULT_EPISODE_STEPS,
    )
