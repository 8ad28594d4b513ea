"""One law for a speed range: an entry's harmonic table scheduled over the command speed.

A delay-compensated table leads the detent by the current path's phase at one
held speed (:mod:`.firmware`), so a law exported at one speed is off elsewhere.
A :class:`FirmwareSchedule` holds the entry's law at the speeds of a uniform
grid ``speeds_rps`` and interpolates its table linearly in speed between them::

    v   = clamp(|w_cmd| / (2*pi), v_0, v_last)   (v_0 where not a number)   rev/s
    u   = (v - v_0) * (1/dv),  k = min(floor(u), n - 2),  t = u - k
    s_h = S[k][h] + t * (S[k+1][h] - S[k][h]),  c_h likewise    A
    iq  = sum_h s_h * sin(h*x) + c_h * cos(h*x)  + the law's friction and feedback

The table is kept as sin/cos coefficients (A): A_h sin(hx + phi_h) =
A_h cos(phi_h) sin(hx) + A_h sin(phi_h) cos(hx). The friction and feedback
terms do not depend on the speed and must be the same at every grid speed.
Outside the grid the law holds the end's table. The tables are computed for the
positive direction, as the benchmark runs (a delay-compensated table's lead
changes sign with the direction): for reverse motion export them again with
the drive's direction convention in mind. :func:`interpolation_error`
measures what the grid loses between its speeds; :func:`schedule_c_source`
writes C99 whose function computes :func:`schedule_correction` to rounding.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from .. import fixedmath as fm
from ..params import ParameterError
from ..version import __version__
from .firmware_c import check_prefix, default_prefix, filtered_feedback_c, write_law_files
from .firmware_law import FirmwareLaw, correction, from_json, to_json

__all__ = ["FirmwareSchedule", "SCHEDULE_FORMAT_ID", "build_schedule", "schedule_correction",
           "interpolation_error", "schedule_to_json", "schedule_from_json",
           "schedule_c_source", "multiply_adds_per_period", "export_schedule"]

#: The JSON file's ``format`` tag of a schedule: /2 when its laws have a filtered
#: feedback (a top-level ``filtered_feedback``, the laws' own), /1 otherwise.
SCHEDULE_FORMAT_ID = "stepdamp-firmware-schedule/2"
_SCHEDULE_V1 = "stepdamp-firmware-schedule/1"
# rad/s -> rev/s, as the C multiplies.
_PER_TURN = 1.0 / (2.0 * math.pi)
# The fields every grid speed's law must share (the terms that do not depend on speed).
_SHARED = ("entry", "motor", "mode", "pwm_hz", "nr", "microsteps", "km_nm_per_a", "harmonics",
           "friction_a", "velocity_gain_a_s_per_rad", "feedback_limit_a",
           "position_gain_a_per_rad", "position_highpass_alpha", "filtered_feedback")


@dataclass(frozen=True)
class FirmwareSchedule:
    """An entry's law at each speed of a uniform grid (see the module docstring).

    Attributes:
        laws: the law at each grid speed, in increasing speed; at least two.
    """

    laws: tuple[FirmwareLaw, ...]

    def __post_init__(self) -> None:
        laws = tuple(self.laws)
        if len(laws) < 2:
            raise ParameterError(f"a schedule needs at least 2 speeds, got {len(laws)}")
        first = laws[0]
        for law in laws[1:]:
            for name in _SHARED:
                if getattr(law, name) != getattr(first, name):
                    raise ParameterError(f"entry {first.entry!r} cannot be scheduled over "
                                         f"speed: its {name} changes with the speed")
        speeds = np.array([law.speed_rps for law in laws])
        step = (speeds[-1] - speeds[0]) / (len(speeds) - 1)
        if not (step > 0.0 and np.allclose(np.diff(speeds), step, rtol=1e-9, atol=0.0)):
            raise ParameterError("the schedule's speeds must be a uniform increasing grid")
        object.__setattr__(self, "laws", laws)

    @property
    def speeds_rps(self) -> np.ndarray:
        return np.array([law.speed_rps for law in self.laws])

    @property
    def step_rps(self) -> float:
        """The grid's spacing (rev/s)."""
        v = self.speeds_rps
        return float((v[-1] - v[0]) / (len(v) - 1))

    def coefficients_a(self) -> np.ndarray:
        """(speeds, harmonics, 2): each grid speed's table as (sin, cos) coefficients (A)."""
        out = np.empty((len(self.laws), len(self.laws[0].harmonics), 2))
        for i, law in enumerate(self.laws):
            for j, (a, p) in enumerate(zip(law.amplitude_a, law.phase_rad)):
                out[i, j] = a * fm.cos(p), a * fm.sin(p)
        return out


def build_schedule(law_at: Callable[[float], FirmwareLaw], low_rps: float, high_rps: float,
                   points: int) -> FirmwareSchedule:
    """The schedule of ``law_at(speed)`` at ``points`` uniform speeds from ``low_rps``
    to ``high_rps`` (rev/s, both included)."""
    if isinstance(points, bool) or not isinstance(points, (int, np.integer)) \
            or not 2 <= points <= 4096:
        raise ParameterError(f"points={points!r} is outside its allowed range [2, 4096]")
    if not (math.isfinite(low_rps) and math.isfinite(high_rps) and 0.0 < low_rps < high_rps):
        raise ParameterError(f"the speed range {low_rps!r}..{high_rps!r} rev/s must satisfy "
                             "0 < low < high")
    step = (high_rps - low_rps) / (points - 1)
    return FirmwareSchedule(tuple(law_at(low_rps + k * step) for k in range(points)))


def _interpolated(schedule: FirmwareSchedule, speed_rps: np.ndarray) -> np.ndarray:
    """(..., harmonics, 2): the table at each |speed| (rev/s), as the C computes it."""
    coef = schedule.coefficients_a()
    v0, n = schedule.laws[0].speed_rps, len(schedule.laws)
    v = np.abs(np.asarray(speed_rps, dtype=np.float64))
    v = np.where(~(v >= v0), v0, np.minimum(v, schedule.laws[-1].speed_rps))   # nan: v0
    u = (v - v0) * (1.0 / schedule.step_rps)
    k = np.minimum(np.floor(u), n - 2).astype(np.int64)
    t = (u - k)[..., None, None]
    return coef[k] + t * (coef[k + 1] - coef[k])


def schedule_correction(schedule: FirmwareSchedule, electrical_angle_rad: Any,
                        velocity_error_rad_s: Any = 0.0, command_speed_rad_s: Any = 0.0,
                        position_error_rad: Any = 0.0, position_lowpass_rad: Any = 0.0) -> Any:
    """The q current (A) of the scheduled law, arguments as :func:`.firmware.correction`;
    the table at the command speed ``command_speed_rad_s`` (shaft rad/s)."""
    x = np.asarray(electrical_angle_rad, dtype=np.float64)
    w = np.asarray(command_speed_rad_s, dtype=np.float64)
    shape = np.broadcast_shapes(x.shape, np.shape(velocity_error_rad_s), w.shape,
                                np.shape(position_error_rad), np.shape(position_lowpass_rad))
    x, w = np.broadcast_to(x, shape), np.broadcast_to(w, shape)
    table = _interpolated(schedule, np.abs(w) * _PER_TURN)
    iq = np.zeros(shape)
    for j, h in enumerate(schedule.laws[0].harmonics):
        arg = np.ascontiguousarray(float(h) * x).reshape(-1)
        s, c = fm.sincos_array(arg)
        iq = iq + table[..., j, 0] * s.reshape(shape) + table[..., j, 1] * c.reshape(shape)
    # The speed-free terms: the law's own, with its table set to nothing.
    rest = dataclasses.replace(schedule.laws[0],
                               amplitude_a=(0.0,) * len(schedule.laws[0].harmonics))
    out = iq + correction(rest, 0.0, velocity_error_rad_s, command_speed_rad_s,
                          position_error_rad, position_lowpass_rad)
    return float(out) if np.ndim(out) == 0 else out


def interpolation_error(schedule: FirmwareSchedule, law_at: Callable[[float], FirmwareLaw]
                        ) -> tuple[float, float]:
    """The largest difference between the interpolated table and the entry's own
    table at the midpoints of the grid, as (A, share of the largest table
    amplitude): the harmonic sum's worst case, sum_h |difference of the phasors|."""
    v = schedule.speeds_rps
    mids = 0.5 * (v[:-1] + v[1:])
    got = _interpolated(schedule, mids)
    worst = 0.0
    for i, speed in enumerate(mids):
        law = law_at(float(speed))
        exact = np.array([[a * fm.cos(p), a * fm.sin(p)]
                          for a, p in zip(law.amplitude_a, law.phase_rad)])
        diff = got[i] - exact
        worst = max(worst, sum(fm.hypot(float(d[0]), float(d[1])) for d in diff))
    top = max(sum(law.amplitude_a) for law in schedule.laws)
    return worst, (worst / top if top > 0.0 else 0.0)


def multiply_adds_per_period(schedule: FirmwareSchedule) -> dict[str, int]:
    """What the C function costs per PWM period: multiplications and additions
    (or subtractions), and sine/cosine evaluations, counted from its source."""
    n_h = len(schedule.laws[0].harmonics)
    law = schedule.laws[0]
    # As schedule_c_source writes it: |w|*(1/2pi), (v - v0)*(1/dv), t = u - k; per
    # harmonic two interpolations (1 mul, 2 add each), h*x twice, s*sin and c*cos
    # (2 mul, 2 add); the friction term (1 add), Kv*e_w (1 mul), the sum (1 add);
    # the position term (2 mul, 4 add).
    mul = 2 + n_h * (2 + 2 + 2) + 1
    add = 2 + n_h * (4 + 2) + 2
    if law.stateful:
        mul, add = mul + 2, add + 4
    out = {"multiplications": mul, "additions": add, "sin_cos": 2 * n_h,
           "table_doubles": 2 * n_h * len(schedule.laws)}
    f = law.filtered_feedback
    if f is not None:
        # feedback_update_a, once per update: the filters, the gains, the bound's scaling.
        encoder = f.kind == "encoder"
        out.update(update_periods=f.periods_per_update,
                   update_multiplications=7 if encoder else 5,
                   update_additions=8 if encoder else 4)
    return out


def schedule_to_json(schedule: FirmwareSchedule) -> dict[str, Any]:
    """The schedule as a JSON object: the grid, the table per speed as sin/cos
    coefficients (A), the cost, and each grid speed's law (:func:`.firmware.to_json`)."""
    coef = schedule.coefficients_a()
    laws = [to_json(law) for law in schedule.laws]
    filtered = {"filtered_feedback": laws[0]["filtered_feedback"]} \
        if "filtered_feedback" in laws[0] else {}
    return {"format": SCHEDULE_FORMAT_ID if filtered else _SCHEDULE_V1,
            "generator": f"stepdamp {__version__}",
            "entry": schedule.laws[0].entry, "motor": schedule.laws[0].motor,
            "speeds_rps": schedule.speeds_rps.tolist(), "step_rps": schedule.step_rps,
            "harmonics": list(schedule.laws[0].harmonics),
            "sin_coefficients_a": coef[:, :, 0].tolist(),
            "cos_coefficients_a": coef[:, :, 1].tolist(),
            "cost_per_pwm_period": multiply_adds_per_period(schedule),
            "convention": "; ".join(" ".join(line.split()) for line in
                                    __doc__.split("::")[1].strip().split("\n\n")[0].splitlines()),
            **filtered, "laws": laws}


def schedule_from_json(data: Mapping[str, Any]) -> FirmwareSchedule:
    """The schedule of a :func:`schedule_to_json` object (from its laws)."""
    if not isinstance(data, Mapping) \
            or data.get("format") not in (SCHEDULE_FORMAT_ID, _SCHEDULE_V1) \
            or not isinstance(data.get("laws"), list):
        raise ParameterError(f"firmware schedule JSON must be an object with format "
                             f"{SCHEDULE_FORMAT_ID!r} or {_SCHEDULE_V1!r} and its laws")
    return FirmwareSchedule(tuple(from_json(law) for law in data["laws"]))


def _rows(values: Sequence[float]) -> str:
    return ",\n".join("    " + ", ".join(repr(float(v)) for v in values[i:i + 4])
                      for i in range(0, len(values), 4))


def schedule_c_source(schedule: FirmwareSchedule, prefix: str | None = None
                      ) -> tuple[str, str]:
    """(header, source) of C99 computing :func:`schedule_correction`: one function,
    ``<prefix>_iq_correction_a``, with :func:`.firmware.c_source`'s arguments."""
    law = schedule.laws[0]
    prefix = check_prefix(default_prefix(law.entry) if prefix is None else prefix)
    macro, fn = prefix.upper(), f"{prefix}_iq_correction_a"
    n, n_h = len(schedule.laws), len(law.harmonics)
    coef = schedule.coefficients_a()
    cost = multiply_adds_per_period(schedule)
    kp = law.stateful
    v_lo, v_hi, dv = (float(schedule.speeds_rps[0]), float(schedule.speeds_rps[-1]),
                      schedule.step_rps)
    args = ("double electrical_angle_rad, double velocity_error_rad_s,\n        "
            "double command_speed_rad_s" + (",\n        double position_error_rad, "
                                            "double *position_lowpass_rad" if kp else ""))
    limited = math.isfinite(law.feedback_limit_a)
    filtered_header, filtered_source = filtered_feedback_c(law, prefix)
    header = f"""/*
 * {prefix}.h: the damping law "{law.entry}" for motor "{law.motor}" over the command speed
 * {v_lo!r}..{v_hi!r} rev/s ({n} speeds, step {dv!r} rev/s),
 * exported by stepdamp {__version__} (stepdamp export --speeds). Generated: re-export, do not edit.
 *
 * {law.mode}, evaluated every PWM period at {law.pwm_hz!r} Hz. The harmonic table (h = {", ".join(map(str, law.harmonics))})
 * is interpolated linearly in |command speed| between the grid's tables and held at
 * its ends; the friction and feedback terms are those of the single-speed law.
 * Cost per PWM period: {cost["multiplications"]} multiplications, {cost["additions"]} additions,
 * {cost["sin_cos"]} sin/cos; table {cost["table_doubles"]} doubles ({8 * cost["table_doubles"]} bytes).
 */
#ifndef {macro}_H
#define {macro}_H

#define {macro}_NR {law.nr}
#define {macro}_SPEEDS {n}

/* The q-axis current correction (A); arguments as in stepdamp's single-speed export
 * (docs/firmware.md){": the last one is the high-pass's state, the caller's, 0.0 at the start" if kp else ""}. */
double {fn}({args});
{filtered_header}
#endif /* {macro}_H */
"""
    clamp = (f"""    if (feedback_a > {law.feedback_limit_a!r}) {{
        feedback_a = {law.feedback_limit_a!r};
    }} else if (feedback_a < {-law.feedback_limit_a!r}) {{
        feedback_a = {-law.feedback_limit_a!r};
    }}
""" if limited else "")
    position = (f"""    *position_lowpass_rad += {law.position_highpass_alpha!r} * (position_error_rad - *position_lowpass_rad);
    feedback_a += {law.position_gain_a_per_rad!r} * (position_error_rad - *position_lowpass_rad);
""" if kp else "")
    source = f"""/* {prefix}.c: see {prefix}.h (generated by stepdamp {__version__}). */
#include "{prefix}.h"

#include <math.h>

static const double harmonic[{n_h}] = {{{", ".join(repr(float(h)) for h in law.harmonics)}}};
/* [speed][harmonic]: sin and cos coefficients of the table (A). */
static const double sin_a[{n * n_h}] = {{
{_rows(coef[:, :, 0].reshape(-1))}
}};
static const double cos_a[{n * n_h}] = {{
{_rows(coef[:, :, 1].reshape(-1))}
}};

double {fn}({args})
{{
    double v = fabs(command_speed_rad_s) * {_PER_TURN!r};
    double u, t, s, c, iq_a = 0.0, feedback_a;
    int k, j;

    if (!(v >= {v_lo!r})) {{      /* below the grid, or not a number */
        v = {v_lo!r};
    }} else if (v > {v_hi!r}) {{
        v = {v_hi!r};
    }}
    u = (v - {v_lo!r}) * {1.0 / dv!r};
    k = (int)floor(u);
    if (k > {n - 2}) {{
        k = {n - 2};
    }}
    t = u - k;
    for (j = 0; j < {n_h}; ++j) {{
        s = sin_a[k * {n_h} + j] + t * (sin_a[(k + 1) * {n_h} + j] - sin_a[k * {n_h} + j]);
        c = cos_a[k * {n_h} + j] + t * (cos_a[(k + 1) * {n_h} + j] - cos_a[k * {n_h} + j]);
        iq_a += s * sin(harmonic[j] * electrical_angle_rad);
        iq_a += c * cos(harmonic[j] * electrical_angle_rad);
    }}
    if (command_speed_rad_s > 0.0) {{
        iq_a += {law.friction_a!r};
    }} else if (command_speed_rad_s < 0.0) {{
        iq_a -= {law.friction_a!r};
    }}
    feedback_a = {law.velocity_gain_a_s_per_rad!r} * velocity_error_rad_s;
{position}{clamp}    return iq_a + feedback_a;
}}
{filtered_source}"""
    return header, source


def export_schedule(schedule: FirmwareSchedule, fmt: str, out_dir: str | os.PathLike[str],
                    prefix: str | None = None) -> list[str]:
    """Write the schedule into ``out_dir``, each file atomically: ``<prefix>.json``
    (fmt "json") or ``<prefix>.h`` and ``<prefix>.c`` (fmt "c"); the paths written."""
    entry = schedule.laws[0].entry
    return write_law_files(fmt, out_dir, default_prefix(entry) if prefix is None else prefix,
                           lambda: schedule_to_json(schedule),
                           lambda p: schedule_c_source(schedule, p))
