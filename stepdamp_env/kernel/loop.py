"""The fused loop: one drive advanced by whole PWM periods (:func:`run_periods`,
with the damping law :func:`run_periods_law`), batches of drives and their
parallel twins, and the merge of metric rows."""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
from numba import njit, prange

from ..fixedmath import sincos
from .control import controller_params
from .layout import ACC, CONFIG, CTRL, LAW, STATE, TRACE
from .period import (control_period, law_input, load_controller, load_law, load_metrics, load_plant,
                     store_controller, store_law, store_metrics, store_plant)
from .plant import plant_params, plant_step

__all__ = ["run_periods", "run_periods_law", "step_batch", "step_batch_parallel", "without_law",
           "run_batch", "run_batch_law", "run_batch_parallel", "run_batch_law_parallel",
           "merge_rows"]

# No Python error checks on division: the inputs are validated before they get here.
# No fastmath, not even contraction: a fused multiply-add rounds once where a CPU
# without FMA rounds twice, and the result must not depend on the CPU
# (:mod:`.fixedmath`).
_jit = njit(cache=True, error_model="numpy")

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
    return _advance(c, s, acc, u_arr, None, n_periods, trace, trace_every)[0]


@_jit
def run_periods_law(c, s, acc, u_arr, law, n_periods, trace, trace_every):
    """:func:`run_periods` with the damping law ``law`` (``L_*``) on top.

    Each period the law reads the drive's samples of the period before (one
    PWM period of computation) and adds its current to the q residual
    ``INPUT.IQ``; gains of zero add exactly nothing.
    """
    # The resonant terms cost a third of the law: they run only while a gain or a
    # coefficient is non-zero (gains are held for the call).
    on = 0.0
    for j in range(LAW.KR1, LAW.KI4 + 1):
        if law[j] != 0.0:
            on = 1.0
    for j in range(LAW.A1, LAW.B4 + 1):
        if law[j] != 0.0:
            on = 1.0
    law[LAW.RESONANT] = on
    rows, lw = _advance(c, s, acc, u_arr, load_law(law, 0, 1), n_periods, trace, trace_every)
    store_law(law, 0, 1, lw)
    return rows


@_jit
def _advance(c, s, acc, u_arr, lw, n_periods, trace, trace_every):
    """The fused loop; ``lw`` None (no law: pruned at compile time) or the law's
    :class:`.layout.LawState`. Returns (rows traced, the law's state)."""
    p = plant_params(c)
    q = controller_params(c)
    u = (u_arr[0], u_arr[1], u_arr[2], u_arr[3], u_arr[4], u_arr[5], u_arr[6])
    n_sub = int(c[CONFIG.SUBSTEPS])
    h = q[CTRL.DT] / n_sub
    w_stick = c[CONFIG.W_STICK]
    win_start = c[CONFIG.WINDOW_START]
    win_end = c[CONFIG.WINDOW_END]
    ref_rate = c[CONFIG.NR] * c[CONFIG.REF_SPEED]
    x = load_plant(s, 0, 1)
    sin_prev, cos_prev = sincos(s[STATE.PARK_ANGLE])
    period, cs, v_next, obs = load_controller(s, 0, 1, sin_prev, cos_prev)
    m = load_metrics(acc, 0, 1)
    law_state = lw              # lw itself is never assigned: its test is pruned when compiled
    rows = 0
    for i in range(n_periods):
        u_period = u
        if lw is not None:
            law_state, u_period = law_input(law_state, u, cs, obs, q[CTRL.DT], None)
        cs, v, v_next, obs, m, _ = control_period(period, x, cs, v_next, obs, m, q, u_period,
                                                  win_start, win_end, ref_rate, None)
        if rows < trace.shape[0] and i % trace_every == 0:
            row = trace[rows]
            (row[TRACE.T], row[TRACE.THETA], row[TRACE.OMEGA], row[TRACE.THETA_CMD],
             row[TRACE.OMEGA_CMD], row[TRACE.IA], row[TRACE.IB], row[TRACE.VA], row[TRACE.VB],
             row[TRACE.ID], row[TRACE.IQ], row[TRACE.IQ_CMD], row[TRACE.IQ_FF],
             row[TRACE.THETA_FB], row[TRACE.OMEGA_FB]) = (
                period * q[CTRL.DT], x[0], x[1], obs.theta_cmd, obs.omega_cmd, x[2], x[3], v[0],
                v[1], obs.id, obs.iq, obs.iq_cmd, obs.iq_ff, obs.theta_fb, cs.omega_fb)
            rows += 1
        for _ in range(n_sub):
            x = plant_step(x, v[0], v[1], p, h, w_stick)
        period += 1.0
    store_plant(s, 0, 1, x)
    store_controller(s, 0, 1, period, cs, v_next, obs)
    store_metrics(acc, 0, 1, m)
    return rows, law_state


@_jit
def _drive(configs, states, accs, inputs, laws, n_periods, i, no_trace):
    """Drive ``i`` of a batch by ``n_periods``, without trace (``no_trace``: a
    (0, len(TRACE)) array, made once per batch)."""
    # int64 as from Python: a literal 1 would compile the whole loop once more for its type.
    every = np.int64(1)
    if laws is None:
        run_periods(configs[i], states[i], accs[i], inputs[i], n_periods, no_trace, every)
    else:
        run_periods_law(configs[i], states[i], accs[i], inputs[i], laws[i], n_periods, no_trace,
                        every)


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
                  ACC.H4_S, ACC.H4_C, ACC.SUM_E2_ALL, ACC.COUNT_ALL, ACC.SUM_IFF2_ALL,
                  ACC.SUM_P, ACC.SUM_P2, ACC.SUM_P2_ALL):
            t[j] += p[j]
        if p[ACC.MAX_LAG] > t[ACC.MAX_LAG]:
            t[ACC.MAX_LAG] = p[ACC.MAX_LAG]
        if p[ACC.MAX_CURRENT] > t[ACC.MAX_CURRENT]:
            t[ACC.MAX_CURRENT] = p[ACC.MAX_CURRENT]
