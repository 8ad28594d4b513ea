"""The fused loop: one drive advanced by whole PWM periods (:func:`run_periods`,
with the damping law :func:`run_periods_law`), batches of drives and their
parallel twins, and the merge of metric rows."""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
from numba import njit, prange

from ..fixedmath import sincos
from .control import control_step, controller_params
from .layout import ACC, CONFIG, CTRL, LAW, STATE, TRACE
from .plant import harmonics, plant_params, plant_step

__all__ = ["run_periods", "run_periods_law", "law_feedback", "resonant_phasor", "law_current",
           "step_batch", "step_batch_parallel", "without_law", "run_batch", "run_batch_law",
           "run_batch_parallel", "run_batch_law_parallel", "merge_rows"]

# No Python error checks on division: the inputs are validated before they get here.
# No fastmath, not even contraction: a fused multiply-add rounds once where a CPU
# without FMA rounds twice, and the result must not depend on the CPU
# (:mod:`.fixedmath`).
_jit = njit(cache=True, error_model="numpy")
# The pieces of the hot loop are inlined at numba-IR level: LLVM's own inliner
# leaves many as calls that return tuples through memory (measured with
# benchmarks/bench_sim.py: about 10 % of the loop's time).
_jit_inline = njit(cache=True, error_model="numpy", inline="always")

# ---------------------------------------------------------------------------
# The fused loop
# ---------------------------------------------------------------------------
@_jit
def run_periods(c, s, acc, u_arr, n_periods, trace, trace_every):
    """Advance one drive by ``n_periods`` PWM periods, in place on ``s`` and ``acc``.

    ``u_arr`` (len(INPUT)) is held for the whole call. ``trace`` receives one row
    every ``trace_every`` periods (counted from this call's start) while it has
    room; pass a (0, len(TRACE)) array for none. Returns the rows written.
    """
    return _advance(c, s, acc, u_arr, None, n_periods, trace, trace_every)


@_jit
def run_periods_law(c, s, acc, u_arr, law, n_periods, trace, trace_every):
    """:func:`run_periods` with the damping law ``law`` (``L_*``) on top.

    Each period the law reads the drive's samples of the period before (one
    PWM period of computation) and adds its current to the q residual
    ``INPUT.IQ``; gains of zero add exactly nothing.
    """
    return _advance(c, s, acc, u_arr, law, n_periods, trace, trace_every)


@_jit_inline
def law_feedback(law, at, step, e_w, e_theta):
    """The law's velocity and high-passed position terms (A), updating its
    low-passed position error. The law's field j is ``law[at + j*step]``: (0, 1)
    for a row of its own, a column of a structure of arrays in
    :mod:`stepdamp_env.lanes`."""
    e_lp = law[at + LAW.E_LP * step] + law[at + LAW.HP_ALPHA * step] * (e_theta - law[at + LAW.E_LP * step])
    law[at + LAW.E_LP * step] = e_lp
    return law[at + LAW.KV * step] * e_w + law[at + LAW.KP * step] * (e_theta - e_lp)


@_jit_inline
def resonant_phasor(law, at, step, k, e_w, sin_h, cos_h, dt, limit):
    """The law's resonant coefficients (a, b) of harmonic k (1, 2, 4 for k = 0,
    1, 2) after one period, clamped to +-limit (A); not stored."""
    kr, ki = law[at + (LAW.KR1 + 2 * k) * step], law[at + (LAW.KI1 + 2 * k) * step]
    es, ec = e_w * sin_h, e_w * cos_h
    a = law[at + (LAW.A1 + 2 * k) * step] + dt * (kr * es - ki * ec)
    b = law[at + (LAW.B1 + 2 * k) * step] + dt * (ki * es + kr * ec)
    return min(max(a, -limit), limit), min(max(b, -limit), limit)


@_jit_inline
def law_current(law, at, step, e_w, e_theta, s1, c1, dt):
    """One period of the damping law (see ``L_*``) at the Park angle whose sin and
    cos are given: updates its state, returns its current (A). Fields as in
    :func:`law_feedback`."""
    i = law_feedback(law, at, step, e_w, e_theta)
    limit = law[at + LAW.LIMIT * step]
    if law[at + LAW.RESONANT * step] != 0.0:
        s2, c2, s4, c4 = harmonics(s1, c1)
        sn = (s1, s2, s4)
        cn = (c1, c2, c4)
        for k in range(3):
            a, b = resonant_phasor(law, at, step, k, e_w, sn[k], cn[k], dt, limit)
            law[at + (LAW.A1 + 2 * k) * step] = a
            law[at + (LAW.B1 + 2 * k) * step] = b
            i += a * sn[k] + b * cn[k]
    i = min(max(i, -limit), limit)
    law[at + LAW.SUM_I2 * step] += i * i
    return i


@_jit
def _advance(c, s, acc, u_arr, law, n_periods, trace, trace_every):
    """The fused loop; ``law`` None (pruned at compile time) or an ``L_*`` row."""
    if law is not None:
        # The resonant terms cost a third of the law: they run only while a gain
        # or a coefficient is non-zero (gains are held for the call).
        on = 0.0
        for j in range(LAW.KR1, LAW.KI4 + 1):
            if law[j] != 0.0:
                on = 1.0
        for j in range(LAW.A1, LAW.B4 + 1):
            if law[j] != 0.0:
                on = 1.0
        law[LAW.RESONANT] = on
    p = plant_params(c)
    q = controller_params(c)
    u = (u_arr[0], u_arr[1], u_arr[2], u_arr[3], u_arr[4], u_arr[5], u_arr[6])
    dt = q[CTRL.DT]
    n_sub = int(c[CONFIG.SUBSTEPS])
    h = dt / n_sub
    w_stick = c[CONFIG.W_STICK]
    win_start = c[CONFIG.WINDOW_START]
    ref_rate = c[CONFIG.NR] * c[CONFIG.REF_SPEED]
    x = (s[STATE.THETA], s[STATE.OMEGA], s[STATE.IA], s[STATE.IB], s[STATE.E_IN], s[STATE.E_CU], s[STATE.E_DAMP],
         s[STATE.E_FRIC], s[STATE.E_LOAD])
    cs = (s[STATE.INT_D], s[STATE.INT_Q], s[STATE.THETA_FB_PREV], s[STATE.OMEGA_FB], s[STATE.POS_INT],
          s[STATE.THETA_EST], s[STATE.IA_PREV], s[STATE.IB_PREV], s[STATE.VA_OLD], s[STATE.VB_OLD])
    va_next, vb_next = s[STATE.VA_NEXT], s[STATE.VB_NEXT]
    period = s[STATE.PERIOD]
    sin_prev, cos_prev = sincos(s[STATE.PARK_ANGLE])
    obs = (s[STATE.THETA_FB], s[STATE.THETA_CMD], s[STATE.OMEGA_CMD], s[STATE.ID_MEAS], s[STATE.IQ_MEAS], 0.0,
           s[STATE.IQ_FF], s[STATE.PARK_ANGLE], sin_prev, cos_prev)
    n_win, sum_e, sum_e2, min_e, max_e, sum_iff2 = (acc[ACC.COUNT], acc[ACC.SUM_E],
                                                     acc[ACC.SUM_E2], acc[ACC.MIN_E],
                                                     acc[ACC.MAX_E], acc[ACC.SUM_IFF2])
    h1s, h1c, h2s, h2c, h4s, h4c = (acc[ACC.H1_S], acc[ACC.H1_C], acc[ACC.H2_S], acc[ACC.H2_C],
                                    acc[ACC.H4_S], acc[ACC.H4_C])
    max_lag, max_i = acc[ACC.MAX_LAG], acc[ACC.MAX_CURRENT]
    sum_e2_all, n_all, sum_iff2_all = acc[ACC.SUM_E2_ALL], acc[ACC.COUNT_ALL], acc[ACC.SUM_IFF2_ALL]
    rows = 0
    for i in range(n_periods):
        t = period * dt
        # Computation delay: this period applies what the previous one computed.
        va, vb = va_next, vb_next
        if law is None:
            cs, v_next, obs = control_step(period, x[0], x[2], x[3], cs, q, u)
        else:
            # The law's current from the previous period's samples, then held.
            i_law = law_current(law, 0, 1, obs[2] - cs[3], obs[1] - cs[2], obs[8], obs[9], dt)
            u_law = (u[0], u[1], u[2], u[3], u[4], u[5], u[6] + i_law)
            cs, v_next, obs = control_step(period, x[0], x[2], x[3], cs, q, u_law)
        va_next, vb_next = v_next
        # What this period applies is, at the next sample, the period that just ended.
        cs = (cs[0], cs[1], cs[2], cs[3], cs[4], cs[5], cs[6], cs[7], va, vb)

        # Metrics of the sample at the period's start.
        err = obs[2] - x[1]
        lag = abs(obs[1] - x[0])
        max_lag = max(max_lag, lag)
        max_i = max(max_i, abs(x[2]), abs(x[3]))
        iq_inj = obs[6]
        sum_e2_all += err * err
        sum_iff2_all += iq_inj * iq_inj
        n_all += 1.0
        if t >= win_start:
            if n_win == 0.0:
                min_e = err
                max_e = err
            min_e = min(min_e, err)
            max_e = max(max_e, err)
            n_win += 1.0
            sum_e += err
            sum_e2 += err * err
            sum_iff2 += iq_inj * iq_inj
            # Lock-in on the detent harmonics h*Nr*w_ref*t, timed from the window
            # start; the reference angle is evaluated afresh each sample, so no
            # rounding accumulates.
            s1, c1 = sincos(ref_rate * (t - win_start))
            s2, c2, s4, c4 = harmonics(s1, c1)
            h1s += err * s1
            h1c += err * c1
            h2s += err * s2
            h2c += err * c2
            h4s += err * s4
            h4c += err * c4

        if rows < trace.shape[0] and i % trace_every == 0:
            row = trace[rows]
            (row[TRACE.T], row[TRACE.THETA], row[TRACE.OMEGA], row[TRACE.THETA_CMD],
             row[TRACE.OMEGA_CMD], row[TRACE.IA], row[TRACE.IB], row[TRACE.VA], row[TRACE.VB],
             row[TRACE.ID], row[TRACE.IQ], row[TRACE.IQ_CMD], row[TRACE.IQ_FF],
             row[TRACE.THETA_FB], row[TRACE.OMEGA_FB]) = (
                t, x[0], x[1], obs[1], obs[2], x[2], x[3], va, vb, obs[3], obs[4], obs[5], obs[6],
                obs[0], cs[3])
            rows += 1

        for _ in range(n_sub):
            x = plant_step(x, va, vb, p, h, w_stick)
        period += 1.0

    s[STATE.PERIOD] = period
    (s[STATE.THETA], s[STATE.OMEGA], s[STATE.IA], s[STATE.IB], s[STATE.E_IN], s[STATE.E_CU], s[STATE.E_DAMP],
     s[STATE.E_FRIC], s[STATE.E_LOAD]) = x
    (s[STATE.INT_D], s[STATE.INT_Q], s[STATE.THETA_FB_PREV], s[STATE.OMEGA_FB], s[STATE.POS_INT], s[STATE.THETA_EST],
     s[STATE.IA_PREV], s[STATE.IB_PREV], s[STATE.VA_OLD], s[STATE.VB_OLD]) = cs
    s[STATE.VA_NEXT], s[STATE.VB_NEXT] = va_next, vb_next
    (s[STATE.THETA_FB], s[STATE.THETA_CMD], s[STATE.OMEGA_CMD], s[STATE.ID_MEAS], s[STATE.IQ_MEAS], _iq_cmd,
     s[STATE.IQ_FF], s[STATE.PARK_ANGLE], _sin, _cos) = obs
    acc[ACC.COUNT], acc[ACC.SUM_E], acc[ACC.SUM_E2], acc[ACC.MIN_E], acc[ACC.MAX_E] = (
        n_win, sum_e, sum_e2, min_e, max_e)
    acc[ACC.SUM_IFF2] = sum_iff2
    acc[ACC.H1_S], acc[ACC.H1_C], acc[ACC.H2_S], acc[ACC.H2_C], acc[ACC.H4_S], acc[ACC.H4_C] = (
        h1s, h1c, h2s, h2c, h4s, h4c)
    acc[ACC.MAX_LAG], acc[ACC.MAX_CURRENT] = max_lag, max_i
    acc[ACC.SUM_E2_ALL], acc[ACC.COUNT_ALL], acc[ACC.SUM_IFF2_ALL] = sum_e2_all, n_all, sum_iff2_all
    return rows


@_jit
def _drive(configs, states, accs, inputs, laws, n_periods, i, no_trace):
    """Drive ``i`` of a batch by ``n_periods``, without trace (``no_trace``: a
    (0, len(TRACE)) array, made once per batch)."""
    # int64 as from Python: a literal 1 would compile the whole loop once more for its type.
    every = np.int64(1)
    if laws is None:
        _advance(configs[i], states[i], accs[i], inputs[i], None, n_periods, no_trace, every)
    else:
        _advance(configs[i], states[i], accs[i], inputs[i], laws[i], n_periods, no_trace, every)


@_jit
def step_batch(configs, states, accs, inputs, laws, n_periods):
    """Advance N drives (rows of the arrays) by ``n_periods`` each, without trace;
    ``laws`` None (no damping law; pruned when compiled) or each drive's LAW row."""
    no_trace = np.zeros((0, len(TRACE)))
    for i in range(configs.shape[0]):
        _drive(configs, states, accs, inputs, laws, n_periods, i, no_trace)


# The parallel twin: the drives of a batch on numba's threads (numba.set_num_threads
# in the calling thread). Each drive's arithmetic is the serial loop's, in its own
# row, so the results do not depend on the number of threads.
_jit_parallel = njit(cache=True, error_model="numpy", parallel=True)


@_jit_parallel
def step_batch_parallel(configs, states, accs, inputs, laws, n_periods):
    """:func:`step_batch`, the drives spread over numba's threads."""
    no_trace = np.zeros((0, len(TRACE)))
    for i in prange(configs.shape[0]):
        _drive(configs, states, accs, inputs, laws, n_periods, i, no_trace)


def without_law(step: Callable[..., Any]) -> Callable[..., Any]:
    """``step(configs, states, accs, inputs, laws, n_periods)`` as a function of
    ``(configs, states, accs, inputs, n_periods)`` with ``laws`` None."""
    def run(configs: np.ndarray, states: np.ndarray, accs: np.ndarray, inputs: np.ndarray,
            n_periods: int) -> Any:
        return step(configs, states, accs, inputs, None, n_periods)

    run.__name__ = run.__qualname__ = f"{step.__name__}_without_law"
    run.__doc__ = f":func:`{step.__name__}` without damping law."
    return run


# The entry points by their names before 0.18: the law's are the steps themselves; the
# others are Python functions (numba code calls step_batch with laws None).
run_batch = without_law(step_batch)
run_batch_parallel = without_law(step_batch_parallel)
run_batch_law = step_batch
run_batch_law_parallel = step_batch_parallel


@njit(cache=True)
def merge_rows(totals, parts):
    """``simulation.merge_accumulators`` row by row (no fast-math: the same sums,
    and ``min``/``max`` as Python's: the first unless the second is strictly
    smaller/larger)."""
    for i in range(totals.shape[0]):
        t = totals[i]
        p = parts[i]
        if p[ACC.COUNT] > 0:
            if t[ACC.COUNT] > 0:
                if p[ACC.MIN_E] < t[ACC.MIN_E]:
                    t[ACC.MIN_E] = p[ACC.MIN_E]
                if p[ACC.MAX_E] > t[ACC.MAX_E]:
                    t[ACC.MAX_E] = p[ACC.MAX_E]
            else:
                t[ACC.MIN_E] = p[ACC.MIN_E]
                t[ACC.MAX_E] = p[ACC.MAX_E]
        for j in (ACC.COUNT, ACC.SUM_E, ACC.SUM_E2, ACC.SUM_IFF2, ACC.H1_S, ACC.H1_C, ACC.H2_S, ACC.H2_C,
                  ACC.H4_S, ACC.H4_C, ACC.SUM_E2_ALL, ACC.COUNT_ALL, ACC.SUM_IFF2_ALL):
            t[j] += p[j]
        if p[ACC.MAX_LAG] > t[ACC.MAX_LAG]:
            t[ACC.MAX_LAG] = p[ACC.MAX_LAG]
        if p[ACC.MAX_CURRENT] > t[ACC.MAX_CURRENT]:
            t[ACC.MAX_CURRENT] = p[ACC.MAX_CURRENT]
