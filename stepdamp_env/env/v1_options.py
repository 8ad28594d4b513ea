"""Options, units and layout of ``StepperDamp-v1``, validated, with their defaults."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..params import ParameterError, SystemParams
from ..motorfile import load_system
from . import v1_compiled as V
from .layout import ACTION_NAMES, OBSERVATION_NAMES, OBSERVATION_UNITS, PRIVILEGED_NAMES
from .options import DriveOptions, EnvOptions, check_choice, check_number
from .registration import ENV_ID_V1

__all__ = ["EnvOptionsV1", "MotorUnits", "BASE_CONTROLLERS_V1", "ACTION_NAMES_V1",
           "REWARD_WINDOWS", "ACTION_MODES_V1", "GAIN_PHASE_LIMIT_RAD", "CONTEXTS", "CONTEXT_NAMES", "OBSERVATION_NAMES_V1",
           "OBSERVATION_UNITS_V1", "REWARD_BOUND", "DEFAULT_EPISODE_S", "observation_names_v1"]

BASE_CONTROLLERS_V1 = ("ff-delay-comp", "patent-ff", "none")
# The damping law's gains (kernel L_KV .. L_KI4), each action 1.0 times its scale.
ACTION_NAMES_V1: dict[str, tuple[str, ...]] = {
    **ACTION_NAMES,
    "damping-gains": ("kv", "kp", "r1_re", "r1_im", "r2_re", "r2_im", "r4_re", "r4_im"),
    "gain-phase": ("gain", "phase"),
}
ACTION_MODES_V1 = ("damping-gains", "harmonic", "current", "harmonic+current", "gain-phase")
#: "gain-phase": the phase of the damping law at phase = +-1 (rad). Within
#: +-pi/4 the law's velocity part (kv = g*cos(phi) >= 0.7*g) removes energy;
#: no action of the box lost steps on the tested draws (tests/test_env_v3.py),
#: where a lead of pi/2 does.
GAIN_PHASE_LIMIT_RAD = math.pi / 4
#: ``reward_window``: every step, or the command's cruise only.
REWARD_WINDOWS = ("episode", "cruise")
CONTEXTS = ("hidden", "visible")
CONTEXT_NAMES = ("speed_over_resonance_h4", "speed_over_resonance_h2", "speed_over_resonance_h1",
                 "model_s1", "model_c1", "model_s2", "model_c2", "model_s4", "model_c4")
# The per-step reward's terms are clipped to this; a terminated episode loses it
# (times 1 + current_penalty) for every step it did not play.
REWARD_BOUND = 10.0
# 0.4 s: the longest default ramp (3.3 rev/s at 50 rev/s^2) takes 66 ms, then
# about three decay times (80-120 ms) of the resonance are held.
DEFAULT_EPISODE_S = 0.4

OBSERVATION_NAMES_V1: tuple[str, ...] = tuple(name.lower() for name in V.OBS._fields)
assert OBSERVATION_NAMES_V1[:9] == OBSERVATION_NAMES[:9]
OBSERVATION_UNITS_V1: dict[str, str] = {
    "position_error": "(theta_cmd - encoder angle) / position_unit_rad",
    "velocity_error": "(omega_cmd - velocity estimate) / velocity_unit_rad_s",
    **{k: OBSERVATION_UNITS[k] for k in OBSERVATION_NAMES[2:8]},    # sin, cos of x, 2x, 4x
    "speed_command": "omega_cmd / (2*pi * predicted h = 1 resonance speed)",
    "id_error": "(measured id - id command) / current_unit_a",
    "iq": "measured iq / current_unit_a",
}


def observation_names_v1(action_mode: str = "damping-gains", history: int = 0,
                         context: str = "hidden", privileged: bool = False) -> tuple[str, ...]:
    """Names of every observation entry in order for a v1 env with these options."""
    last = tuple(f"last_action_{n}" for n in ACTION_NAMES_V1[action_mode])
    hist = tuple(f"{sig}_{k}" for k in range(1, history + 1)
                 for sig in ("position_error", "velocity_error"))
    ctx = CONTEXT_NAMES if context == "visible" else ()
    return OBSERVATION_NAMES_V1 + last + hist + ctx + (PRIVILEGED_NAMES if privileged else ())


@dataclass(frozen=True)
class MotorUnits:
    """The units of v1's observations and reward, from the drive's own (nominal) model.

    The rotor sits on the spring of its holding current, stiffness
    ``k = Km * I_hold * Nr`` (N*m/rad), natural frequency ``wn = sqrt(k/J)``; the
    largest detent harmonic ``Kd = max(Kd1, Kd2, Kd4)`` (2 % of the holding
    torque without detent) moves it by ``position_unit_rad = Kd/k`` off
    resonance; ``velocity_unit_rad_s = wn * position_unit_rad`` is that ripple
    as a speed, ``current_unit_a = Kd/Km`` the current that cancels it.
    """

    stiffness_nm_per_rad: float
    wn_rad_s: float
    position_unit_rad: float
    velocity_unit_rad_s: float
    current_unit_a: float
    speed_unit_rad_s: float

    @classmethod
    def of(cls, nominal: SystemParams) -> "MotorUnits":
        m, hold = nominal.motor, nominal.drive.holding_current
        k = m.Km * hold * m.Nr
        wn = math.sqrt(k / m.J)
        kd = max(m.Kd1, m.Kd2, m.Kd4)
        if kd <= 0.0:
            kd = 0.02 * m.Km * hold
        top = max(nominal.predicted_resonances_rps().values())
        return cls(stiffness_nm_per_rad=k, wn_rad_s=wn, position_unit_rad=kd / k,
                   velocity_unit_rad_s=wn * kd / k, current_unit_a=kd / m.Km,
                   speed_unit_rad_s=2.0 * math.pi * top)


@dataclass(frozen=True)
class EnvOptionsV1(DriveOptions):
    """Validated constructor options of ``StepperDamp-v1``; see :class:`StepperDampV1Env`."""

    nominal: Any = None
    base_controller: str = "ff-delay-comp"
    action_mode: str = "damping-gains"
    episode_s: float = DEFAULT_EPISODE_S
    history: int = 0
    context: str = "hidden"
    damping_ratio_scale: float = 0.5
    resonant_rate_scale: float = 0.05
    law_limit_factor: float = 0.5
    current_penalty: float = 0.0
    reward_window: str = "episode"

    @classmethod
    def from_kwargs(cls, kwargs: Mapping[str, Any], env_id: str = ENV_ID_V1) -> "EnvOptionsV1":
        """Options from keyword arguments; unknown names raise ``ValueError`` (v0's
        rule), naming ``env_id``."""
        return super().from_kwargs(kwargs, env_id)

    def __post_init__(self) -> None:
        check_choice("base_controller", self.base_controller, BASE_CONTROLLERS_V1)
        check_choice("action_mode", self.action_mode, ACTION_MODES_V1)
        check_choice("context", self.context, CONTEXTS)
        check_choice("reward_window", self.reward_window, REWARD_WINDOWS)
        self.check_drive()
        check_number("episode_s", self.episode_s, 0.0, 1e4, low_open=True)
        if isinstance(self.history, bool) or not isinstance(self.history, (int, np.integer)) \
                or not 0 <= self.history <= 1000:
            raise ParameterError(f"history={self.history!r} is outside its allowed range "
                                 "[0, 1000] (integer)")
        check_number("damping_ratio_scale", self.damping_ratio_scale, 0.0, 100.0, low_open=True)
        check_number("resonant_rate_scale", self.resonant_rate_scale, 0.0, 100.0, low_open=True)
        check_number("law_limit_factor", self.law_limit_factor, 0.0, 10.0, low_open=True)
        check_number("current_penalty", self.current_penalty, 0.0, 1e3)
        if self.nominal is not None:
            if not isinstance(self.nominal, (str, SystemParams)):
                raise ParameterError(f"nominal={self.nominal!r} must be None, a preset name, a "
                                     "motor file or a SystemParams")
            try:
                load_system(self.nominal)
            except ParameterError as exc:
                raise ParameterError(f"nominal={self.nominal!r}: {exc}") from None
        if int(round(self.episode_s * self.agent_hz)) < 1:
            raise ParameterError(f"episode_s={self.episode_s!r} is shorter than one agent step "
                                 f"(1/agent_hz = {1.0 / self.agent_hz:.6g} s); allowed: >= 1/agent_hz")

    def shared(self) -> EnvOptions:
        """The v0 options of the same drive and episode draws (v0 draws the episodes)."""
        return EnvOptions.of_drive(self, action_mode="harmonic+current",
                                   base_controller="patent-ff" if self.base_controller != "none"
                                   else "none")

    @property
    def max_episode_steps(self) -> int:
        """Agent steps per episode: ``round(episode_s * agent_hz)``."""
        return int(round(self.episode_s * self.agent_hz))


OPTIONS_DOC_V1 = """
    ## Arguments

    All are keyword arguments with defaults; an unknown name or a value out of
    its range raises ``ValueError`` naming it. Shared with v0 (same meaning,
    same defaults, same episode draws for the same seed): ``motor``,
    ``overrides``, ``randomize``, ``mode``, ``estimate``, ``speed_rps``,
    ``speed_range_rps``, ``resonance_prob``, ``resonance_spread``,
    ``accel_rps2``, ``agent_hz``, ``harmonic_scale_nm``, ``current_scale_a``,
    ``current_limit_factor``, ``lag_limit_steps``, ``privileged``, ``substeps``,
    ``velocity_estimator``, ``measure_from_s``, ``measure_until_s``, ``profile``,
    ``ramp``, ``distance_rev``, ``cruise_s``, ``accel_range_rps2`` (see
    ``StepperDamp-v0``). New or
    changed in v1:

    * ``base_controller`` ("ff-delay-comp"): the drive's model-based damping under
      the agent: "ff-delay-comp" (the patent feedforward of the ``estimate``
      model sent through the inverse of the drive model's current path and
      static lag at the held speed), "patent-ff" (the patent's feedforward) or
      "none".
    * ``action_mode`` ("damping-gains"): see Action Space.
    * ``episode_s`` (0.4): episode length (s); the env truncates after
      ``round(episode_s * agent_hz)`` steps and refuses to step on.
    * ``history`` (0): append the position and velocity error of the last
      ``history`` agent steps (newest first).
    * ``context`` ("hidden"): "visible" appends what the drive knows about the
      episode (Observation Space).
    * ``damping_ratio_scale`` (0.5): the damping ratio that ``kv`` = 1 adds to
      the nominal rotor on its spring; ``resonant_rate_scale`` (0.05): the
      adaptation rate of a resonant gain of 1, as a fraction of wn (off
      resonance); ``law_limit_factor`` (0.5): the law's current bound, as a
      fraction of the holding current.
    * ``current_penalty`` (0.0): weight of the injected-current term of the reward.
    * ``reward_window`` ("episode"): the steps that are rewarded: every one, or
      "cruise", those whose middle lies in the command's cruise, the other
      steps' reward being 0 (ending early still loses the rest of the
      episode). A move's cruise runs from the end of its first ramp to the
      start of its deceleration: the window of the moves suite's headline
      ripple. A move too short to cruise rewards no step. At a constant speed
      the cruise runs from the end of the ramp on; the leaderboard's window
      there starts a settling time later.
    * ``nominal`` (None): the drive's datasheet model (a preset name, a motor
      file or a ``SystemParams``) when it is not the motor itself, as on the
      leaderboard, where ``motor`` is the true plant: units, action scales,
      ff-delay-comp's compensation, ``estimate="nominal"`` and the context's
      resonance speeds come from it. None: from ``motor`` (before randomisation).
"""
