"""Firmware out: a damping law's tables and gains, as JSON or as C99 (issue #34, point 6).

A :class:`FirmwareLaw` describes what an entry's drive adds to its q-current
command at one operating point (motor, mode, held command speed), in the terms
the kernel (:mod:`stepdamp_env.kernel`) applies it::

    iq(x, e_w, w_cmd) = sum_h A_h * sin(h*x + phi_h)            harmonic table, h = 1, 2, 4
                      + F * sign(w_cmd)                           servo only: friction feedforward
                      + clip(Kv * e_w, -I_max, I_max)             velocity feedback (if any)

* ``x``: the electrical angle of the drive's Park transform (rad), Nr times the
  shaft angle: in open loop Nr times the microstep-quantised command angle, in
  servo Nr times (the encoder angle + half a count), as the kernel takes it;
* ``e_w = w_cmd - w_est``: the command speed minus the drive's own speed
  estimate (shaft rad/s), positive while the rotor lags;
* the result is in A; positive q current gives positive torque (the positive
  direction of rotation). ``A_h`` is the q-current amplitude (A): the detent
  torque amplitude (N*m) the feedforward cancels divided by the torque constant
  ``km_nm_per_a`` of the model it uses.

The harmonic table holds for the held command speed it was exported at
(``speed_rps``): a delay-compensated table leads by the current path's phase at
that speed (:func:`stepdamp_env.response.torque_paths`), as the benchmark's
entries compute it once per run. :func:`correction` is the Python reference,
:func:`microstep_table` the angle part at each microstep of one electrical
period (for table-driven drivers), :func:`c_source` a C99 header and source
with one function that computes the same to rounding, :func:`export_law` writes
either format.

Entries describe themselves: a policy with a ``firmware_law(context:
PolicyContext) -> FirmwareLaw`` method (duck-typed; the baselines build theirs
with :func:`harmonic_law`) can be exported; :class:`~.policy.ZeroAction` (the
``patent-ff-*`` entries) is handled here. :func:`entry_law` turns an entry name
and a :class:`~.policy.MotorKnowledge` (:func:`firmware_knowledge` for a motor
file) into its law, or a one-line ``ParameterError`` saying why it cannot be
exported (learned, adaptive, stateful or oracle entries).
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from .. import fixedmath as fm
from ..analysis import bridge_limit_rps
from ..io import write_json, write_text
from ..params import DETENT_HARMONICS, FeedforwardModel, ParameterError, SystemParams
from ..simulation import DEFAULT_ACCEL_RPS2, MODES
from ..version import __version__
from .policy import (MotorKnowledge, PolicyContext, ZeroAction, estimate_model, policy_card,
                     policy_context, policy_env_options)
from .registry import resolve_policy
from .rig import CalibrationRig

__all__ = ["FirmwareLaw", "FORMATS", "FORMAT_ID", "correction", "microstep_table", "to_json",
           "from_json", "c_source", "export_law", "default_prefix", "harmonic_law",
           "firmware_knowledge", "default_speed_rps", "policy_law", "entry_law"]

#: What ``export_law`` writes: "json" (``<prefix>.json``) or "c" (``<prefix>.h``, ``<prefix>.c``).
FORMATS = ("c", "json")
#: The JSON file's ``format`` tag (its layout's name and version).
FORMAT_ID = "stepdamp-firmware-law/1"

# A C identifier that is safe as a file name too (no leading underscore: reserved in C).
_PREFIX = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,39}")
_C_KEYWORDS = frozenset(
    "auto break case char const continue default do double else enum extern float for goto "
    "if inline int long register restrict return short signed sizeof static struct switch "
    "typedef union unsigned void volatile while".split())


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
        feedback_limit_a: I_max, the bound of the velocity feedback's current
            (A); ``math.inf`` when it has none.
        velocity_estimator: how the drive measures the speed in ``e_w`` (text).
        notes: what the entry does, in a sentence or two.
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

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ParameterError(f"mode={self.mode!r} is not one of {list(MODES)}")
        for name in ("speed_rps", "pwm_hz", "km_nm_per_a", "friction_a",
                     "velocity_gain_a_s_per_rad"):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
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
               command_speed_rad_s: Any = 0.0) -> Any:
    """The q current (A) the law adds to the drive's q-current command.

    Args:
        electrical_angle_rad: x, the drive's Park angle (rad) = Nr * shaft angle
            (module docstring); any value, periodic in 2*pi.
        velocity_error_rad_s: e_w = w_cmd - w_est (shaft rad/s).
        command_speed_rad_s: w_cmd (shaft rad/s); only its sign is used (the
            servo's friction feedforward).

    Scalars give a float, arrays (broadcast together) an array. The sum is
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
    feedback = np.clip(law.velocity_gain_a_s_per_rad * e_w, -law.feedback_limit_a,
                       law.feedback_limit_a)
    out = iq + feedback
    return float(out) if out.ndim == 0 else out


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


def to_json(law: FirmwareLaw) -> dict[str, Any]:
    """The law as a JSON object: its fields, the harmonic table as rows, the
    convention in words and the microstep table (A); :func:`from_json` reads it back."""
    out: dict[str, Any] = {"format": FORMAT_ID, "generator": f"stepdamp {__version__}"}
    for name in _JSON_FIELDS:
        out[name] = getattr(law, name)
    if math.isinf(law.feedback_limit_a):
        out["feedback_limit_a"] = None          # JSON has no infinity
    out["harmonic_table"] = [
        {"harmonic": h, "amplitude_a": a, "phase_rad": p, "amplitude_nm": a * law.km_nm_per_a}
        for h, a, p in zip(law.harmonics, law.amplitude_a, law.phase_rad)]
    out["convention"] = _CONVENTION
    out["microstep_table_a"] = microstep_table(law).tolist()
    return out


def from_json(data: Mapping[str, Any]) -> FirmwareLaw:
    """The law of a :func:`to_json` object (derived items are not read back)."""
    if not isinstance(data, Mapping) or data.get("format") != FORMAT_ID:
        raise ParameterError(f"firmware law JSON must be an object with format {FORMAT_ID!r}")
    missing = [k for k in (*_JSON_FIELDS, "harmonic_table") if k not in data]
    if missing:
        raise ParameterError(f"firmware law JSON lacks {missing}")
    rows = data["harmonic_table"]
    if not isinstance(rows, list) or not all(isinstance(r, Mapping) and
                                             {"harmonic", "amplitude_a", "phase_rad"} <= set(r)
                                             for r in rows):
        raise ParameterError("harmonic_table must be a list of {harmonic, amplitude_a, "
                             "phase_rad} objects")
    values = {k: data[k] for k in _JSON_FIELDS}
    if values["feedback_limit_a"] is None:
        values["feedback_limit_a"] = math.inf
    return FirmwareLaw(**values, harmonics=tuple(r["harmonic"] for r in rows),
                       amplitude_a=tuple(r["amplitude_a"] for r in rows),
                       phase_rad=tuple(r["phase_rad"] for r in rows))


def default_prefix(entry: str) -> str:
    """A C prefix from an entry name: "tuned-constant-gain" -> "tuned_constant_gain"."""
    text = re.sub(r"[^A-Za-z0-9]+", "_", os.path.basename(entry)).strip("_")[:40].rstrip("_")
    if not text or not text[0].isalpha():
        text = ("law_" + text)[:40].rstrip("_")
    return text


def _check_prefix(prefix: str) -> str:
    if not isinstance(prefix, str) or not _PREFIX.fullmatch(prefix) or prefix in _C_KEYWORDS:
        raise ParameterError(f"prefix={prefix!r} must be a C identifier of 1-40 letters, digits "
                             "and underscores starting with a letter (it names the files and "
                             "the function)")
    return prefix


def _c(value: float) -> str:
    """A double literal that parses back to ``value`` exactly (repr is round-trip)."""
    text = repr(float(value))
    if not math.isfinite(value):
        raise ParameterError(f"cannot write the non-finite value {text} as a C literal")
    return text


def _comment(text: str) -> str:
    """``text`` made safe inside a C block comment, wrapped at 86 columns."""
    words = text.replace("*/", "* /").split()
    lines, line = [], ""
    for w in words:
        if line and len(line) + 1 + len(w) > 86:
            lines.append(line)
            line = w
        else:
            line = f"{line} {w}" if line else w
    return "\n".join(f" * {x}" for x in lines + ([line] if line else []))


def c_source(law: FirmwareLaw, prefix: str | None = None) -> tuple[str, str]:
    """(header text, source text) of a self-contained C99 implementation of the law.

    The header declares one function, ``double <prefix>_iq_correction_a(double
    electrical_angle_rad, double velocity_error_rad_s, double command_speed_rad_s)``,
    which returns :func:`correction` (A) computed in double with ``sin`` from
    ``<math.h>`` (no state, no allocation, no globals to initialise), and the
    constant microstep table ``<prefix>_microstep_table_a`` (A, :func:`microstep_table`).
    The source includes ``"<prefix>.h"``. Compiles clean with ``-std=c99 -Wall
    -Wextra -Werror -pedantic``; link with ``-lm``.
    """
    prefix = _check_prefix(default_prefix(law.entry) if prefix is None else prefix)
    macro = prefix.upper()
    fn = f"{prefix}_iq_correction_a"
    table = f"{prefix}_microstep_table_a"
    n = len(law.harmonics)
    limited = math.isfinite(law.feedback_limit_a)
    limit_text = f"{law.feedback_limit_a!r} A" if limited else "none (no limit)"
    hs = ", ".join(map(str, law.harmonics))
    harmonic_rows = "\n".join(
        f" *   h = {h}: A = {a!r} A ({a * law.km_nm_per_a!r} N*m), phi = {p!r} rad"
        for h, a, p in zip(law.harmonics, law.amplitude_a, law.phase_rad))
    header = f"""/*
 * {prefix}.h: the damping law "{law.entry}" for motor "{law.motor}",
 * exported by stepdamp {__version__} (stepdamp export). Generated: re-export, do not edit.
 *
 * Operating point: {law.mode}, held command speed {law.speed_rps!r} rev/s, evaluated every
 * PWM period at {law.pwm_hz!r} Hz from the samples of the period before.
{_comment(law.notes)}
 *
 * Harmonic table (q-current amplitude A_h and electrical phase phi_h; torque = A_h*Km,
 * Km = {law.km_nm_per_a!r} N*m/A):
{harmonic_rows}
 *
{_comment(f"Friction feedforward F = {law.friction_a!r} A; velocity gain Kv = "
          f"{law.velocity_gain_a_s_per_rad!r} A*s/rad; feedback limit I_max = {limit_text}. "
          "Speed estimate in the velocity error: "
          f"{law.velocity_estimator or 'not used (Kv = 0)'}.")}
 */
#ifndef {macro}_H
#define {macro}_H

/* Rotor teeth: electrical angle = NR * shaft angle. */
#define {macro}_NR {law.nr}
/* Microsteps per full step. */
#define {macro}_MICROSTEPS {law.microsteps}
/* Microsteps per electrical period (4 full steps): the microstep table's length. */
#define {macro}_TABLE_SIZE {law.table_size}

/*
 * {fn}: the q-axis current correction (A) of the law.
 *
 *   iq = sum_h A_h * sin(h*x + phi_h)                   (harmonic table above, h = {hs})
 *      + F * sign(command_speed_rad_s)                  (servo's friction feedforward)
 *      + clamp(Kv * velocity_error_rad_s, -I_max, I_max) (velocity feedback)
 *
 * electrical_angle_rad  x (rad): the electrical angle of the drive's Park transform,
 *                       NR * shaft angle; open loop: NR * the microstep-quantised command
 *                       angle; servo: NR * (encoder angle + half a count). Any value;
 *                       wrapped to one period it loses the least to rounding.
 * velocity_error_rad_s  e_w = w_cmd - w_est (shaft rad/s): the command speed minus the
 *                       drive's speed estimate; positive while the rotor lags.
 * command_speed_rad_s   w_cmd (shaft rad/s); only its sign is used.
 * Returns               the correction (A) to add to the q-current command; positive q
 *                       current gives positive torque (positive direction of rotation).
 *
 * Pure: no state, no allocation, no globals to set up; double precision, sin() from
 * <math.h> only (link with -lm).
 */
double {fn}(double electrical_angle_rad, double velocity_error_rad_s,
        double command_speed_rad_s);

/*
{_comment(f"{table}[k]: the harmonic part of the correction (A) at x = "
          f"2*pi*k/{macro}_TABLE_SIZE, i.e. {fn}(x, 0.0, 0.0), for table-driven drivers: k = "
          f"the microstep count modulo {macro}_TABLE_SIZE (the non-negative remainder), counted "
          "from the shaft angle where "
          f"x = 0. Add the velocity feedback and the friction term as {fn} does.")}
 */
extern const double {table}[{macro}_TABLE_SIZE];

#endif /* {macro}_H */
"""
    values = microstep_table(law)
    rows = ",\n".join("    " + ", ".join(_c(v) for v in values[i:i + 4])
                      for i in range(0, len(values), 4))
    if limited:
        clamp = f"""    if (feedback_a > {_c(law.feedback_limit_a)}) {{
        feedback_a = {_c(law.feedback_limit_a)};
    }} else if (feedback_a < {_c(-law.feedback_limit_a)}) {{
        feedback_a = {_c(-law.feedback_limit_a)};
    }}
"""
    else:
        clamp = "    /* no limit on the feedback current */\n"
    source = f"""/* {prefix}.c: see {prefix}.h (generated by stepdamp {__version__}). */
#include "{prefix}.h"

#include <math.h>

const double {table}[{macro}_TABLE_SIZE] = {{
{rows}
}};

double {fn}(double electrical_angle_rad, double velocity_error_rad_s,
        double command_speed_rad_s)
{{
    static const double harmonic[{n}] = {{{", ".join(_c(h) for h in law.harmonics)}}};
    static const double amplitude_a[{n}] = {{{", ".join(_c(a) for a in law.amplitude_a)}}};
    static const double phase_rad[{n}] = {{{", ".join(_c(p) for p in law.phase_rad)}}};
    double iq_a = 0.0;
    double feedback_a;
    int k;

    for (k = 0; k < {n}; ++k) {{
        iq_a += amplitude_a[k] * sin(harmonic[k] * electrical_angle_rad + phase_rad[k]);
    }}
    /* The servo's friction feedforward, with the command's sign (0 at rest). */
    if (command_speed_rad_s > 0.0) {{
        iq_a += {_c(law.friction_a)};
    }} else if (command_speed_rad_s < 0.0) {{
        iq_a -= {_c(law.friction_a)};
    }}
    feedback_a = {_c(law.velocity_gain_a_s_per_rad)} * velocity_error_rad_s;
{clamp}    return iq_a + feedback_a;
}}
"""
    return header, source


def export_law(law: FirmwareLaw, fmt: str, out_dir: str | os.PathLike[str],
               prefix: str | None = None) -> list[str]:
    """Write the law into ``out_dir`` (made if needed), each file atomically:
    ``<prefix>.json`` (fmt "json", :func:`to_json`) or ``<prefix>.h`` and
    ``<prefix>.c`` (fmt "c", :func:`c_source`). ``prefix`` defaults to
    :func:`default_prefix` of the entry. Returns the paths written."""
    if fmt not in FORMATS:
        raise ParameterError(f"format={fmt!r} is not one of {list(FORMATS)}")
    prefix = _check_prefix(default_prefix(law.entry) if prefix is None else prefix)
    out_dir = os.fspath(out_dir)
    if fmt == "json":
        path = os.path.join(out_dir, f"{prefix}.json")
        write_json(path, to_json(law))
        return [path]
    header, source = c_source(law, prefix)
    paths = [os.path.join(out_dir, f"{prefix}.h"), os.path.join(out_dir, f"{prefix}.c")]
    write_text(paths[0], header)
    write_text(paths[1], source)
    return paths


def harmonic_law(context: PolicyContext, entry: str, coefficients_nm: Sequence[float],
                 model: FeedforwardModel, *, velocity_gain_a_s_per_rad: float = 0.0,
                 feedback_limit_a: float = math.inf, velocity_estimator: str = "",
                 notes: str = "") -> FirmwareLaw:
    """The law of a drive whose base controller is the patent feedforward with
    ``model`` (its Km divides the torque; in servo its Fs is fed forward with the
    command's sign, as the kernel does), applying the torque coefficients
    ``coefficients_nm`` (N*m, (s1, c1, s2, c2, s4, c4): s_h sin(h x) + c_h cos(h x)),
    plus an optional velocity feedback, at ``context``'s mode and held speed on
    its knowledge's nominal drive."""
    c = [float(v) for v in coefficients_nm]
    if len(c) != 2 * len(DETENT_HARMONICS):
        raise ParameterError(f"coefficients_nm must hold {2 * len(DETENT_HARMONICS)} numbers "
                             f"(s, c per harmonic {list(DETENT_HARMONICS)}), got {len(c)}")
    system = context.knowledge.nominal
    inv_km = 1.0 / model.Km
    return FirmwareLaw(
        entry=entry, motor=system.name, mode=context.mode, speed_rps=float(context.speed_rps),
        pwm_hz=system.drive.pwm_hz, nr=system.motor.Nr, microsteps=system.drive.microsteps,
        km_nm_per_a=model.Km, harmonics=tuple(DETENT_HARMONICS),
        # s sin(hx) + c cos(hx) = hypot(s, c) * sin(hx + atan2(c, s))
        amplitude_a=tuple(fm.hypot(c[2 * i], c[2 * i + 1]) * inv_km
                          for i in range(len(DETENT_HARMONICS))),
        phase_rad=tuple(fm.atan2(c[2 * i + 1], c[2 * i]) for i in range(len(DETENT_HARMONICS))),
        friction_a=model.Fs * inv_km if context.mode == "servo" else 0.0,
        velocity_gain_a_s_per_rad=velocity_gain_a_s_per_rad, feedback_limit_a=feedback_limit_a,
        velocity_estimator=velocity_estimator, notes=notes)


def firmware_knowledge(system: SystemParams, identified: FeedforwardModel | None = None, *,
                       rig_seed: int = 0, accel_rps2: float = DEFAULT_ACCEL_RPS2
                       ) -> MotorKnowledge:
    """What a drive exported for the motor ``system`` knows: ``system`` is its
    datasheet (nominal) model; the identified detent model is ``identified``, by
    default the system's own (a motor file written by ``stepdamp identify`` holds
    the identified model); entries that calibrate get a rig on ``system``
    (:class:`~.rig.CalibrationRig`). No true plant: oracles cannot be exported."""
    exact = FeedforwardModel.from_motor(system.motor)
    return MotorKnowledge(nominal=system, identified=exact if identified is None else identified,
                          exact=exact, plant=None,
                          rig=CalibrationRig(system, rig_seed, accel_rps2))


def default_speed_rps(system: SystemParams) -> float:
    """The default design speed (rev/s): the motor's lowest predicted resonance,
    where the 4th detent harmonic meets the rotor's natural frequency (the
    protocol's "h4" speed)."""
    return float(system.predicted_resonances_rps()[4])


def _base_controller_law(policy: ZeroAction, context: PolicyContext) -> FirmwareLaw:
    """The ``patent-ff-*`` entries: the base controller's feedforward alone."""
    if policy.base_controller == "none":
        raise ParameterError(f"entry {policy.name!r} cannot be exported: it adds no correction "
                             "(the base controller without feedforward)")
    model = estimate_model(policy.estimate, context.knowledge)
    return harmonic_law(context, policy.name, model.coefficients(), model,
                        notes=f"The patent's harmonic feedforward (US 7,733,051, eq. 8) with "
                              f"the {policy.estimate} detent model: iq = detent torque model "
                              "/ Km, sent without delay compensation.")


def policy_law(policy: Any, knowledge: MotorKnowledge, *, mode: str = "open-loop",
               speed_rps: float | None = None) -> FirmwareLaw:
    """The law ``policy`` applies on the drive of ``knowledge`` in ``mode`` at the
    held command speed ``speed_rps`` (rev/s; default :func:`default_speed_rps` of
    the nominal motor): its ``firmware_law(context)`` with the context the
    benchmark's runner gives it, or a one-line ``ParameterError`` naming it and
    saying why it cannot be exported."""
    name = str(getattr(policy, "name", policy))
    if mode not in MODES:
        raise ParameterError(f"mode={mode!r} is not one of {list(MODES)}")
    speed = default_speed_rps(knowledge.nominal) if speed_rps is None else speed_rps
    if isinstance(speed, bool) or not isinstance(speed, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(speed) and speed > 0.0):
        raise ParameterError(f"speed_rps={speed!r} is outside its allowed range (0, inf) rev/s")
    top = bridge_limit_rps(knowledge.nominal)
    if speed > top:
        # Past it the drive cannot push the current: a law there is never run.
        raise ParameterError(f"speed_rps={speed:g} is above the top speed of "
                             f"{knowledge.nominal.name!r} on its bus ({top:.4g} rev/s, the "
                             f"bridge circle Vdc/sqrt(2)); allowed: (0, {top:.4g}] rev/s")
    hook = getattr(policy, "firmware_law", None)
    if not isinstance(policy, ZeroAction) and not callable(hook):
        card = policy_card(policy)
        why = ("it is a learned agent: its action comes from a network at run time, not "
               "from a fixed table and gains" if card is not None and card.learned else
               "it is an oracle: it reads what no drive has" if card is not None and card.oracle
               else "it has no firmware_law: its law is not a fixed table and gains")
        raise ParameterError(f"entry {name!r} cannot be exported: {why}")
    try:
        options = policy_env_options(policy, knowledge)
        context = policy_context(options, knowledge, mode, float(speed))
        law = _base_controller_law(policy, context) if isinstance(policy, ZeroAction) \
            else hook(context)
    except ParameterError:
        raise
    except ValueError as exc:       # e.g. a model or rig the knowledge lacks
        first = (str(exc).strip().splitlines() or [""])[0]
        raise ParameterError(f"entry {name!r} cannot be exported: {first}") from None
    if not isinstance(law, FirmwareLaw):
        raise ParameterError(f"entry {name!r}: firmware_law returned {type(law).__name__}, "
                             "not a FirmwareLaw")
    return law


def entry_law(entry: str, knowledge: MotorKnowledge, *, mode: str = "open-loop",
              speed_rps: float | None = None) -> FirmwareLaw:
    """:func:`policy_law` of a fresh instance of the entry ``entry`` (a registered
    name or any policy spec, :func:`~.registry.resolve_policy`)."""
    return policy_law(resolve_policy(entry).make(), knowledge, mode=mode, speed_rps=speed_rps)
