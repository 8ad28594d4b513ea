"""The firmware law as C99 (:func:`c_source`; see :mod:`stepdamp_env.bench.firmware`)."""

from __future__ import annotations

import math
import os
import re
from typing import Any, Callable

from ..io import write_json, write_text
from ..params import ParameterError
from ..version import __version__
from .firmware_law import FirmwareLaw, microstep_table

__all__ = ["c_source", "filtered_feedback_c", "default_prefix", "check_prefix", "c_double",
           "c_comment", "write_law_files", "FORMATS"]

#: What a law is written as: "json" (``<prefix>.json``) or "c" (``<prefix>.h``, ``<prefix>.c``).
FORMATS = ("c", "json")

# A C identifier that is safe as a file name too (no leading underscore: reserved in C).
_PREFIX = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,39}")
_C_KEYWORDS = frozenset(
    "auto break case char const continue default do double else enum extern float for goto "
    "if inline int long register restrict return short signed sizeof static struct switch "
    "typedef union unsigned void volatile while".split())


def default_prefix(entry: str) -> str:
    """A C prefix from an entry name: "tuned-constant-gain" -> "tuned_constant_gain"."""
    text = re.sub(r"[^A-Za-z0-9]+", "_", os.path.basename(entry)).strip("_")[:40].rstrip("_")
    if not text or not text[0].isalpha():
        text = ("law_" + text)[:40].rstrip("_")
    return text


def check_prefix(prefix: str) -> str:
    if not isinstance(prefix, str) or not _PREFIX.fullmatch(prefix) or prefix in _C_KEYWORDS:
        raise ParameterError(f"prefix={prefix!r} must be a C identifier of 1-40 letters, digits "
                             "and underscores starting with a letter (it names the files and "
                             "the function)")
    return prefix


def c_double(value: float) -> str:
    """A double literal that parses back to ``value`` exactly (repr is round-trip)."""
    text = repr(float(value))
    if not math.isfinite(value):
        raise ParameterError(f"cannot write the non-finite value {text} as a C literal")
    return text


def c_comment(text: str) -> str:
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


def filtered_feedback_c(law: FirmwareLaw, prefix: str) -> tuple[str, str]:
    """(header part, source part) of the law's filtered feedback
    (:class:`.firmware_law.FilteredFeedback`): a state struct, the update
    period and ``<prefix>_feedback_update_a``; ("", "") for a law without it."""
    f = law.filtered_feedback
    if f is None:
        return "", ""
    macro = prefix.upper()
    state, fn = f"{prefix}_feedback_state", f"{prefix}_feedback_update_a"
    encoder = f.kind == "encoder"
    what = ("gain_a*lp(e_w) + gain_b*lp(hp(e_theta)): lp a low-pass, hp a high-pass of the "
            "position error" if encoder else
            "gain_a*lp(e_w) + gain_b*(lp(e_w) - its value at the update before): lp a "
            "low-pass (the position error is not used)")
    coefficients = (f"gain_a = {f.gain_a!r}, gain_b = {f.gain_b!r}; the low-pass's "
                    f"coefficient {f.lowpass_beta!r} per update"
                    + (f", the high-pass's {f.highpass_alpha!r}" if encoder else ""))
    header = f"""
/*
{c_comment(f"The filtered feedback ({f.kind}): call {fn} every {macro}_UPDATE_PERIODS PWM "
          "periods, the first time at the start of the run, and add what it returns (A) to "
          f"the q-current command until the next call (besides {prefix}_iq_correction_a). "
          f"i = {what}; {coefficients}. The current is bounded by +-{f.current_scale_a!r} A "
          "and rounded to float, as the benchmark's action is.")}
 *
 * velocity_error_rad_s  e_w = w_cmd - w_est (shaft rad/s), with the drive's speed estimate.
 * position_error_rad    e_theta = theta_cmd - theta_encoder (shaft rad){"" if encoder else
                                                                         "; unused"}.
 * state                 the filters, the caller's, one per drive: zero it before the
 *                       first call (started = 0).
 */
#define {macro}_UPDATE_PERIODS {f.periods_per_update}
struct {state} {{
    double lowpass_rad;     /* the high-pass's low-pass of e_theta (rad) */
    double speed_rad_s;     /* lp(e_w) (rad/s) */
    double position_rad;    /* lp(hp(e_theta)) (rad) */
    int started;
}};
double {fn}(double velocity_error_rad_s, double position_error_rad,
        struct {state} *state);
"""
    if encoder:
        law_lines = f"""    state->lowpass_rad += {c_double(f.highpass_alpha)}
        * (position_error_rad - state->lowpass_rad);
    state->speed_rad_s += {c_double(f.lowpass_beta)} * (velocity_error_rad_s - state->speed_rad_s);
    state->position_rad += {c_double(f.lowpass_beta)}
        * (position_error_rad - state->lowpass_rad - state->position_rad);
    current_a = {c_double(f.gain_a)} * state->speed_rad_s
        + {c_double(f.gain_b)} * state->position_rad;
"""
    else:
        law_lines = f"""    previous = state->speed_rad_s;
    state->speed_rad_s += {c_double(f.lowpass_beta)} * (velocity_error_rad_s - state->speed_rad_s);
    current_a = {c_double(f.gain_a)} * state->speed_rad_s
        + {c_double(f.gain_b)} * (state->speed_rad_s - previous);
"""
    declare = "    double current_a, action;\n" + (
        "" if encoder else "    double previous;\n\n    (void)position_error_rad;\n")
    start = "        state->lowpass_rad = position_error_rad;\n" if encoder else ""
    source = f"""
double {fn}(double velocity_error_rad_s, double position_error_rad,
        struct {state} *state)
{{
{declare}
    if (!state->started) {{
{start}        state->speed_rad_s = velocity_error_rad_s;
        state->position_rad = 0.0;
        state->started = 1;
    }}
{law_lines}    action = current_a * {c_double(1.0 / f.current_scale_a)};
    if (action > 1.0) {{
        action = 1.0;
    }} else if (action < -1.0) {{
        action = -1.0;
    }}
    return (double)(float)action * {c_double(f.current_scale_a)};
}}
"""
    return header, source


def c_source(law: FirmwareLaw, prefix: str | None = None) -> tuple[str, str]:
    """(header text, source text) of a self-contained C99 implementation of the law.

    The header declares one function, ``double <prefix>_iq_correction_a(double
    electrical_angle_rad, double velocity_error_rad_s, double command_speed_rad_s)``,
    which returns :func:`correction` (A) computed in double with ``sin`` from
    ``<math.h>`` (no state, no allocation, no globals to initialise; a law with
    the position term takes two more arguments, the position error and a
    pointer to its high-pass's state, the caller's), and the
    constant microstep table ``<prefix>_microstep_table_a`` (A, :func:`microstep_table`).
    The source includes ``"<prefix>.h"``. Compiles clean with ``-std=c99 -Wall
    -Wextra -Werror -pedantic``; link with ``-lm``.
    """
    prefix = check_prefix(default_prefix(law.entry) if prefix is None else prefix)
    macro = prefix.upper()
    fn = f"{prefix}_iq_correction_a"
    filtered_header, filtered_source = filtered_feedback_c(law, prefix)
    kp = law.stateful
    position_args = (",\n        double position_error_rad, double *position_lowpass_rad"
                     if kp else "")
    position_doc = (
        " * position_error_rad    e_theta = theta_cmd - theta_encoder (shaft rad).\n"
        " * position_lowpass_rad  the high-pass's state, one double per drive, 0.0 at the\n"
        " *                       start, updated in place: *s += alpha*(e_theta - *s),\n"
        " *                       hp = e_theta - *s. Call once per PWM period, in order.\n"
        if kp else "")
    purity = ("Its one state is the caller's (position_lowpass_rad)" if kp
              else "Pure: no state")
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
{c_comment(law.notes)}
 *
 * Harmonic table (q-current amplitude A_h and electrical phase phi_h; torque = A_h*Km,
 * Km = {law.km_nm_per_a!r} N*m/A):
{harmonic_rows}
 *
{c_comment(f"Friction feedforward F = {law.friction_a!r} A; velocity gain Kv = "
          f"{law.velocity_gain_a_s_per_rad!r} A*s/rad; "
          + (f"position gain Kp = {law.position_gain_a_per_rad!r} A/rad on the position error "
             f"high-passed with alpha = {law.position_highpass_alpha!r} per period; " if kp
             else "")
          + f"feedback limit I_max = {limit_text}. "
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
 *      + clamp(Kv * velocity_error_rad_s{" + Kp * hp" if kp else ""}, -I_max, I_max) (feedback)
 *
 * electrical_angle_rad  x (rad): the electrical angle of the drive's Park transform,
 *                       NR * shaft angle; open loop: NR * the microstep-quantised command
 *                       angle; servo: NR * (encoder angle + half a count). Any value;
 *                       wrapped to one period it loses the least to rounding.
 * velocity_error_rad_s  e_w = w_cmd - w_est (shaft rad/s): the command speed minus the
 *                       drive's speed estimate; positive while the rotor lags.
 * command_speed_rad_s   w_cmd (shaft rad/s); only its sign is used.
{position_doc} * Returns               the correction (A) to add to the q-current command; positive q
 *                       current gives positive torque (positive direction of rotation).
 *
 * {purity}; no allocation, no globals to set up;
 * double precision, sin() from <math.h> only (link with -lm).
 */
double {fn}(double electrical_angle_rad, double velocity_error_rad_s,
        double command_speed_rad_s{position_args});

/*
{c_comment(f"{table}[k]: the harmonic part of the correction (A) at x = "
          f"2*pi*k/{macro}_TABLE_SIZE, i.e. {fn} at x with zero errors and command speed, "
          "for table-driven drivers: k = "
          f"the microstep count modulo {macro}_TABLE_SIZE (the non-negative remainder), counted "
          "from the shaft angle where "
          f"x = 0. Add the feedback and the friction term as {fn} does.")}
 */
extern const double {table}[{macro}_TABLE_SIZE];
{filtered_header}
#endif /* {macro}_H */
"""
    values = microstep_table(law)
    rows = ",\n".join("    " + ", ".join(c_double(v) for v in values[i:i + 4])
                      for i in range(0, len(values), 4))
    if limited:
        clamp = f"""    if (feedback_a > {c_double(law.feedback_limit_a)}) {{
        feedback_a = {c_double(law.feedback_limit_a)};
    }} else if (feedback_a < {c_double(-law.feedback_limit_a)}) {{
        feedback_a = {c_double(-law.feedback_limit_a)};
    }}
"""
    else:
        clamp = "    /* no limit on the feedback current */\n"
    alpha, gain = c_double(law.position_highpass_alpha), c_double(law.position_gain_a_per_rad)
    position = (
        "    /* The high-passed position error (the kernel's first-order high-pass). */\n"
        f"    *position_lowpass_rad += {alpha} * (position_error_rad - *position_lowpass_rad);\n"
        f"    feedback_a += {gain} * (position_error_rad - *position_lowpass_rad);\n"
        if kp else "")
    source = f"""/* {prefix}.c: see {prefix}.h (generated by stepdamp {__version__}). */
#include "{prefix}.h"

#include <math.h>

const double {table}[{macro}_TABLE_SIZE] = {{
{rows}
}};

double {fn}(double electrical_angle_rad, double velocity_error_rad_s,
        double command_speed_rad_s{position_args})
{{
    static const double harmonic[{n}] = {{{", ".join(c_double(h) for h in law.harmonics)}}};
    static const double amplitude_a[{n}] = {{{", ".join(c_double(a) for a in law.amplitude_a)}}};
    static const double phase_rad[{n}] = {{{", ".join(c_double(p) for p in law.phase_rad)}}};
    double iq_a = 0.0;
    double feedback_a;
    int k;

    for (k = 0; k < {n}; ++k) {{
        iq_a += amplitude_a[k] * sin(harmonic[k] * electrical_angle_rad + phase_rad[k]);
    }}
    /* The servo's friction feedforward, with the command's sign (0 at rest). */
    if (command_speed_rad_s > 0.0) {{
        iq_a += {c_double(law.friction_a)};
    }} else if (command_speed_rad_s < 0.0) {{
        iq_a -= {c_double(law.friction_a)};
    }}
    feedback_a = {c_double(law.velocity_gain_a_s_per_rad)} * velocity_error_rad_s;
{position}{clamp}    return iq_a + feedback_a;
}}
{filtered_source}"""
    return header, source


def write_law_files(fmt: str, out_dir: str | os.PathLike[str], prefix: str,
                    json_of: Callable[[], dict[str, Any]],
                    c_of: Callable[[str], tuple[str, str]]) -> list[str]:
    """Write ``<prefix>.json`` (fmt "json": ``json_of()``) or ``<prefix>.h`` and
    ``<prefix>.c`` (fmt "c": ``c_of(prefix)``) into ``out_dir``, each atomically;
    the paths written."""
    if fmt not in FORMATS:
        raise ParameterError(f"format={fmt!r} is not one of {list(FORMATS)}")
    prefix = check_prefix(prefix)
    out_dir = os.fspath(out_dir)
    if fmt == "json":
        path = os.path.join(out_dir, f"{prefix}.json")
        write_json(path, json_of())
        return [path]
    header, source = c_of(prefix)
    paths = [os.path.join(out_dir, f"{prefix}.h"), os.path.join(out_dir, f"{prefix}.c")]
    write_text(paths[0], header)
    write_text(paths[1], source)
    return paths
