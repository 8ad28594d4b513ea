"""The online harmonic tables of :mod:`.firmware_online` as C99
(:func:`online_c_source`) and their files (:func:`export_online`)."""

from __future__ import annotations

from ..version import __version__
from .firmware_c import c_comment, c_double, check_prefix, default_prefix, write_law_files
from .firmware_online import KalmanTable, OnlineTableLaw, online_to_json

__all__ = ["online_c_source", "export_online"]


def export_online(law: OnlineTableLaw, fmt: str, out_dir: str, prefix: str | None = None
                  ) -> list[str]:
    """Write the law into ``out_dir``, each file atomically: ``<prefix>.json``
    (fmt "json") or ``<prefix>.h`` and ``<prefix>.c`` (fmt "c"). Returns the paths."""
    return write_law_files(fmt, out_dir, default_prefix(law.entry) if prefix is None else prefix,
                           lambda: online_to_json(law), lambda p: online_c_source(law, p))


def _six(values: tuple[float, ...]) -> str:
    return ", ".join(map(c_double, values))


_KALMAN_STATE = """    double x[6];            /* the ripple's coefficients (rad/s) */
    double p[6][6];         /* their covariance */
    double reference[3];    /* each harmonic's ripple power before adapting */
"""
_REPETITIVE_STATE = """    double angle;           /* the electrical angle at the step before (rad) */
    double turned;          /* the angle turned since the period began (rad) */
    double sums[6];         /* sum of z*sin(hx), z*cos(hx) over the period */
    double count;           /* the period's steps (a double: no overflow) */
    double reference[3];    /* each harmonic's least ripple size */
    int seen;               /* a period has ended */
    double learned_nm[6];   /* the learned table, before its rounding (N*m) */
"""

_KALMAN_CONSTANTS = """static const double inverse_path[6] = {{{inverse}}};
static const double drift = {drift};
static const double noise = {noise};
static const double step_gain = {gain};
"""
_REPETITIVE_CONSTANTS = """static const double start_nm[6] = {{{start}}};
static const double learn[6] = {{{learn}}};
static const double leak = {leak};
"""

_KALMAN_C = r"""
void {p}_start(struct {state} *state)
{{
    int i, j;

    start_table(state);
    for (i = 0; i < 6; ++i) {{
        state->x[i] = 0.0;
        for (j = 0; j < 6; ++j) {{
            state->p[i][j] = i == j ? {p0} : 0.0;
        }}
    }}
    for (i = 0; i < 3; ++i) {{
        state->reference[i] = 0.0;
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

    if (state->step <= {adapt_step}L) {{       /* past it only "later" matters: no overflow */
        state->step += 1;
    }}
    if (state->step <= {start_step}L) {{
        return;
    }}
    for (i = 0; i < 6; ++i) {{
        h[i] = (double)sincos[i];
    }}
    kalman(h, (double)velocity_error * speed_ref, state);
    for (k = 0; k < 3; ++k) {{
        power = state->x[2 * k] * state->x[2 * k] + state->x[2 * k + 1] * state->x[2 * k + 1];
        if (state->step <= {adapt_step}L) {{
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
    if (state->step > {adapt_step}L) {{
        set_action(wanted, state);
    }}
}}
"""

# fdlibm's atan and atan2 as stepdamp_env.fixedmath computes them, and Python's
# float modulo (the sign of the divisor).
_ANGLE_C = r"""
static const double atan_hi[4] = {{4.63647609000806093515e-01, 7.85398163397448278999e-01,
    9.82793723247329054082e-01, 1.57079632679489655800e+00}};
static const double atan_lo[4] = {{2.26987774529616870924e-17, 3.06161699786838301793e-17,
    1.39033110312309984516e-17, 6.12323399573676603587e-17}};
static const double pi_hi = 3.1415926535897931160e+00;
static const double pi_lo = 1.2246467991473531772e-16;

static double fixed_atan(double x)
{{
    double ax, t, z, w, s1, s2, r;
    int i = -1;

    if (x != x) {{
        return x;
    }}
    ax = fabs(x);
    if (ax >= 7.378697629483821e+19) {{
        z = atan_hi[3] + atan_lo[3];
        return x > 0.0 ? z : -z;
    }}
    t = ax;
    if (ax < 0.4375) {{
        if (ax < 7.450580596923828e-09) {{
            return x;
        }}
    }} else if (ax < 1.1875) {{
        if (ax < 0.6875) {{
            i = 0;
            t = (2.0 * ax - 1.0) / (2.0 + ax);
        }} else {{
            i = 1;
            t = (ax - 1.0) / (ax + 1.0);
        }}
    }} else if (ax < 2.4375) {{
        i = 2;
        t = (ax - 1.5) / (1.0 + 1.5 * ax);
    }} else {{
        i = 3;
        t = -1.0 / ax;
    }}
    z = t * t;
    w = z * z;
    s1 = z * (3.33333333333329318027e-01 + w * (1.42857142725034663711e-01
        + w * (9.09088713343650656196e-02 + w * (6.66107313738753120669e-02
        + w * (4.97687799461593236017e-02 + w * 1.62858201153657823623e-02)))));
    s2 = w * (-1.99999999998764832476e-01 + w * (-1.11111104054623557880e-01
        + w * (-7.69187620504482999495e-02 + w * (-5.83357013379057348645e-02
        + w * -3.65315727442169155270e-02))));
    if (i < 0) {{
        r = t - t * (s1 + s2);
    }} else {{
        r = atan_hi[i] - ((t * (s1 + s2) - atan_lo[i]) - t);
    }}
    return x >= 0.0 ? r : -r;
}}

/* atan2 of finite arguments (sines and cosines). */
static double fixed_atan2(double y, double x)
{{
    double q, z;

    if (x != x || y != y) {{
        return x + y;
    }}
    if (y == 0.0) {{
        return copysign(1.0, x) > 0.0 ? y : copysign(pi_hi, y);
    }}
    if (x == 0.0) {{
        return copysign(0.5 * pi_hi, y);
    }}
    q = fabs(y / x);
    if (q > 1.152921504606847e+18) {{
        z = 0.5 * pi_hi + 0.5 * pi_lo;
    }} else if (x < 0.0 && q < 8.673617379884035e-19) {{
        z = 0.0;
    }} else {{
        z = fixed_atan(q);
    }}
    if (x > 0.0) {{
        return y > 0.0 ? z : -z;
    }}
    if (y > 0.0) {{
        return pi_hi - (z - pi_lo);
    }}
    return (z - pi_lo) - pi_hi;
}}

static double python_mod(double x, double y)
{{
    double m = fmod(x, y);

    if (m != 0.0) {{
        if ((y < 0.0) != (m < 0.0)) {{
            m += y;
        }}
    }} else {{
        m = copysign(0.0, y);
    }}
    return m;
}}
"""

_REPETITIVE_C = r"""
void {p}_start(struct {state} *state)
{{
    int i;

    start_table(state);
    state->angle = 0.0;
    state->turned = 0.0;
    state->count = 0.0;
    state->seen = 0;
    for (i = 0; i < 6; ++i) {{
        state->sums[i] = 0.0;
        state->learned_nm[i] = start_nm[i];
    }}
    for (i = 0; i < 3; ++i) {{
        state->reference[i] = 0.0;
    }}
}}

void {p}_update(float velocity_error, const float sincos[6], struct {state} *state)
{{
    const double two_pi = 2.0 * pi_hi;
    double z, angle, re, im, size, reference, wanted[6], inv_count;
    int i, k, diverged;

    if (state->step <= {wait_step}L + 1) {{   /* past it only "later" matters: no overflow */
        state->step += 1;
    }}
    if (state->step <= {wait_step}L) {{
        return;
    }}
    z = (double)velocity_error * speed_ref;
    angle = fixed_atan2((double)sincos[0], (double)sincos[1]);
    if (state->step != {wait_step}L + 1) {{
        state->turned += python_mod(angle - state->angle + pi_hi, two_pi) - pi_hi;
    }}
    state->angle = angle;
    for (i = 0; i < 6; ++i) {{
        state->sums[i] += z * (double)sincos[i];
    }}
    state->count += 1.0;
    if (!(fabs(state->turned) >= two_pi)) {{
        return;
    }}
    inv_count = 1.0 / state->count;
    for (k = 0; k < 3; ++k) {{
        re = 2.0 * state->sums[2 * k] * inv_count;
        im = 2.0 * state->sums[2 * k + 1] * inv_count;
        size = sqrt(re * re + im * im);
        reference = state->seen ? (state->reference[k] < size ? state->reference[k] : size)
            : size;
        diverged = state->active[k] && size > guard_ratio * reference;
        if (diverged) {{
            state->active[k] = 0;
            state->learned_nm[2 * k] = start_nm[2 * k];
            state->learned_nm[2 * k + 1] = start_nm[2 * k + 1];
        }}
        wanted[2 * k] = start_nm[2 * k] + leak * (state->learned_nm[2 * k] - start_nm[2 * k]);
        wanted[2 * k + 1] = start_nm[2 * k + 1]
            + leak * (state->learned_nm[2 * k + 1] - start_nm[2 * k + 1]);
        if (state->active[k]) {{
            wanted[2 * k] += learn[2 * k] * re - learn[2 * k + 1] * im;
            wanted[2 * k + 1] += learn[2 * k] * im + learn[2 * k + 1] * re;
        }}
        state->reference[k] = reference;
    }}
    set_action(wanted, state);
    for (i = 0; i < 6; ++i) {{
        state->learned_nm[i] = state->table_nm[i];
        state->sums[i] = 0.0;
    }}
    state->seen = 1;
    state->turned -= copysign(two_pi, state->turned);
    state->count = 0.0;
}}
"""


def online_c_source(law: OnlineTableLaw, prefix: str | None = None) -> tuple[str, str]:
    """(header text, source text) of the law in C99: a state struct, ``<prefix>_start``,
    ``<prefix>_update`` (every agent step) and ``<prefix>_iq_correction_a``
    (every PWM period). Compiles clean with ``-std=c99 -Wall -Wextra -Werror
    -pedantic``; link with ``-lm``; compile with ``-ffp-contract=off`` (no a*b + c
    fused into one rounding) for the simulated bits."""
    p = check_prefix(default_prefix(law.entry) if prefix is None else prefix)
    macro = p.upper()
    state = f"{p}_state"
    kalman = isinstance(law, KalmanTable)
    how = ("a Kalman filter of the speed ripple's harmonics 1, 2, 4 and an integrator "
           "that moves the table against it, with a guard that puts back a harmonic whose "
           "ripple grows" if kalman else
           "the speed error's harmonics 1, 2, 4 summed over each electrical period, and "
           "at the period's end the table moved by them (repetitive control), with a "
           "guard that puts back a harmonic whose ripple grows")
    if kalman:
        steps = (f"{macro}_START_STEPS {law.start_step}", f"{macro}_ADAPT_STEPS {law.adapt_step}")
        counts = (f"The filter starts after {law.start_step} updates and the table moves "
                  f"after {law.adapt_step} ({macro}_START_STEPS, {macro}_ADAPT_STEPS)")
        cost = "about 500 multiply-adds per update (the 6x6 covariance)"
    else:
        steps = (f"{macro}_WAIT_STEPS {law.wait_step}",)
        counts = f"Learning starts after {law.wait_step} updates ({macro}_WAIT_STEPS)"
        cost = ("about 30 multiply-adds and one atan2 per update, 30 more at a period's end")
    ramp = abs(law.speed_rps) / law.accel_rps2
    header = f"""/*
 * {p}.h: the online (adapting) harmonic table of "{law.entry}" for motor "{law.motor}",
 * exported by stepdamp {__version__} (stepdamp export). Generated: re-export, do not edit.
 *
{c_comment(f"Operating point: {law.mode}, held command speed {law.speed_rps!r} rev/s. Call "
           f"{p}_start once at the start of the run, {p}_update every 1/"
           f"{macro}_DECISION_HZ s (the first call at the start) with the speed error "
           "and the electrical angle's sines and cosines as the benchmark's observation "
           "gives them (float), and "
           f"{p}_iq_correction_a every PWM period: it adds the table (and in servo the "
           f"friction feedforward) to the q-current command. The update: {how}; {cost}. "
           "The table is kept as the benchmark's float action, so the update is the "
           "simulated one bit for bit when compiled with -ffp-contract=off (gcc contracts "
           "a*b + c into one rounding by default in its GNU modes on FMA hardware).")}
{c_comment(f"{counts}: counted from the start of the run, which begins at rest with a ramp "
           f"at {law.accel_rps2!r} rev/s^2 to the held speed ({ramp:.4g} s); with another "
           "ramp, call start when the ramp would have begun, or scale the counts.")}
{c_comment(getattr(law, "notes", ""))}
{c_comment("Update and correction share the table: where the update runs outside the PWM "
           "interrupt, copy the table (double-buffer it) or mask the interrupt while it "
           "changes. The inputs must be finite: a NaN stays in the state.")}
 *
 * velocity_error  (w_cmd - w_est) / {law.speed_ref_rad_s!r} rad/s as the benchmark's
 *                 observation holds it: clipped to +-10, 0 if not finite, rounded to
 *                 float; w_est {law.velocity_estimator}.
 * sincos          sin x, cos x (rounded to float), then sin 2x = 2 sin x cos x,
 *                 cos 2x = cos^2 x - sin^2 x and 4x from 2x alike, in double from the
 *                 unrounded sin x, cos x, each rounded to float: x the electrical angle
 *                 of electrical_angle_rad at the update.
 * electrical_angle_rad  the drive's Park angle: in open loop Nr times the command angle
 *                 on its microstep, in servo Nr times (the encoder angle + half a count).
 * table_nm        the table applied: s1, c1, s2, c2, s4, c4 (N*m), the torque
 *                 s_h sin(h x) + c_h cos(h x).
 */
#ifndef {macro}_H
#define {macro}_H

#define {macro}_DECISION_HZ {c_double(law.decision_hz)}
{chr(10).join("#define " + s for s in steps)}

struct {state} {{
    long step;              /* agent steps so far, counted up to the last that matters */
{_KALMAN_STATE if kalman else _REPETITIVE_STATE}    int active[3];          /* 0 once a harmonic's guard tripped */
    float action[6];        /* the table as the benchmark's action */
    double table_nm[6];     /* the table applied (N*m) */
}};

void {p}_start(struct {state} *state);
void {p}_update(float velocity_error, const float sincos[6], struct {state} *state);
double {p}_iq_correction_a(double electrical_angle_rad, double command_speed_rad_s,
        const struct {state} *state);

#endif
"""
    constants = (_KALMAN_CONSTANTS.format(inverse=_six(law.inverse_path),
                                          drift=c_double(law.drift_variance),
                                          noise=c_double(law.noise_variance),
                                          gain=c_double(law.step_gain))
                 if kalman else
                 _REPETITIVE_CONSTANTS.format(start=_six(law.start_nm), learn=_six(law.learn),
                                              leak=c_double(law.leak)))
    update = (_KALMAN_C.format(p=p, state=state, p0=c_double(law.initial_variance),
                               start_step=law.start_step, adapt_step=law.adapt_step)
              if kalman else
              _ANGLE_C.format() + _REPETITIVE_C.format(p=p, state=state,
                                                       wait_step=law.wait_step))
    initial = ", ".join(c_double(v) + "f" for v in law.initial_action)
    source = f"""/* {p}.c: see {p}.h. Generated by stepdamp {__version__}: re-export, do not edit. */
#include <math.h>
#include "{p}.h"

#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF
#endif

static const double base_nm[6] = {{{_six(law.base_nm)}}};
static const float initial_action[6] = {{{initial}}};
static const double scale_nm = {c_double(law.action_scale_nm)};
static const double speed_ref = {c_double(law.speed_ref_rad_s)};
static const double guard_ratio = {c_double(law.guard_ratio)};
static const double inv_km = {c_double(1.0 / law.km_nm_per_a)};
static const double friction_a = {c_double(law.friction_a)};
{constants}
/* The float action of a table and the table it applies (the benchmark's way:
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

static void start_table(struct {state} *state)
{{
    int i;

    state->step = 0;
    for (i = 0; i < 6; ++i) {{
        state->action[i] = initial_action[i];
        state->table_nm[i] = base_nm[i] + scale_nm * (double)initial_action[i];
    }}
    for (i = 0; i < 3; ++i) {{
        state->active[i] = 1;
    }}
}}
{update}
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
