"""The firmware law's definition: :class:`FirmwareLaw`, its Python reference
:func:`correction` and its JSON (see :mod:`stepdamp_env.bench.firmware`)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from .. import fixedmath as fm
from ..params import ParameterError
from ..simulation import MODES
from ..version import __version__

__all__ = ["FirmwareLaw", "FilteredFeedback", "FILTER_KINDS", "FORMAT_ID", "correction",
           "position_lowpass", "filtered_feedback_currents", "microstep_table", "to_json",
           "from_json"]

#: The JSON file's ``format`` tag (its layout's name and version): /2 adds the
#: high-passed position feedback, /3 the filtered feedback (:class:`FilteredFeedback`);
#: a law without them is written as /1, as before.
FORMAT_ID = "stepdamp-firmware-law/3"
_FORMAT_V2 = "stepdamp-firmware-law/2"
_FORMAT_V1 = "stepdamp-firmware-law/1"

#: The filtered feedback's kinds: "encoder" (``velocity-feedback``: the speed error
#: and the high-passed position error, both low-passed) and "back-emf"
#: (``sensorless-damping``: the speed error low-passed and its difference).
FILTER_KINDS = ("encoder", "back-emf")


def _finite(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(float(value)):
        raise ParameterError(f"{name}={value!r} must be a finite number")
    return float(value)


def _count(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ParameterError(f"{name}={value!r} must be an integer >= 1")
    return int(value)


@dataclass(frozen=True)
class FilteredFeedback:
    """A feedback current computed every ``periods_per_update`` PWM periods (the
    agent rate) from filtered signals, and held in between: the law of
    ``velocity-feedback`` ("encoder") and ``sensorless-damping`` ("back-emf").

    At each update, from the speed error ``e_w`` (shaft rad/s, the drive's speed
    estimate) and, for "encoder", the position error ``e_theta`` (shaft rad),
    with states started at the first update (``e_lp = e_theta``, ``f_w = e_w``,
    ``f_p = 0``; "back-emf": ``f_w = e_w``)::

        encoder:  e_lp += highpass_alpha*(e_theta - e_lp)
                  f_w  += lowpass_beta*(e_w - f_w)
                  f_p  += lowpass_beta*(e_theta - e_lp - f_p)
                  i = gain_a*f_w + gain_b*f_p
        back-emf: f_prev = f_w;  f_w += lowpass_beta*(e_w - f_w)
                  i = gain_a*f_w + gain_b*(f_w - f_prev)

    then ``u = clip(i/current_scale_a, -1, 1)`` rounded to float32 (the
    benchmark's action; a relative step of 6e-8) and the current ``u *
    current_scale_a`` (A) is added to the q-current command until the next update.
    The inputs are the errors as the benchmark's policy reads them: its
    observations are float32 and bounded (at 10 times the command speed and 10
    full steps), so the law is the simulated one bit for bit for those values;
    a drive feeds its own errors.

    Attributes:
        kind: one of :data:`FILTER_KINDS`.
        periods_per_update: PWM periods per update (pwm_hz / agent_hz).
        gain_a: on the low-passed speed error (A*s/rad).
        gain_b: "encoder": on the low-passed high-passed position error (A/rad);
            "back-emf": on the difference of successive low-passed speed
            errors (A*s/rad).
        lowpass_beta: the low-passes' coefficient per update, in (0, 1].
        highpass_alpha: the position high-pass's coefficient per update, in
            [0, 1] ("encoder"; 0 for "back-emf").
        current_scale_a: the current at action 1.0 (A): the feedback's bound.
    """

    kind: str
    periods_per_update: int
    gain_a: float
    gain_b: float
    lowpass_beta: float
    highpass_alpha: float
    current_scale_a: float

    def __post_init__(self) -> None:
        if self.kind not in FILTER_KINDS:
            raise ParameterError(f"kind={self.kind!r} is not one of {list(FILTER_KINDS)}")
        object.__setattr__(self, "periods_per_update",
                           _count("periods_per_update", self.periods_per_update))
        for name in ("gain_a", "gain_b", "lowpass_beta", "highpass_alpha", "current_scale_a"):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
        if not 0.0 < self.lowpass_beta <= 1.0:
            raise ParameterError(f"lowpass_beta={self.lowpass_beta!r} is outside its allowed "
                                 "range (0, 1]")
        if not 0.0 <= self.highpass_alpha <= 1.0:
            raise ParameterError(f"highpass_alpha={self.highpass_alpha!r} is outside its "
                                 "allowed range [0, 1]")
        if not self.current_scale_a > 0.0:
            raise ParameterError(f"current_scale_a={self.current_scale_a!r} must be > 0")
        if self.kind == "back-emf" and self.highpass_alpha != 0.0:
            raise ParameterError("highpass_alpha must be 0 for kind 'back-emf' (no position)")


@dataclass(frozen=True)
class FirmwareLaw:
    """One entry's damping law at one operating point (see the module docstring).

    Attributes:
        entry: the leaderboard entry it comes from (e.g. "ff-delay-comp").
        motor: the motor's name (its system's ``name``).
        mode: "open-loop" or "servo": which angle ``x`` is (module docstring)
            and whether the friction term applies.
        speed_rps: the held command speed the table was computed for (rev/s,
            positive direction, as the benchmark runs).
        pwm_hz: the drive's PWM and control rate (Hz); the benchmark's drive
            evaluates the law once per period from the samples of the period before.
        nr: rotor teeth: electrical angle = ``nr`` * shaft angle.
        microsteps: microsteps per full step; one electrical period is
            4 * ``microsteps`` microsteps (the microstep table's length).
        km_nm_per_a: torque constant of the model the feedforward divides by (N*m/A).
        harmonics: the detent harmonics h of the table (1, 2, 4).
        amplitude_a: q-current amplitude A_h of each harmonic (A).
        phase_rad: phase phi_h of each harmonic (rad, electrical):
            the term is A_h * sin(h*x + phi_h).
        friction_a: the servo's friction feedforward Fs/Km (A), added with the
            sign of the command speed (0 in open loop).
        velocity_gain_a_s_per_rad: Kv, q current per shaft rad/s of velocity
            error (A*s/rad); 0 for a feedforward-only law.
        feedback_limit_a: I_max, the bound of the feedback's current
            (A); ``math.inf`` when it has none.
        position_gain_a_per_rad: Kp, q current per shaft rad of high-passed
            position error (A/rad); 0: no position term (a stateless law).
        position_highpass_alpha: the high-pass's coefficient per PWM period,
            1 - exp(-2*pi*fc/pwm_hz), in [0, 1].
        velocity_estimator: how the drive measures the speed in ``e_w`` (text).
        notes: what the entry does, in a sentence or two.
        filtered_feedback: the feedback held over agent steps
            (:class:`FilteredFeedback`), or None; a law has it or the
            per-period gains (Kv, Kp), not both.
    """

    entry: str
    motor: str
    mode: str
    speed_rps: float
    pwm_hz: float
    nr: int
    microsteps: int
    km_nm_per_a: float
    harmonics: tuple[int, ...]
    amplitude_a: tuple[float, ...]
    phase_rad: tuple[float, ...]
    friction_a: float = 0.0
    velocity_gain_a_s_per_rad: float = 0.0
    feedback_limit_a: float = math.inf
    velocity_estimator: str = ""
    notes: str = ""
    position_gain_a_per_rad: float = 0.0
    position_highpass_alpha: float = 0.0
    filtered_feedback: FilteredFeedback | None = None

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ParameterError(f"mode={self.mode!r} is not one of {list(MODES)}")
        for name in ("speed_rps", "pwm_hz", "km_nm_per_a", "friction_a",
                     "velocity_gain_a_s_per_rad", "position_gain_a_per_rad",
                     "position_highpass_alpha"):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
        if not 0.0 <= self.position_highpass_alpha <= 1.0:
            raise ParameterError(f"position_highpass_alpha={self.position_highpass_alpha!r} "
                                 "is outside its allowed range [0, 1]")
        if self.position_gain_a_per_rad == 0.0:      # no position term: no high-pass either
            object.__setattr__(self, "position_highpass_alpha", 0.0)
        for name in ("pwm_hz", "km_nm_per_a"):
            if not getattr(self, name) > 0.0:
                raise ParameterError(f"{name}={getattr(self, name)!r} must be > 0")
        object.__setattr__(self, "nr", _count("nr", self.nr))
        object.__setattr__(self, "microsteps", _count("microsteps", self.microsteps))
        limit = self.feedback_limit_a
        if isinstance(limit, bool) or not isinstance(limit, (int, float, np.integer, np.floating)) \
                or not float(limit) > 0.0:
            raise ParameterError(f"feedback_limit_a={limit!r} must be > 0 (math.inf: no limit)")
        object.__setattr__(self, "feedback_limit_a", float(limit))
        harmonics = tuple(_count("harmonics", h) for h in self.harmonics)
        amplitude = tuple(_finite("amplitude_a", a) for a in self.amplitude_a)
        phase = tuple(_finite("phase_rad", p) for p in self.phase_rad)
        if not len(harmonics) == len(amplitude) == len(phase):
            raise ParameterError(f"harmonics, amplitude_a and phase_rad must have one entry per "
                                 f"harmonic; got {len(harmonics)}, {len(amplitude)}, {len(phase)}")
        object.__setattr__(self, "harmonics", harmonics)
        object.__setattr__(self, "amplitude_a", amplitude)
        object.__setattr__(self, "phase_rad", phase)
        for name in ("entry", "motor", "velocity_estimator", "notes"):
            if not isinstance(getattr(self, name), str):
                raise ParameterError(f"{name}={getattr(self, name)!r} must be text")
        f = self.filtered_feedback
        if f is not None:
            if not isinstance(f, FilteredFeedback):
                raise ParameterError(f"filtered_feedback={f!r} must be a FilteredFeedback or "
                                     "None")
            if self.velocity_gain_a_s_per_rad != 0.0 or self.position_gain_a_per_rad != 0.0:
                raise ParameterError("a law with filtered_feedback has no per-period gains "
                                     "(velocity_gain_a_s_per_rad and position_gain_a_per_rad "
                                     "must be 0)")

    @property
    def stateful(self) -> bool:
        """Whether the law has the position term (and so one state, ``e_lp``, an
        argument of :func:`correction`); a filtered feedback keeps its own states
        (:class:`FilteredFeedback`)."""
        return self.position_gain_a_per_rad != 0.0

    @property
    def table_size(self) -> int:
        """Microsteps per electrical period: 4 full steps of ``microsteps`` each."""
        return 4 * self.microsteps

    def coefficients_nm(self) -> tuple[float, ...]:
        """The table as torque sin/cos coefficients (N*m), (s1, c1, s2, c2, s4, c4)
        for harmonics 1, 2, 4: A_h*Km*sin(h x + phi_h) = s_h sin(h x) + c_h cos(h x)."""
        out: list[float] = []
        for a, p in zip(self.amplitude_a, self.phase_rad):
            out += [a * self.km_nm_per_a * fm.cos(p), a * self.km_nm_per_a * fm.sin(p)]
        return tuple(out)


def correction(law: FirmwareLaw, electrical_angle_rad: Any, velocity_error_rad_s: Any = 0.0,
               command_speed_rad_s: Any = 0.0, position_error_rad: Any = 0.0,
               position_lowpass_rad: Any = 0.0) -> Any:
    """The q current (A) the law adds to the drive's q-current command.

    Args:
        electrical_angle_rad: x, the drive's Park angle (rad) = Nr * shaft angle
            (module docstring); any value, periodic in 2*pi.
        velocity_error_rad_s: e_w = w_cmd - w_est (shaft rad/s).
        command_speed_rad_s: w_cmd (shaft rad/s); only its sign is used (the
            servo's friction feedforward).
        position_error_rad: e_theta = theta_cmd - theta_encoder (shaft rad),
            used where the law has a position term.
        position_lowpass_rad: the high-pass's state e_lp before this period
            (:func:`position_lowpass`; 0 at the start).

    A :class:`FilteredFeedback`'s held current is not in it: add
    :func:`filtered_feedback_currents`. Scalars give a float, arrays (broadcast
    together) an array. The sum is
    taken in the order of :func:`c_source`'s function; the sines are the
    kernel's fixed-order ones (:mod:`stepdamp_env.fixedmath`: the same bits on
    every CPU, within a few ulp of the C library's while |h*x| < 1e6 rad).
    """
    x = np.asarray(electrical_angle_rad, dtype=np.float64)
    e_w = np.asarray(velocity_error_rad_s, dtype=np.float64)
    w_cmd = np.asarray(command_speed_rad_s, dtype=np.float64)
    iq = np.zeros(np.broadcast_shapes(x.shape, e_w.shape, w_cmd.shape))
    for h, a, p in zip(law.harmonics, law.amplitude_a, law.phase_rad):
        arg = np.ascontiguousarray(np.broadcast_to(float(h) * x + p, iq.shape)).reshape(-1)
        iq = iq + a * fm.sincos_array(arg)[0].reshape(iq.shape)
    iq = iq + law.friction_a * np.sign(w_cmd)
    feedback = law.velocity_gain_a_s_per_rad * e_w
    if law.stateful:
        e_theta = np.asarray(position_error_rad, dtype=np.float64)
        e_lp = np.asarray(position_lowpass_rad, dtype=np.float64)
        e_lp = e_lp + law.position_highpass_alpha * (e_theta - e_lp)
        feedback = feedback + law.position_gain_a_per_rad * (e_theta - e_lp)
    feedback = np.clip(feedback, -law.feedback_limit_a, law.feedback_limit_a)
    out = iq + feedback
    return float(out) if out.ndim == 0 else out


def position_lowpass(law: FirmwareLaw, position_error_rad: Any, start_rad: float = 0.0
                     ) -> np.ndarray:
    """The high-pass's state e_lp before each period of a sequence of position
    errors (rad, one per PWM period), from ``start_rad``: what :func:`correction`
    takes as ``position_lowpass_rad`` for each, as the kernel and the C keep it."""
    e = np.asarray(position_error_rad, dtype=np.float64).reshape(-1)
    out = np.empty_like(e)
    state, alpha = float(start_rad), law.position_highpass_alpha
    for k in range(len(e)):
        out[k] = state
        state = state + alpha * (e[k] - state)
    return out


def filtered_feedback_currents(law: FirmwareLaw, velocity_error_rad_s: Any,
                               position_error_rad: Any = 0.0) -> np.ndarray:
    """The current (A) the law's :class:`FilteredFeedback` holds after each update,
    from the start: one speed error (rad/s) and position error (rad; "encoder"
    only) per update, in order, as the C's update function and the simulation
    compute it (float64, the action rounded to float32)."""
    f = law.filtered_feedback
    if f is None:
        raise ParameterError(f"the law of {law.entry!r} has no filtered feedback")
    e_w = np.asarray(velocity_error_rad_s, dtype=np.float64).reshape(-1)
    e_theta = np.broadcast_to(np.asarray(position_error_rad, dtype=np.float64), e_w.shape)
    out = np.empty_like(e_w)
    to_action = 1.0 / f.current_scale_a
    # The states start at the first update's inputs.
    lp, fw, fp = (float(e_theta[0]), float(e_w[0]), 0.0) if len(e_w) else (0.0, 0.0, 0.0)
    for k in range(len(e_w)):
        if f.kind == "encoder":
            lp = lp + f.highpass_alpha * (e_theta[k] - lp)
            fw = fw + f.lowpass_beta * (e_w[k] - fw)
            fp = fp + f.lowpass_beta * (e_theta[k] - lp - fp)
            current = f.gain_a * fw + f.gain_b * fp
        else:
            previous = fw
            fw = fw + f.lowpass_beta * (e_w[k] - fw)
            current = f.gain_a * fw + f.gain_b * (fw - previous)
        u = np.float32(min(max(current * to_action, -1.0), 1.0))
        out[k] = float(u) * f.current_scale_a
    return out


def microstep_table(law: FirmwareLaw) -> np.ndarray:
    """The angle part of the correction at each microstep of one electrical period (A).

    Entry k is ``correction(law, 2*pi*k/(4*microsteps))`` (no velocity error,
    no friction term): the feedforward current at microstep count n with
    k = n mod 4*microsteps, counted from the shaft angle where x = 0. In open
    loop the drive's Park angle is always on such a microstep, so the table is
    exact there; the velocity feedback and the servo's friction term are added
    by the driver (``velocity_gain_a_s_per_rad``, ``friction_a``).
    """
    k = np.arange(law.table_size, dtype=np.float64)
    return np.asarray(correction(law, 2.0 * math.pi * k / law.table_size), dtype=np.float64)


_JSON_FIELDS = ("entry", "motor", "mode", "speed_rps", "pwm_hz", "nr", "microsteps",
                "km_nm_per_a", "friction_a", "velocity_gain_a_s_per_rad", "feedback_limit_a",
                "velocity_estimator", "notes")
_CONVENTION = ("iq_a = sum_h amplitude_a*sin(h*x + phase_rad) + friction_a*sign(w_cmd) "
               "+ clip(velocity_gain_a_s_per_rad*e_w, -feedback_limit_a, feedback_limit_a); "
               "x = Nr*shaft angle (electrical, rad) of the drive's Park transform (open loop: "
               "the microstep-quantised command; servo: encoder + half a count), e_w = w_cmd - "
               "w_est (shaft rad/s), iq_a (A) added to the q-current command, positive = "
               "positive torque; feedback_limit_a null = no limit; microstep_table_a[k] = the "
               "harmonic part at x = 2*pi*k/(4*microsteps)")
_POSITION_FIELDS = ("position_gain_a_per_rad", "position_highpass_alpha")
_CONVENTION_V2 = (_CONVENTION.replace(
    "clip(velocity_gain_a_s_per_rad*e_w, ", "clip(velocity_gain_a_s_per_rad*e_w + "
    "position_gain_a_per_rad*hp, ") + "; hp = e_theta - e_lp after e_lp += "
    "position_highpass_alpha*(e_theta - e_lp), e_theta = theta_cmd - theta_encoder (shaft "
    "rad), e_lp a state kept from PWM period to PWM period, 0 at the start")
_FILTER_FIELDS = tuple(f.name for f in dataclasses.fields(FilteredFeedback))
_CONVENTION_V3 = (_CONVENTION_V2 + "; plus, every filtered_feedback.periods_per_update PWM "
                  "periods, a current held until the next update: filtered_feedback's "
                  "filters (kind encoder: i = gain_a*lp(e_w) + gain_b*lp(hp(e_theta)); kind "
                  "back-emf: i = gain_a*lp(e_w) + gain_b*(lp(e_w) - its previous value); "
                  "lp: f += lowpass_beta*(x - f), hp: e_theta - e_lp after e_lp += "
                  "highpass_alpha*(e_theta - e_lp), every state started at the first "
                  "update's input, f_p at 0), held as float32(clip(i/current_scale_a, -1, "
                  "1))*current_scale_a (A)")


def to_json(law: FirmwareLaw) -> dict[str, Any]:
    """The law as a JSON object: its fields, the harmonic table as rows, the
    convention in words and the microstep table (A); :func:`from_json` reads it back."""
    filtered = law.filtered_feedback is not None
    out: dict[str, Any] = {"format": FORMAT_ID if filtered else _FORMAT_V2 if law.stateful
                           else _FORMAT_V1, "generator": f"stepdamp {__version__}"}
    for name in _JSON_FIELDS + (_POSITION_FIELDS if law.stateful or filtered else ()):
        out[name] = getattr(law, name)
    if filtered:
        out["filtered_feedback"] = {k: getattr(law.filtered_feedback, k) for k in _FILTER_FIELDS}
    if math.isinf(law.feedback_limit_a):
        out["feedback_limit_a"] = None          # JSON has no infinity
    out["harmonic_table"] = [
        {"harmonic": h, "amplitude_a": a, "phase_rad": p, "amplitude_nm": a * law.km_nm_per_a}
        for h, a, p in zip(law.harmonics, law.amplitude_a, law.phase_rad)]
    out["convention"] = (_CONVENTION_V3 if filtered else _CONVENTION_V2 if law.stateful
                         else _CONVENTION)
    out["microstep_table_a"] = microstep_table(law).tolist()
    return out


def from_json(data: Mapping[str, Any]) -> FirmwareLaw:
    """The law of a :func:`to_json` object (derived items are not read back)."""
    formats = (FORMAT_ID, _FORMAT_V2, _FORMAT_V1)
    if not isinstance(data, Mapping) or data.get("format") not in formats:
        raise ParameterError(f"firmware law JSON must be an object with format one of "
                             f"{list(formats)}")
    fields = _JSON_FIELDS + (_POSITION_FIELDS if data["format"] != _FORMAT_V1 else ()) \
        + (("filtered_feedback",) if data["format"] == FORMAT_ID else ())
    missing = [k for k in (*fields, "harmonic_table") if k not in data]
    if missing:
        raise ParameterError(f"firmware law JSON lacks {missing}")
    rows = data["harmonic_table"]
    if not isinstance(rows, list) or not all(isinstance(r, Mapping) and
                                             {"harmonic", "amplitude_a", "phase_rad"} <= set(r)
                                             for r in rows):
        raise ParameterError("harmonic_table must be a list of {harmonic, amplitude_a, "
                             "phase_rad} objects")
    values = {k: data[k] for k in fields}
    if "filtered_feedback" in values:
        block = values["filtered_feedback"]
        if not isinstance(block, Mapping) or set(block) != set(_FILTER_FIELDS):
            raise ParameterError(f"filtered_feedback must be an object with exactly "
                                 f"{list(_FILTER_FIELDS)}")
        values["filtered_feedback"] = FilteredFeedback(**{k: block[k] for k in _FILTER_FIELDS})
    if values["feedback_limit_a"] is None:
        values["feedback_limit_a"] = math.inf
    return FirmwareLaw(**values, harmonics=tuple(r["harmonic"] for r in rows),
                       amplitude_a=tuple(r["amplitude_a"] for r in rows),
                       phase_rad=tuple(r["phase_rad"] for r in rows))
