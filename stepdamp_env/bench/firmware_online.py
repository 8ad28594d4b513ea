"""A harmonic table that adapts while it runs, for a drive's firmware:
:class:`KalmanTable` (``adaptive-ff``), its JSON and its C99.

The drive applies a harmonic table every PWM period, as a fixed law's
(:mod:`.firmware`), but the table changes: every agent step (``decision_hz``)
an update reads the speed error and the electrical angle's sines and cosines
the benchmark's policy reads (its float32 observation entries
``velocity_error``, ``sin_x`` ... ``cos_4x``) and moves the table. The C
keeps the update's state in a struct, the caller's, one per drive; the
benchmark's action is float32, so the exported update is the simulated one bit
for bit (``tests/test_firmware_online.py``).

The table is a phasor per detent harmonic h = 1, 2, 4: ``P_h = s_h + j*c_h``
(N*m), the torque ``s_h*sin(h*x) + c_h*cos(h*x)``; the q current the drive adds
is ``sum_h (s_h*sin(h*x) + c_h*cos(h*x)) / Km`` plus, in servo, the friction
feedforward ``friction_a*sign(w_cmd)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..params import DETENT_HARMONICS, ParameterError
from ..version import __version__
from .firmware_c import c_comment, c_double, check_prefix, default_prefix, write_law_files

__all__ = ["KalmanTable", "ONLINE_FORMAT_ID", "online_to_json", "online_from_json",
           "online_c_source", "export_online"]

#: The JSON file's ``format`` tag.
ONLINE_FORMAT_ID = "stepdamp-firmware-online-table/1"

_FLOAT_FIELDS = ("speed_rps", "decision_hz", "km_nm_per_a", "friction_a", "action_scale_nm",
                 "speed_ref_rad_s", "drift_variance", "noise_variance", "initial_variance",
                 "step_gain", "guard_ratio")
_SIX = ("base_nm", "initial_action", "inverse_path")


@dataclass(frozen=True)
class KalmanTable:
    """``adaptive-ff``'s law: a harmonic table moved by a Kalman filter's
    estimate of the speed ripple (see :class:`stepdamp_baselines.AdaptiveFF`).

    Every agent step k = 1, 2, ... (the first at the start of the run) with the
    speed error ``z = velocity_error * speed_ref_rad_s`` (rad/s) and ``H`` =
    (sin x, cos x, sin 2x, cos 2x, sin 4x, cos 4x):

    * from k > ``start_step``: one random-walk Kalman step of the ripple's six
      coefficients ``X`` (``P += drift_variance*I``; measurement ``H.X`` with
      variance ``noise_variance``; Joseph form), from ``X = 0``,
      ``P = initial_variance*I``;
    * up to k = ``adapt_step``: each harmonic's ripple power |R_h|^2 is kept
      as its reference;
    * after: a harmonic whose power passes ``guard_ratio`` times its reference
      plus 4 times its variance goes back to its first table and stops
      adapting; the others move by ``step_gain * w_h * R_h * inverse_path_h``
      (complex), ``w_h = clip(1 - 4*var_h/|R_h|^2, 0, 1)``;
    * the table is then written as the benchmark's action (relative to
      ``base_nm``, over ``action_scale_nm``, rounded to float32 and clipped to
      [-1, 1]) and read back: the table applied.

    Attributes:
        entry, motor, mode, speed_rps: the entry and operating point.
        decision_hz: updates per second (the agent rate, Hz).
        km_nm_per_a: the torque constant the table is divided by (N*m/A).
        friction_a: the servo's friction feedforward (A; 0 in open loop).
        base_nm: the patent feedforward's table (s1, c1, s2, c2, s4, c4), N*m.
        action_scale_nm: the action's scale (N*m per 1.0).
        initial_action: the first table's action (float32; ``ff-delay-comp``'s).
        inverse_path: 1/(G*H) per harmonic as (re, im) pairs (rad/s -> N*m).
        speed_ref_rad_s: the observation's velocity unit (rad/s).
        start_step, adapt_step: the agent steps where the filter starts and
            where adapting starts (after the probe).
        drift_variance, noise_variance, initial_variance: the filter's Q, R
            and P0 (rad^2/s^2).
        step_gain, guard_ratio: as above.
    """

    entry: str
    motor: str
    mode: str
    speed_rps: float
    decision_hz: float
    km_nm_per_a: float
    friction_a: float
    base_nm: tuple[float, ...]
    action_scale_nm: float
    initial_action: tuple[float, ...]
    inverse_path: tuple[float, ...]
    speed_ref_rad_s: float
    start_step: int
    adapt_step: int
    drift_variance: float
    noise_variance: float
    initial_variance: float
    step_gain: float
    guard_ratio: float
    notes: str = ""

    def __post_init__(self) -> None:
        for name in _FLOAT_FIELDS:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer,
                                                                 np.floating)) \
                    or not math.isfinite(float(value)):
                raise ParameterError(f"{name}={value!r} must be a finite number")
            object.__setattr__(self, name, float(value))
        for name in _SIX:
            try:
                values = tuple(float(v) for v in getattr(self, name))
            except (TypeError, ValueError):
                values = ()
            if len(values) != 6 or not all(math.isfinite(v) for v in values):
                raise ParameterError(f"{name} must hold 6 finite numbers")
            object.__setattr__(self, name, values)
        if any(float(np.float32(v)) != v or abs(v) > 1.0 for v in self.initial_action):
            raise ParameterError("initial_action must hold float32 values in [-1, 1]")
        for name in ("start_step", "adapt_step"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise ParameterError(f"{name}={value!r} must be an integer >= 0")
            object.__setattr__(self, name, int(value))
        if self.adapt_step < self.start_step:
            raise ParameterError("adapt_step must not be below start_step")
        for name in ("decision_hz", "km_nm_per_a", "action_scale_nm", "noise_variance"):
            if not getattr(self, name) > 0.0:
                raise ParameterError(f"{name}={getattr(self, name)!r} must be > 0")


def online_to_json(law: KalmanTable) -> dict[str, Any]:
    """The law as a JSON object (``format`` :data:`ONLINE_FORMAT_ID`)."""
    out: dict[str, Any] = {"format": ONLINE_FORMAT_ID, "kind": "kalman",
                           "exported_by": f"stepdamp {__version__}",
                           "harmonics": list(DETENT_HARMONICS)}
    for name in KalmanTable.__dataclass_fields__:
        value = getattr(law, name)
        out[name] = list(value) if isinstance(value, tuple) else value
    return out


def online_from_json(data: Mapping[str, Any]) -> KalmanTable:
    """The law of :func:`online_to_json`'s object (a one-line error otherwise)."""
    if not isinstance(data, Mapping) or data.get("format") != ONLINE_FORMAT_ID:
        raise ParameterError(f"not a {ONLINE_FORMAT_ID} object")
    missing = [f for f in KalmanTable.__dataclass_fields__ if f not in data]
    if missing:
        raise ParameterError(f"online table JSON lacks {missing}")
    return KalmanTable(**{f: data[f] for f in KalmanTable.__dataclass_fields__})


def export_online(law: KalmanTable, fmt: str, out_dir: str, prefix: str | None = None
                  ) -> list[str]:
    """Write the law into ``out_dir``, each file atomically: ``<prefix>.json``
    (fmt "json") or ``<prefix>.h`` and ``<prefix>.c`` (fmt "c"). Returns the paths."""
    return write_law_files(fmt, out_dir, default_prefix(law.entry) if prefix is None else prefix,
                           lambda: online_to_json(law), lambda p: online_c_source(law, p))


def _six(values: tuple[float, ...]) -> str:
    return ", ".join(map(c_double, values))


def online_c_source(law: KalmanTable, prefix: str | None = None) -> tuple[str, str]:
    """(header text, source text) of the law in C99: a state struct, ``<prefix>_start``,
    ``<prefix>_update`` (every agent step) and ``<prefix>_iq_correction_a``
    (every PWM period). Compiles clean with ``-std=c99 -Wall -Wextra -Werror
    -pedantic``; link with ``-lm``; compile without contracting a*b + c into a
    fused multiply-add (gcc's default with -std=c99)."""
    p = check_prefix(default_prefix(law.entry) if prefix is None else prefix)
    macro = p.upper()
    state = f"{p}_state"
    header = f"""/*
 * {p}.h: the adapting harmonic table of "{law.entry}" for motor "{law.motor}",
 * exported by stepdamp {__version__} (stepdamp export). Generated: re-export, do not edit.
 *
{c_comment(f"Operating point: {law.mode}, held command speed {law.speed_rps!r} rev/s. Call "
           f"{p}_start once at the start of the run, {p}_update every 1/"
           f"{macro}_DECISION_HZ s (the first call at the start) with the speed error "
           "and the electrical angle's sines and cosines as the benchmark's observation "
           "gives them (float), and "
           f"{p}_iq_correction_a every PWM period: it adds the table (and in servo the "
           "friction feedforward) to the q-current command. The update is a Kalman filter "
           "of the speed ripple's harmonics 1, 2, 4 and an integrator that moves the table "
           "against it, with a guard that puts back a harmonic whose ripple grows; the "
           "table is kept as the benchmark's float action, so the update is the simulated "
           "one bit for bit. Compile without contracting a*b + c into a fused multiply-add "
           "(gcc's default with -std=c99).")}
{c_comment(law.notes)}
 *
 * velocity_error  (w_cmd - w_est) / {law.speed_ref_rad_s!r} rad/s (the observation's).
 * sincos          sin x, cos x, sin 2x, cos 2x, sin 4x, cos 4x of the electrical angle x.
 * table_nm        the table applied: s1, c1, s2, c2, s4, c4 (N*m), the torque
 *                 s_h sin(h x) + c_h cos(h x).
 */
#ifndef {macro}_H
#define {macro}_H

#define {macro}_DECISION_HZ {c_double(law.decision_hz)}

struct {state} {{
    long step;              /* agent steps so far */
    double x[6];            /* the ripple's coefficients (rad/s) */
    double p[6][6];         /* their covariance */
    double reference[3];    /* each harmonic's ripple power before adapting */
    int active[3];          /* 0 once a harmonic's guard tripped */
    float action[6];        /* the table as the benchmark's action */
    double table_nm[6];     /* the table applied (N*m) */
}};

void {p}_start(struct {state} *state);
void {p}_update(float velocity_error, const float sincos[6], struct {state} *state);
double {p}_iq_correction_a(double electrical_angle_rad, double command_speed_rad_s,
        const struct {state} *state);

#endif
"""
    source = f"""/* {p}.c: see {p}.h. Generated by stepdamp {__version__}: re-export, do not edit. */
#include <math.h>
#include "{p}.h"

#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF
#endif

static const double base_nm[6] = {{{_six(law.base_nm)}}};
static const float initial_action[6] = {{{", ".join(c_double(v) + "f" for v in law.initial_action)}}};
static const double inverse_path[6] = {{{_six(law.inverse_path)}}};
static const double scale_nm = {c_double(law.action_scale_nm)};
static const double speed_ref = {c_double(law.speed_ref_rad_s)};
static const double drift = {c_double(law.drift_variance)};
static const double noise = {c_double(law.noise_variance)};
static const double step_gain = {c_double(law.step_gain)};
static const double guard_ratio = {c_double(law.guard_ratio)};
static const double inv_km = {c_double(1.0 / law.km_nm_per_a)};
static const double friction_a = {c_double(law.friction_a)};

/* The table of an action, and the float action of a table (the benchmark's way:
   (table - base) * (1/scale), rounded to float, clipped to [-1, 1]). */
static void set_action(const double wanted[6], struct {state} *state)
{{
    const double inv_scale = 1.0 / scale_nm;
    float a;
    int i;

    for (i = 0; i < 6; ++i) {{
        a = (float)((wanted[i] - base_nm[i]) * inv_scale);
        if (a < -1.0f) {{
            a = -1.0f;
        }} else if (a > 1.0f) {{
            a = 1.0f;
        }}
        state->action[i] = a;
        state->table_nm[i] = base_nm[i] + scale_nm * (double)a;
    }}
}}

void {p}_start(struct {state} *state)
{{
    int i, j;

    state->step = 0;
    for (i = 0; i < 6; ++i) {{
        state->x[i] = 0.0;
        for (j = 0; j < 6; ++j) {{
            state->p[i][j] = i == j ? {c_double(law.initial_variance)} : 0.0;
        }}
        state->action[i] = initial_action[i];
        state->table_nm[i] = base_nm[i] + scale_nm * (double)initial_action[i];
    }}
    for (i = 0; i < 3; ++i) {{
        state->reference[i] = 0.0;
        state->active[i] = 1;
    }}
}}

/* One random-walk Kalman step (stepdamp_env.fixedmath.random_walk_kalman_update). */
static void kalman(const double h[6], double z, struct {state} *s)
{{
    double ph[6], gain[6], m[6][6], mp[6][6], y, acc, sum;
    int a, b, c;

    for (a = 0; a < 6; ++a) {{
        s->p[a][a] += drift;
    }}
    y = z;
    for (a = 0; a < 6; ++a) {{
        y -= h[a] * s->x[a];
    }}
    sum = noise;
    for (a = 0; a < 6; ++a) {{
        acc = 0.0;
        for (b = 0; b < 6; ++b) {{
            acc += s->p[a][b] * h[b];
        }}
        ph[a] = acc;
    }}
    for (a = 0; a < 6; ++a) {{
        sum += h[a] * ph[a];
    }}
    for (a = 0; a < 6; ++a) {{
        gain[a] = ph[a] / sum;
        s->x[a] += gain[a] * y;
    }}
    for (a = 0; a < 6; ++a) {{
        for (b = 0; b < 6; ++b) {{
            m[a][b] = (a == b ? 1.0 : 0.0) - gain[a] * h[b];
        }}
    }}
    for (a = 0; a < 6; ++a) {{
        for (b = 0; b < 6; ++b) {{
            acc = 0.0;
            for (c = 0; c < 6; ++c) {{
                acc += m[a][c] * s->p[c][b];
            }}
            mp[a][b] = acc;
        }}
    }}
    for (a = 0; a < 6; ++a) {{
        for (b = 0; b < 6; ++b) {{
            acc = 0.0;
            for (c = 0; c < 6; ++c) {{
                acc += mp[a][c] * m[b][c];
            }}
            s->p[a][b] = acc + gain[a] * noise * gain[b];
        }}
    }}
}}

void {p}_update(float velocity_error, const float sincos[6], struct {state} *state)
{{
    double h[6], wanted[6], power, variance, weight, re, im;
    int i, k;

    state->step += 1;
    if (state->step <= {law.start_step}L) {{
        return;
    }}
    for (i = 0; i < 6; ++i) {{
        h[i] = (double)sincos[i];
    }}
    kalman(h, (double)velocity_error * speed_ref, state);
    for (k = 0; k < 3; ++k) {{
        power = state->x[2 * k] * state->x[2 * k] + state->x[2 * k + 1] * state->x[2 * k + 1];
        if (state->step <= {law.adapt_step}L) {{
            state->reference[k] = power;
            continue;
        }}
        variance = state->p[2 * k][2 * k] + state->p[2 * k + 1][2 * k + 1];
        wanted[2 * k] = state->table_nm[2 * k];
        wanted[2 * k + 1] = state->table_nm[2 * k + 1];
        if (state->active[k] && power > guard_ratio * state->reference[k] + 4.0 * variance) {{
            state->active[k] = 0;
            wanted[2 * k] = base_nm[2 * k] + scale_nm * (double)initial_action[2 * k];
            wanted[2 * k + 1] = base_nm[2 * k + 1] + scale_nm * (double)initial_action[2 * k + 1];
        }}
        weight = 1.0 - 4.0 * variance / (power > 1e-300 ? power : 1e-300);
        weight = weight < 0.0 ? 0.0 : (weight > 1.0 ? 1.0 : weight);
        weight = state->active[k] ? weight : 0.0;
        re = state->x[2 * k] * inverse_path[2 * k] - state->x[2 * k + 1] * inverse_path[2 * k + 1];
        im = state->x[2 * k] * inverse_path[2 * k + 1] + state->x[2 * k + 1] * inverse_path[2 * k];
        wanted[2 * k] += step_gain * weight * re;
        wanted[2 * k + 1] += step_gain * weight * im;
    }}
    if (state->step > {law.adapt_step}L) {{
        set_action(wanted, state);
    }}
}}

double {p}_iq_correction_a(double electrical_angle_rad, double command_speed_rad_s,
        const struct {state} *state)
{{
    static const double harmonic[3] = {{1.0, 2.0, 4.0}};
    double torque = 0.0, friction = 0.0;
    int k;

    for (k = 0; k < 3; ++k) {{
        torque += state->table_nm[2 * k] * sin(harmonic[k] * electrical_angle_rad)
            + state->table_nm[2 * k + 1] * cos(harmonic[k] * electrical_angle_rad);
    }}
    if (command_speed_rad_s > 0.0) {{
        friction = friction_a;
    }} else if (command_speed_rad_s < 0.0) {{
        friction = -friction_a;
    }}
    return torque * inv_km + friction;
}}
"""
    return header, source
