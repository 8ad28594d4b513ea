"""Model-based harmonic feedforward policies: delay compensation and adaptation.

Both act in ``action_mode="harmonic"`` on top of the patent feedforward and
describe a detent harmonic h as a phasor P = a + j*b of its sine and cosine
coefficients (a*sin(hx) + b*cos(hx) = Im(P*exp(j*hx)), N*m). The feedforward's
torque reaches the rotor through the current path G (sampled current loop,
computation delay, held voltage; :func:`stepdamp_env.response.current_path`);
in open loop the detent it acts against runs behind it by the rotor's static lag. Sending
P/G instead of P puts the intended torque on the rotor.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import numpy as np

from stepdamp_env.bench.firmware import FirmwareLaw, KalmanTable, harmonic_law
from stepdamp_env.bench.policy import (MotorKnowledge, PolicyContext, RowPolicy,
                                       estimate_model, resolve_estimate)
from stepdamp_env.env.layout import HARMONIC_COS, HARMONIC_SIN, OBS
from stepdamp_env.fixedmath import cmul, random_walk_kalman_update
from stepdamp_env.params import DETENT_HARMONICS, ParameterError
from stepdamp_env.response import phasors, torque_paths, torque_to_velocity, velocity_filter

__all__ = ["DelayCompensatedFF", "AdaptiveFF", "OnlineTable", "HARMONICS", "phasors", "torque_paths",
           "harmonic_actions", "harmonic_action_rows", "gather_rows", "phasor_pairs",
           "online_table_fields"]

HARMONICS = DETENT_HARMONICS


def gather_rows(policy: Any, contexts: Sequence[PolicyContext],
                get: Callable[[], dict[str, Any]]) -> dict[str, np.ndarray]:
    """A batched policy's per-row settings: ``policy`` is configured for each
    context (its ``configure``) and what ``get()`` reads of it then is stacked,
    one row per context."""
    rows: dict[str, list[np.ndarray]] = {}
    for context in contexts:
        policy.configure(context)
        for k, v in get().items():
            rows.setdefault(k, []).append(np.array(v, copy=True))
    return {k: np.stack(v) for k, v in rows.items()}


def harmonic_action_rows(applied: np.ndarray, base: np.ndarray, scale: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`harmonic_actions` row by row ((n, 3) phasors, (n,) scales), with the
    phasors the actions really apply (each row the same arithmetic as one call)."""
    scale = scale[:, None]
    delta = (applied - base) / scale
    action = np.empty((len(applied), 6), dtype=np.float32)
    action[:, 0::2] = delta.real
    action[:, 1::2] = delta.imag
    action = np.clip(action, -1.0, 1.0)
    return action, base + scale * (action[:, 0::2].astype(float)
                                   + 1j * action[:, 1::2].astype(float))


def harmonic_actions(applied: np.ndarray, base: np.ndarray, scale: float) -> np.ndarray:
    """Actions that turn the base feedforward ``base`` into ``applied``, clipped
    to the action range [-1, 1] (a policy cannot ask for more)."""
    delta = (applied - base) / scale
    out = np.empty(6, dtype=np.float32)
    out[0::2] = delta.real
    out[1::2] = delta.imag
    return np.clip(out, -1.0, 1.0)


def _applied(action: np.ndarray, base: np.ndarray, scale: float) -> np.ndarray:
    """The feedforward phasors an action really applies."""
    return base + scale * (action[0::2].astype(float) + 1j * action[1::2].astype(float))


def phasor_pairs(z: np.ndarray) -> tuple[float, ...]:
    """Complex numbers as (re, im) pairs, one after the other."""
    return tuple(float(v) for c in z for v in (c.real, c.imag))


def online_table_fields(context: PolicyContext, *, entry: str, estimate: str,
                        base: np.ndarray, action: np.ndarray, scale: float,
                        speed_ref_rad_s: float) -> dict[str, Any]:
    """The :class:`~stepdamp_env.bench.firmware_online.OnlineTableLaw` fields of the
    harmonic policy ``entry`` that learns its table on line in ``context``: its
    detent model (``estimate``), the patent feedforward's phasors ``base`` (N*m),
    its first action and the action's scale, the observation's velocity unit."""
    model = estimate_model(estimate, context.knowledge)
    nominal = context.knowledge.nominal
    return dict(
        entry=entry, motor=nominal.name, mode=context.mode,
        speed_rps=float(context.speed_rps), decision_hz=float(context.agent_hz),
        km_nm_per_a=model.Km,
        # As harmonic_law: the servo's friction feedforward, Fs times 1/Km.
        friction_a=model.Fs * (1.0 / model.Km) if context.mode == "servo" else 0.0,
        base_nm=phasor_pairs(base), action_scale_nm=float(scale),
        initial_action=tuple(float(v) for v in action),
        speed_ref_rad_s=float(speed_ref_rad_s), accel_rps2=float(context.accel_rps2),
        velocity_estimator=("the drive's encoder difference through a first-order low-pass "
                            f"at {nominal.servo.velocity_cutoff_hz!r} Hz, every PWM period"))


class _HarmonicResidual(RowPolicy):
    """Shared by the harmonic policies: harmonic actions on the patent feedforward
    with the model named by ``self.estimate``."""

    estimate: str

    def env_options(self, knowledge: MotorKnowledge) -> dict[str, Any]:
        return {"base_controller": "patent-ff", "action_mode": "harmonic",
                "estimate": resolve_estimate(self.estimate, knowledge)}


class DelayCompensatedFF(_HarmonicResidual):
    """``ff-delay-comp``: the identified feedforward sent as P/G.

    G is evaluated at the held command speed (a speed-dependent phase lead and
    gain derived from the drive model), so during the start-up ramp the lead
    is that of the final speed.
    """

    def __init__(self, estimate: str = "identified") -> None:
        self.name = "ff-delay-comp"
        self.estimate = estimate
        self._action = np.zeros(6, dtype=np.float32)

    def configure(self, context: PolicyContext) -> None:
        model = estimate_model(self.estimate, context.knowledge)
        base = phasors(model)
        g = torque_paths(context.knowledge.nominal, context.mode, context.speed_rps, model)
        self._action = harmonic_actions(base / g, base, context.action_scale)

    def firmware_law(self, context: PolicyContext) -> FirmwareLaw:
        """The harmonic table this entry applies in ``context``'s run
        (:mod:`stepdamp_env.bench.firmware`): the patent feedforward's coefficients
        plus its constant harmonic action as the env applies it (rounded to
        float32, clipped to [-1, 1], times the action scale), over the model's Km."""
        if (type(self).act_batch is not DelayCompensatedFF.act_batch
                or type(self).act is not DelayCompensatedFF.act):
            raise ParameterError(f"entry {self.name!r} cannot be exported: its harmonic "
                                 "table changes while it runs (it learns on line); a firmware "
                                 "table is fixed")
        self.reset(context)
        model = estimate_model(self.estimate, context.knowledge)
        applied = _applied(self._action, phasors(model), context.action_scale)
        coefficients = np.empty(6)
        coefficients[0::2], coefficients[1::2] = applied.real, applied.imag
        what = (f"the {self.estimate} detent model sent through the inverse of the drive's "
                "current path at the held speed (phase lead and gain; in open loop also the "
                "rotor's static lag)" if type(self) is DelayCompensatedFF else
                "its fixed harmonic table at the held speed (see its docstring)")
        return harmonic_law(context, self.name, coefficients, model, notes=(
            f"{self.name}: {what}, as the benchmark applies it: its harmonic action on the "
            "patent feedforward, rounded to float32 and clipped to [-1, 1]."))

    # The law on rows (RowPolicy: a scalar run is row 0): each row configured, its
    # (constant) action kept.
    def reset_batch(self, contexts: Sequence[PolicyContext]) -> None:
        self._rows = gather_rows(self, contexts, lambda: {
            "_action": self._action, "calibration_s": float(getattr(self, "calibration_s", 0.0))})

    def act_batch(self, observations: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return self._rows["_action"][rows]

    def row_calibration_s(self, row: int) -> float:
        return float(self._rows["calibration_s"][row])


class OnlineTable:
    """What the harmonic policies that learn their table on line share: each step
    the rows past their start (the row setting named by ``LIVE_FROM``, in agent
    steps) update their table (``_update_rows``); the action is the rows' table."""

    LIVE_FROM: str

    def act_batch(self, observations: np.ndarray, rows: np.ndarray) -> np.ndarray:
        self._rows_step += 1
        r = self._rows
        live = self._rows_step > r[self.LIVE_FROM][rows]
        if live.any():
            self._update_rows(observations[live], rows[live])
        return r["_action"][rows]

    def _update_rows(self, observations: np.ndarray, idx: np.ndarray) -> None:
        raise NotImplementedError


class AdaptiveFF(OnlineTable, _HarmonicResidual):
    """``adaptive-ff``: cancels what is left of the detent ripple, online.

    Two parts, per harmonic h = 1, 2, 4 at h*Nr*speed:

    * a Kalman filter tracks the phasors R_h of the velocity error
      e = Im(sum_h R_h*exp(j*h*x)) from the filtered velocity error and the
      electrical angle x of each observation (six random-walk states, so the
      ripple's change after each correction is followed);
    * an integrator moves the applied feedforward A_h by mu * R_h/(G_h*H_h),
      with G the current path and H = M*F the rotor's torque-to-speed response
      (open loop: on its spring; servo: inside the loop) times the velocity
      estimator, all from the datasheet model (:mod:`stepdamp_env.response`).

    Since e = Im(sum (D_h - A_h*G_h)*H_h*exp(j*h*x)) for a detent D, the only
    rest point is R = 0, A = D/G, whatever the model's error, as long as its
    phase error stays below 90 degrees: phases that drift with the load (the
    patent's warning) are followed. Each correction is shrunk by the
    estimate's signal-to-noise ratio, max(0, 1 - 4*var R/|R|^2), so a ripple
    buried in the encoder's noise (under 2 sigma) leaves the feedforward alone.

    The model's phase error is small on the motor the model describes, but a
    lightly damped resonance turns a few per cent of error in inertia or
    torque constant into tens of degrees. A guard therefore watches each
    harmonic: after ``start_s`` past the ramp it first measures the ripple of
    the unadapted feedforward for ``probe_s``, and if adapting ever makes a
    harmonic's ripple more than ``guard_ratio`` times that (beyond the noise),
    it puts that harmonic's feedforward back and stops adapting it.

    Args:
        estimate: starting model, "identified" or "nominal".
        step_gain: mu, the fraction of the estimated error corrected per agent
            step (0.02 at 1 kHz: a 50 ms time constant).
        ripple_drift_rad_s: random-walk step of each ripple phasor per agent
            step (rad/s), how fast the estimate may follow a change.
        noise_rad_s: standard deviation of the velocity error not explained
            by the harmonics (encoder quantisation, other ripple) (rad/s).
        start_s: wait after the ramp before adapting (s).
    """

    def __init__(self, estimate: str = "identified", step_gain: float = 0.02,
                 ripple_drift_rad_s: float = 0.005, noise_rad_s: float = 0.3,
                 start_s: float = 0.05, probe_s: float = 0.05,
                 guard_ratio: float = 2.0) -> None:
        self.name = "adaptive-ff"
        self.estimate = estimate
        self.step_gain = step_gain
        self.ripple_drift_rad_s = ripple_drift_rad_s
        self.noise_rad_s = noise_rad_s
        self.start_s = start_s
        self.probe_s = probe_s
        self.guard_ratio = guard_ratio
        self._action = np.zeros(6, dtype=np.float32)

    #: The modes ``stepdamp export`` writes its online table for.
    firmware_modes: tuple[str, ...] = ("open-loop", "servo")

    def firmware_law(self, context: PolicyContext) -> FirmwareLaw:
        """Not a fixed law: the table adapts on line (:meth:`firmware_online`)."""
        raise ParameterError(f"entry {self.name!r} cannot be exported as a fixed law: it "
                             "adapts its harmonic table on line (Kalman filter on the "
                             "velocity error); export writes its online table")

    def firmware_online(self, context: PolicyContext) -> KalmanTable:
        """The law this entry runs in ``context`` for a drive's firmware
        (:mod:`stepdamp_env.bench.firmware_online`): its first table, the filter's
        and the integrator's constants, the guard's."""
        if type(self) is not AdaptiveFF:        # a subclass may move its table otherwise
            raise ParameterError(f"entry {self.name!r} cannot be exported: its law is not "
                                 "the online table AdaptiveFF exports")
        self.configure(context)
        return KalmanTable(
            **online_table_fields(context, entry=self.name, estimate=self.estimate,
                                  base=self._base, action=self._action, scale=self._scale,
                                  speed_ref_rad_s=self._w_ref),
            inverse_path=phasor_pairs(self._inverse_path), start_step=int(self._start_step),
            adapt_step=int(self._adapt_step),
            drift_variance=self._q, noise_variance=self._r,
            initial_variance=float(self._p[0, 0]), step_gain=float(self.step_gain),
            guard_ratio=float(self.guard_ratio),
            notes=(f"{self.name}: ff-delay-comp's table on the {self.estimate} detent model "
                   "to start; the ripple estimated by a Kalman filter on the speed error, "
                   "the table moved against it through the inverse of the current path and "
                   "the rotor's response at the held speed (nominal model)."))

    def configure(self, context: PolicyContext) -> None:
        system = context.knowledge.nominal
        model = estimate_model(self.estimate, context.knowledge)
        self._base = phasors(model)
        g = torque_paths(system, context.mode, context.speed_rps, model)
        w = 2.0 * math.pi * abs(context.speed_rps)
        nr = system.motor.Nr
        h = np.array([torque_to_velocity(system, k * nr * w, context.mode)
                      * velocity_filter(system, k * nr * w) for k in HARMONICS])
        self._inverse_path = 1.0 / cmul(g, h)
        self._w_ref = w
        self._scale = context.action_scale
        # The filter (fixedmath.random_walk_kalman_update: filterpy's recursion in
        # a fixed order, the same for one row and for many).
        self._x = np.zeros(6)
        self._p = np.eye(6) * ((0.1 * w + 1.0) * (0.1 * w + 1.0))
        self._q = self.ripple_drift_rad_s * self.ripple_drift_rad_s
        self._r = self.noise_rad_s * self.noise_rad_s
        self._action = harmonic_actions(self._base / g, self._base, self._scale)
        self._applied = _applied(self._action, self._base, self._scale)
        self._initial = self._applied.copy()
        self._start_step = int(round((context.ramp_s + self.start_s) * context.agent_hz))
        self._adapt_step = self._start_step + int(round(self.probe_s * context.agent_hz))

    # The law on rows (RowPolicy: a scalar run is row 0); the filter is
    # fixedmath.random_walk_kalman_update, the same arithmetic for one row and many.
    _ROW_SETTINGS = ("_base", "_inverse_path", "_w_ref", "_scale", "_action", "_applied",
                     "_initial", "_start_step", "_adapt_step")
    LIVE_FROM = "_start_step"

    def reset_batch(self, contexts: Sequence[PolicyContext]) -> None:
        self._rows = gather_rows(self, contexts, lambda: {
            **{k: getattr(self, k) for k in self._ROW_SETTINGS}, "x": self._x, "P": self._p})
        n = len(contexts)
        self._rows["_reference_power"] = np.zeros((n, 3))
        self._rows["_active"] = np.ones((n, 3), dtype=bool)
        self._rows_kf = (self._q, self._r)
        self._rows_step = 0

    def _update_rows(self, observations: np.ndarray, idx: np.ndarray) -> None:
        r = self._rows
        q, noise = self._rows_kf
        h = np.zeros((len(idx), 6))
        h[:, 0::2] = observations[:, HARMONIC_SIN]
        h[:, 1::2] = observations[:, HARMONIC_COS]
        z = (observations[:, OBS.velocity_error].astype(np.float64) * r["_w_ref"][idx])
        x, p = r["x"][idx], r["P"][idx]
        random_walk_kalman_update(x, p, h, z, q, noise)
        r["x"][idx], r["P"][idx] = x, p
        ripple = x[:, 0::2] + 1j * x[:, 1::2]
        power = x[:, 0::2] * x[:, 0::2] + x[:, 1::2] * x[:, 1::2]
        variance = (np.diagonal(p[:, 0::2, 0::2], axis1=1, axis2=2)
                    + np.diagonal(p[:, 1::2, 1::2], axis1=1, axis2=2))
        probing = self._rows_step <= r["_adapt_step"][idx]
        r["_reference_power"][idx[probing]] = power[probing]
        adapt = ~probing
        if not adapt.any():
            return
        idx, power, variance, ripple = idx[adapt], power[adapt], variance[adapt], ripple[adapt]
        active, applied = r["_active"][idx], r["_applied"][idx]
        diverged = active & (power > self.guard_ratio * r["_reference_power"][idx]
                             + 4.0 * variance)
        active &= ~diverged
        applied = np.where(diverged, r["_initial"][idx], applied)
        weight = active * np.clip(1.0 - 4.0 * variance / np.maximum(power, 1e-300), 0.0, 1.0)
        target = applied + self.step_gain * weight * cmul(ripple, r["_inverse_path"][idx])
        r["_action"][idx], r["_applied"][idx] = harmonic_action_rows(target, r["_base"][idx],
                                                                     r["_scale"][idx])
        r["_active"][idx] = active

