"""Damping by feedback: velocity feedback, sensorless damping and the oracle floor.

Each adds a q current ``i = a*e + b*f`` at the agent rate on top of the
delay-compensated feedforward (:class:`~.harmonic.DelayCompensatedFF`), where
``e`` is a velocity-error estimate (rad/s) and ``f`` a quadrature signal that
gives the law its phase lead. The rotor on its holding spring (open loop) or in
its servo loop is a lightly damped mode at wn; a current ``i`` proportional to
the speed error adds the damping torque ``c*(w_cmd - w)`` if, at wn, the
signals, the agent's hold and the current path (:func:`~stepdamp_env.response.current_path`)
together turn ``a*E + b*Q`` into the real number ``c/(Km*G*D)``: two real
equations, two gains (:func:`design_gains`). ``c = 2*zeta_add*J*wn`` adds
``zeta_add`` to the damping ratio (first-order theory; ``tests/test_ladder.py``
measures it). All models are the nominal ones (datasheet), except the oracle's.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

import numpy as np

from stepdamp_env import fixedmath as fm
from stepdamp_env.bench.firmware import FilteredFeedback, FirmwareLaw, harmonic_law
from stepdamp_env.bench.policy import (MotorKnowledge, PolicyCard, PolicyContext,
                                       RowPolicy, estimate_model)
from stepdamp_env.bench.suites import nearest_suite, suite_of, tuned_suite
from stepdamp_env.env import EnvOptionsV1, TaskV1, periods_per_agent_step
from stepdamp_env.env.layout import OBS, observation_names
from stepdamp_env.env.registration import ENV_ID_V1
from stepdamp_env.params import ParameterError, SystemParams
from stepdamp_env.response import current_path, phasors, torque_paths, velocity_filter

from .harmonic import DelayCompensatedFF, gather_rows, harmonic_actions

__all__ = ["VelocityFeedback", "SensorlessDamping", "OracleFloor", "TunedConstantGain",
           "gains_law", "design_gains",
           "hold_response", "DEFAULT_ZETA_ADD", "DEFAULT_SENSORLESS_ZETA_ADD"]

# Added damping ratios, chosen on training motors (scripts/ladder_tuning.py);
# the rule then sets each motor's gains from its nominal model.
DEFAULT_ZETA_ADD = 0.03
# v1's damping-gains law at one constant kv: the best mean held reward over a
# grid on 64 training motors at their resonances (scripts/v1_spread.py).
DEFAULT_CONSTANT_KV = 0.5
DEFAULT_FILTER_HZ = 30.0
DEFAULT_SENSORLESS_ZETA_ADD = 0.05
DEFAULT_SENSORLESS_FILTER_HZ = 30.0
ORACLE_ZETA_ADD = 0.5


def hold_response(w: float, pwm_hz: float, agent_hz: float) -> complex:
    """From a sample at the end of an agent step to the current the controller
    computes over the next step's PWM periods, at w (rad/s): the mean of
    exp(-j*w*m*dt), m = 1..n (n PWM periods per agent step)."""
    n = int(round(pwm_hz / agent_hz))
    dt = 1.0 / pwm_hz
    return sum(fm.cexp(-1j * w * m * dt) for m in range(1, n + 1)) / n


def design_gains(target: complex, e_response: complex, f_response: complex
                 ) -> tuple[float, float]:
    """Real gains (a, b) with a*e_response + b*f_response = target."""
    m = np.array([[e_response.real, f_response.real], [e_response.imag, f_response.imag]])
    a, b = fm.solve(m, np.array([target.real, target.imag]))
    return float(a), float(b)


def _lowpass(w: float, alpha: float, dt: float) -> complex:
    """First-order low-pass y += alpha*(x - y), run every dt, at w."""
    return alpha / (1.0 - (1.0 - alpha) * fm.cexp(-1j * w * dt))


def _law_target(system: SystemParams, mode: str, agent_hz: float, zeta_add: float,
                wn: float) -> complex:
    """c/(Km*G*D) at wn: what the law's signals must turn the speed error into."""
    m = system.motor
    c = 2.0 * zeta_add * m.J * wn
    g = current_path(system, wn)
    d = hold_response(wn, system.drive.pwm_hz, agent_hz)
    return c / (m.Km * g * d)


class _FeedbackOnFF(DelayCompensatedFF):
    """``ff-delay-comp``'s harmonic actions plus a q current, in "harmonic+current"."""

    velocity_estimator = "lowpass"
    privileged = False

    def env_options(self, knowledge: MotorKnowledge) -> dict[str, Any]:
        out = super().env_options(knowledge)
        out["action_mode"] = "harmonic+current"
        out["velocity_estimator"] = self.velocity_estimator
        if self.privileged:
            out["privileged"] = True
        return out

    #: The exported law's :class:`FilteredFeedback` kind ("encoder", "back-emf").
    filter_kind = ""
    #: The modes ``stepdamp export`` writes it for (a servo closes its own loop).
    firmware_modes: tuple[str, ...] = ("open-loop",)

    def firmware_law(self, context: PolicyContext) -> FirmwareLaw:
        """The law this entry runs in ``context`` (see
        :mod:`stepdamp_env.bench.firmware`): ``ff-delay-comp``'s table, and its
        feedback current computed every agent step from the same filters, gains and
        float32 action, held in between (:class:`FilteredFeedback`, format /3);
        open loop only, as the entry runs."""
        owner = next(c for c in type(self).__mro__ if "filter_kind" in vars(c))
        if not self.filter_kind or any(getattr(type(self), m) is not getattr(owner, m)
                                       for m in ("act", "act_batch", "configure")):
            # A subclass that changes the law would be exported as its parent's.
            raise ParameterError(f"entry {self.name!r} cannot be exported: its law is not "
                                 f"the filtered feedback {owner.__name__} exports")
        if context.mode == "servo":
            raise ParameterError(f"entry {self.name!r} cannot be exported in servo: "
                                 f"{self.card.not_in_suites}")
        periods = periods_per_agent_step(context.knowledge.nominal.drive.pwm_hz,
                                         context.agent_hz)
        self.reset(context)
        table = DelayCompensatedFF(self.estimate).firmware_law(context)
        a, b = self.gains
        feedback = FilteredFeedback(
            kind=self.filter_kind, periods_per_update=periods,
            gain_a=a, gain_b=b, lowpass_beta=self._beta,
            highpass_alpha=self._hp_alpha if self.filter_kind == "encoder" else 0.0,
            current_scale_a=context.current_scale_a)
        cutoff = context.knowledge.nominal.servo.velocity_cutoff_hz
        estimator = ("the drive's encoder difference through a first-order low-pass at "
                     f"{cutoff!r} Hz" if self.filter_kind == "encoder" else
                     "the back-EMF, v - R*i - L*di/dt over each PWM period projected on the "
                     f"command's electrical angle, through a first-order low-pass at "
                     f"{cutoff!r} Hz")
        return dataclasses.replace(
            table, entry=self.name, filtered_feedback=feedback,
            velocity_estimator=f"{estimator}, read every agent step ({context.agent_hz!r} Hz)",
            notes=(f"{self.name}: ff-delay-comp's table (the {self.estimate} detent model "
                   "through the inverse current path at the held speed) plus its feedback "
                   f"current for an added damping ratio of {self.zeta_add!r} at the nominal "
                   f"wn, its signals low-passed at {self.filter_hz!r} Hz, computed every "
                   "agent step and held in between, as the benchmark applies it."))

    def _feedforward(self, context: PolicyContext, system: SystemParams) -> np.ndarray:
        """ff-delay-comp's actions, with the current path of ``system``."""
        model = estimate_model(self.estimate, context.knowledge)
        base = phasors(model)
        g = torque_paths(system, context.mode, context.speed_rps, model)
        return harmonic_actions(base / g, base, context.action_scale)

    # The law on rows (RowPolicy: a scalar run is row 0): each row configured and its
    # settings gathered; element-wise float64, then the float32 rounding of the current.
    _ROW_SETTINGS: tuple[str, ...] = ()

    def reset_batch(self, contexts: Sequence[PolicyContext]) -> None:
        names = ("_action", "_w_ref", "_to_action", "_full_step", "gains", *self._ROW_SETTINGS)
        self._rows = gather_rows(self, contexts, lambda: {k: getattr(self, k) for k in names})
        n = len(contexts)
        self._rows_state = np.zeros((3, n))     # the law's filter states
        self._rows_started = False

    def _row_current(self, current: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """The rows' actions: feedforward plus ``current`` (A, before scaling)."""
        out = self._rows["_action"][rows].copy()
        out[:, 6] = np.clip(current * self._rows["_to_action"][rows], -1.0, 1.0)
        return out

    def row_calibration_s(self, row: int) -> float:
        return 0.0

    def __init__(self, name: str, zeta_add: float, filter_hz: float = 0.0,
                 estimate: str = "identified") -> None:
        super().__init__(estimate)
        self.name = name
        self.zeta_add = float(zeta_add)
        self.filter_hz = float(filter_hz)

    def _start(self, context: PolicyContext, system: SystemParams) -> float:
        """The run's feedforward, scales and full step; returns the natural
        frequency of ``system`` (rad/s)."""
        self._action = np.zeros(7, dtype=np.float32)
        self._action[:6] = self._feedforward(context, system)
        self._w_ref = 2.0 * math.pi * abs(context.speed_rps)
        self._to_action = 1.0 / context.current_scale_a
        self._full_step = system.motor.full_step_rad
        return system.natural_frequency()


class VelocityFeedback(_FeedbackOnFF):
    """``velocity-feedback``: the classic anti-resonance law, with an encoder.

    Source idea: velocity-feedback damping of the rotor's resonance (what
    commercial "anti-resonance" does; ``damping-methods.md``). Senses the
    encoder (the drive's low-passed velocity estimate and its position error);
    model: nominal (datasheet) for the law, identified for the feedforward.

    Law: ``i = a*e_w + b*hp(e_theta)`` on top of ``ff-delay-comp``, where
    ``e_w`` is the drive's velocity error estimate (rad/s) and ``hp(e_theta)``
    the encoder's position error through a first-order high-pass at wn/5 (it
    drops the static lag; at wn it is the speed error turned by 90 degrees,
    which supplies the phase lead the low-pass, the hold and the current loop
    take away). Settings: (a, b) from :func:`design_gains` for an added damping
    ratio ``zeta_add`` at the nominal wn of the holding spring. Open loop
    only (see ``card.not_in_suites``). Both signals pass a first-order low-pass at ``filter_hz`` (its
    phase is in the design): the 4000-count encoder's quantisation noise, fed
    back, would otherwise add more ripple than the damping removes.
    ``zeta_add`` = 0.03 and ``filter_hz`` = 30 were chosen on training motors
    (``scripts/ladder_tuning.py``: larger added damping loses to that noise).
    """

    card = PolicyCard(sensors="encoder (velocity estimate, position error), currents",
                      model="nominal (law), identified (feedforward)",
                      suites=("open-loop", "mid-band", "moves"),
                      not_in_suites="the servo's own loop is velocity feedback already "
                                    "(eq. 15): a second one on top retunes the servo (and, "
                                    "designed for the open-loop spring, loses steps there)")

    def __init__(self, zeta_add: float = DEFAULT_ZETA_ADD,
                 filter_hz: float = DEFAULT_FILTER_HZ) -> None:
        super().__init__("velocity-feedback", zeta_add, filter_hz)

    filter_kind = "encoder"

    def configure(self, context: PolicyContext) -> None:
        nominal = context.knowledge.nominal
        wn = self._start(context, nominal)
        dt_a = 1.0 / context.agent_hz
        self._hp_alpha = 1.0 - fm.exp(-wn / 5.0 * dt_a)
        self._beta = 1.0 - fm.exp(-2.0 * math.pi * self.filter_hz * dt_a)
        hp = 1.0 - _lowpass(wn, self._hp_alpha, dt_a)
        lp = _lowpass(wn, self._beta, dt_a)
        target = _law_target(nominal, context.mode, context.agent_hz, self.zeta_add, wn)
        self.gains = design_gains(target, velocity_filter(nominal, wn) * lp,
                                  hp * lp / complex(0.0, wn))

    _ROW_SETTINGS = ("_hp_alpha", "_beta")

    def act_batch(self, observations: np.ndarray, rows: np.ndarray) -> np.ndarray:
        r = self._rows
        e_w = observations[:, OBS.velocity_error].astype(np.float64) * r["_w_ref"][rows]
        e_theta = observations[:, OBS.position_error].astype(np.float64) * r["_full_step"][rows]
        lp, fw, fp = (self._rows_state[k, rows] for k in range(3))
        if not self._rows_started:
            lp, fw, fp = e_theta, e_w, np.zeros(len(rows))
            self._rows_started = True
        lp = lp + r["_hp_alpha"][rows] * (e_theta - lp)
        beta = r["_beta"][rows]
        fw = fw + beta * (e_w - fw)
        fp = fp + beta * (e_theta - lp - fp)
        self._rows_state[:, rows] = lp, fw, fp
        a, b = r["gains"][rows, 0], r["gains"][rows, 1]
        return self._row_current(a * fw + b * fp, rows)


class SensorlessDamping(_FeedbackOnFF):
    """``sensorless-damping``: damping without an encoder (the idea of US 5,847,535).

    Senses the phase currents and the applied winding voltages only: the
    drive's ``velocity_estimator="back-emf"`` estimates the rotor's speed from
    the back-EMF, ``e = v - R*i - L*di/dt`` solved exactly over each PWM period
    with the winding's R and L, projected on the command's electrical angle and
    low-passed (:mod:`stepdamp_env.kernel`). Model: nominal (Km, J, wn) for the
    law, identified for the feedforward, the winding's R and L as a standstill
    measurement gives them.

    Law: ``i = a*e_w + b*(e_w - e_w_prev)`` on top of ``ff-delay-comp``; the
    difference of successive estimates supplies the phase lead (there is no
    position to take it from), after a low-pass at ``filter_hz`` against the
    current sensors' noise. Settings: (a, b) from :func:`design_gains` for an
    added damping ratio ``zeta_add`` at the nominal wn; ``zeta_add`` = 0.05
    and ``filter_hz`` = 30 chosen on training motors
    (``scripts/ladder_tuning.py``).

    Open loop only: a servo has an encoder by definition (it closes its
    position loop on it), so sensorless damping has nothing to add there that
    ``velocity-feedback`` does not.
    """

    card = PolicyCard(sensors="currents + winding voltages (no encoder)",
                      model="nominal (law), identified (feedforward), winding R, L",
                      suites=("open-loop", "mid-band", "moves"),
                      not_in_suites="a servo closes its loop on an encoder: sensorless "
                                    "damping is for open-loop drives")
    velocity_estimator = "back-emf"

    def __init__(self, zeta_add: float = DEFAULT_SENSORLESS_ZETA_ADD,
                 filter_hz: float = DEFAULT_SENSORLESS_FILTER_HZ) -> None:
        super().__init__("sensorless-damping", zeta_add, filter_hz)

    filter_kind = "back-emf"

    def configure(self, context: PolicyContext) -> None:
        nominal = context.knowledge.nominal
        wn = self._start(context, nominal)
        dt = 1.0 / nominal.drive.pwm_hz
        alpha = 1.0 - fm.exp(-2.0 * math.pi * nominal.servo.velocity_cutoff_hz * dt)
        dt_a = 1.0 / context.agent_hz
        self._beta = 1.0 - fm.exp(-2.0 * math.pi * self.filter_hz * dt_a)
        # The back-EMF is that of the period before the sample: half a period late.
        est = (_lowpass(wn, alpha, dt) * fm.cexp(-0.5j * wn * dt)
               * _lowpass(wn, self._beta, dt_a))
        diff = est * (1.0 - fm.cexp(-1j * wn * dt_a))
        target = _law_target(nominal, context.mode, context.agent_hz, self.zeta_add, wn)
        self.gains = design_gains(target, est, diff)

    _ROW_SETTINGS = ("_beta",)

    def act_batch(self, observations: np.ndarray, rows: np.ndarray) -> np.ndarray:
        r = self._rows
        raw = observations[:, OBS.velocity_error].astype(np.float64) * r["_w_ref"][rows]
        prev, fw = self._rows_state[0, rows], self._rows_state[1, rows]
        if not self._rows_started:
            prev, fw = raw, raw
            self._rows_started = True
        fw = fw + r["_beta"][rows] * (raw - fw)
        self._rows_state[0, rows], self._rows_state[1, rows] = fw, fw
        a, b = r["gains"][rows, 0], r["gains"][rows, 1]
        return self._row_current(a * fw + b * (fw - prev), rows)


class OracleFloor(_FeedbackOnFF):
    """``oracle-floor`` (oracle): how far the ripple can fall on this drive.

    Knows what no drive knows: the true plant (every parameter) and its true
    state (``privileged`` observation: the true position and speed error). It
    cancels the detent with the exact model sent through the true plant's
    current path (``ff-delay-comp`` with perfect knowledge) and adds state
    feedback on the true speed error and the high-passed true position error
    (the law of :class:`VelocityFeedback` without sensor lag, quantisation or
    noise) for an added damping ratio of 0.5 at the true wn. What remains is
    what the drive cannot do: the current loop's bandwidth and noise, the PWM
    and agent-step hold, the bus voltage, the microstep quantisation of the
    open-loop command. In servo the servo's own loop damps the rotor and the
    state feedback is left out (zeta_add = 0 there): the floor of exact
    cancellation.
    """

    card = PolicyCard(sensors="true state (position, speed)", model="true plant (exact)",
                      oracle=True)
    privileged = True

    def __init__(self, zeta_add: float = ORACLE_ZETA_ADD) -> None:
        super().__init__("oracle-floor", zeta_add, estimate="exact")

    def configure(self, context: PolicyContext) -> None:
        plant = context.knowledge.plant
        if plant is None:
            raise ValueError("oracle-floor needs MotorKnowledge.plant (the true plant)")
        wn = self._start(context, plant)
        names = observation_names("harmonic+current", privileged=True)
        self._i_w = names.index("true_velocity_error")
        self._i_theta = names.index("true_position_error")
        dt_a = 1.0 / context.agent_hz
        self._hp_alpha = 1.0 - fm.exp(-wn / 5.0 * dt_a)
        hp = 1.0 - _lowpass(wn, self._hp_alpha, dt_a)
        zeta = self._zeta(context)
        target = _law_target(plant, context.mode, context.agent_hz, zeta, wn)
        self.gains = design_gains(target, complex(1.0, 0.0), hp / complex(0.0, wn))

    #: Never exported: an oracle.
    firmware_modes: tuple[str, ...] = ()

    def firmware_law(self, context: PolicyContext) -> FirmwareLaw:
        """Not exportable: an oracle (see :mod:`stepdamp_env.bench.firmware`)."""
        raise ParameterError(f"entry {self.name!r} cannot be exported: it is an oracle (it "
                             "reads the true plant and the true state, which no drive has)")

    def _zeta(self, context: PolicyContext) -> float:
        """The added damping ratio of this run: ``zeta_add`` in open loop, 0 in servo."""
        return self.zeta_add if context.mode == "open-loop" else 0.0

    _ROW_SETTINGS = ("_hp_alpha", "_i_w", "_i_theta")

    def act_batch(self, observations: np.ndarray, rows: np.ndarray) -> np.ndarray:
        r = self._rows
        i_w, i_theta = int(r["_i_w"][0]), int(r["_i_theta"][0])
        e_w = observations[:, i_w].astype(np.float64) * r["_w_ref"][rows]
        e_theta = observations[:, i_theta].astype(np.float64) * r["_full_step"][rows]
        lp = self._rows_state[0, rows]
        if not self._rows_started:
            lp = e_theta
            self._rows_started = True
        lp = lp + r["_hp_alpha"][rows] * (e_theta - lp)
        self._rows_state[0, rows] = lp
        a, b = r["gains"][rows, 0], r["gains"][rows, 1]
        return self._row_current(a * e_w + b * (e_theta - lp), rows)


# privileged-bound's law per suite: added damping ratio, decision rate (Hz) and
# feedforward ("delay-comp": the exact model through the true current path;
# "patent": the exact model, uncompensated; "none"), chosen on v3's dev split
# (scripts/bound_tuning.py; docs/protocol_v3.md has its table).
PRIVILEGED_SETTINGS: dict[str, tuple[float, float, str]] = {
    "open-loop": (2.0, 5000.0, "delay-comp"),
    "servo": (0.1, 5000.0, "delay-comp"),
    "mid-band": (0.05, 5000.0, "none"),
}
FEEDFORWARDS = ("delay-comp", "patent", "none")


class PrivilegedBound(OracleFloor):
    """``privileged-bound`` (privileged): the bound of stepdamp-bench v3.

    oracle-floor's law (feedback on the true speed and position error) with its
    added damping ratio, decision rate and feedforward chosen per suite on v3's
    dev split, never on a scored motor (``scripts/bound_tuning.py``; the
    setting whose interval of IQM attenuation over the 16 dev motors has the
    highest lower end, so that a knife-edge gain is not chosen; its output:
    docs/results/v3/bound_tuning.txt). The
    feedforward is the exact model sent through the true plant's current path
    (``delay-comp``, oracle-floor's), the exact model uncompensated
    (``patent``), or none. The suite is the run's (``PolicyContext.suite``;
    ``env_options``, before the run, reads it from the plant's drive). Settings:
    ``PRIVILEGED_SETTINGS``, (zeta_add, agent_hz, feedforward) per suite.
    """

    def __init__(self, settings: dict[str, tuple[float, float, str]] | None = None) -> None:
        super().__init__()
        self.name = "privileged-bound"
        self.settings = dict(PRIVILEGED_SETTINGS if settings is None else settings)
        for suite, (zeta, hz, ff) in self.settings.items():
            if ff not in FEEDFORWARDS or not (zeta >= 0.0 and hz > 0.0):
                raise ValueError(f"settings[{suite!r}] = {(zeta, hz, ff)!r}: zeta_add >= 0, "
                                 f"agent_hz > 0, feedforward one of {list(FEEDFORWARDS)}")
        # The env options are chosen before the mode is known: open loop and servo
        # (both on the current-mode drive) must share the rate and the base.
        ol, sv = self.settings["open-loop"], self.settings["servo"]
        if ol[1] != sv[1] or (ol[2] == "none") != (sv[2] == "none"):
            raise ValueError("settings: open-loop and servo must share agent_hz and "
                             "whether there is a feedforward")

    def env_options(self, knowledge: MotorKnowledge) -> dict[str, Any]:
        out = super().env_options(knowledge)
        # The mode is not known here: open loop and servo share their rate and base.
        plant = knowledge.plant if knowledge.plant is not None else knowledge.nominal
        zeta, hz, ff = self.settings[suite_of("open-loop", plant.drive.drive_mode)]
        out["agent_hz"] = hz
        if ff == "none":
            out["base_controller"] = "none"
        return out

    def configure(self, context: PolicyContext) -> None:
        super().configure(context)
        if self._run_settings(context)[2] != "delay-comp":
            self._action[:6] = 0.0          # the base's own feedforward, or none

    def _zeta(self, context: PolicyContext) -> float:
        return self._run_settings(context)[0]

    def _run_settings(self, context: PolicyContext) -> tuple[float, float, str]:
        plant = context.knowledge.plant
        drive = (plant if plant is not None else context.knowledge.nominal).drive.drive_mode
        suite = tuned_suite(context.suite or nearest_suite(context.mode, drive), self.settings)
        if suite not in self.settings:
            raise ParameterError(f"{self.name}: no settings for suite {suite!r} (tuned "
                                 f"for {sorted(self.settings)})")
        return self.settings[suite]


class TunedConstantGain(RowPolicy):
    """``tuned-constant-gain``: StepperDamp-v1's damping law on ``ff-delay-comp``
    at one constant gain, what the per-step agents must beat to have learned
    more than a number.

    The law (``action_mode="damping-gains"``, run by the kernel every PWM
    period from the drive's own samples) adds ``kv*Kv*e_w``, ``e_w`` the drive's
    velocity-error estimate, ``Kv = 2*J*wn/Km`` of the nominal model (so kv = 1
    adds a damping ratio of 0.5 to the datasheet rotor); every other gain is 0.
    Setting: ``kv`` = 0.5, the best mean held reward over the grid 0.05-1.0 on
    64 training motors at their resonances (``scripts/v1_spread.py``); the
    per-step agents act on the same law with the same options. Senses the
    encoder (velocity estimate) and currents; model: nominal (law units),
    identified (feedforward).
    """

    env_id = ENV_ID_V1
    card = PolicyCard(sensors="encoder (velocity estimate), currents",
                      model="nominal (law), identified (feedforward)")

    def __init__(self, kv: float = DEFAULT_CONSTANT_KV) -> None:
        if not (math.isfinite(kv) and -1.0 <= kv <= 1.0):
            raise ValueError(f"kv={kv!r} is outside its allowed range [-1, 1]")
        self.name = "tuned-constant-gain"
        self.kv = float(kv)
        self._action = np.zeros(8, dtype=np.float32)
        self._action[0] = self.kv

    def env_options(self, knowledge: MotorKnowledge) -> dict[str, Any]:
        return {"base_controller": "ff-delay-comp", "estimate": knowledge.identified,
                "action_mode": "damping-gains", "agent_hz": 100.0}

    def firmware_law(self, context: PolicyContext) -> FirmwareLaw:
        """The law this entry runs in ``context`` (:mod:`stepdamp_env.bench.firmware`):
        v1's ff-delay-comp base feedforward (unrounded) plus the kernel's feedback
        ``clip(kv*Kv*e_w + kp*Kv*wn*hp(e_theta), +-law limit)``, with v1's own scales
        (the env's task computes them, so the export follows the env)."""
        return gains_law(self.name, self._gains(context), self.env_options(context.knowledge),
                         context)

    def _gains(self, context: PolicyContext) -> np.ndarray:
        """The float32 damping-gains action this entry holds in ``context``."""
        return self._action

    def reset_batch(self, contexts: Sequence[PolicyContext]) -> None:
        pass

    def act_batch(self, observations: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return np.tile(self._action, (len(rows), 1))


def gains_law(name: str, action: np.ndarray, options: dict[str, Any],
              context: PolicyContext) -> FirmwareLaw:
    """The law of an entry holding the constant damping-gains ``action`` (float32,
    StepperDamp-v1's scales) on ff-delay-comp with the env ``options``, in ``context``."""
    if np.any(action[2:] != 0.0):
        raise ParameterError(f"entry {name!r} cannot be exported: only the gains kv and kp "
                             "of the damping law are supported (the resonant gains must be 0)")
    knowledge = context.knowledge
    model = options["estimate"]
    if model is None:
        raise ParameterError(f"entry {name!r} cannot be exported: it needs an identified "
                             "motor model (MotorKnowledge.identified is None)")
    nominal = knowledge.nominal
    task = TaskV1(EnvOptionsV1.from_kwargs({
        **options, "motor": nominal, "nominal": nominal, "mode": context.mode,
        "speed_rps": context.speed_rps}))
    # The kernel's KV and KP: the float32 actions times their scales, Kv = 2*zeta_scale*
    # J*wn/Km (A*s/rad) and Kv*wn (A/rad).
    kv, kp = float(action[0]), float(action[1])
    position = (f" and the high-passed position gain kp = {kp!r} (Kp = kp*Kv*wn; the "
                "high-pass's corner wn/4)" if kp != 0.0 else "")
    return harmonic_law(
        context, name, task.base_coefficients(model, context.speed_rps), model,
        velocity_gain_a_s_per_rad=kv * task.action_scales[0], feedback_limit_a=task.law_limit_a,
        position_gain_a_per_rad=kp * task.action_scales[1],
        position_highpass_alpha=task.law_hp_alpha if kp != 0.0 else 0.0,
        velocity_estimator=(f"the drive's encoder difference through a first-order "
                            f"low-pass at {nominal.servo.velocity_cutoff_hz!r} Hz, every "
                            "PWM period"),
        notes=(f"{name}: ff-delay-comp's table (the identified detent model through "
               "the inverse current path at the held speed) plus StepperDamp-v1's damping "
               f"law at the constant gain kv = {kv!r}{position}: Kv = kv*2*"
               f"{task.options.damping_ratio_scale!r}*J*wn/Km of the nominal motor, "
               f"bounded by {task.options.law_limit_factor!r} times the holding current."))
