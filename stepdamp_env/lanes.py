"""The kernel with SIMD across drives (structure of arrays).

:func:`run_batch_lanes` advances a batch of drives like :func:`kernel.run_batch`
and gives the same bits, but steps ``LANES`` drives at once: each field of the
drives' CONFIG, STATE, ACC, INPUT and LAW rows is one row of a workspace, so that
a loop over the drives is a loop over contiguous lanes that LLVM vectorises (8
doubles per AVX-512 instruction, 4 per AVX2). The arithmetic per drive is the
kernel's, in the kernel's order (no FMA, no reassociation), so vectorising
cannot change a bit.

Lanes run one variant of the drive, v1's default: open loop, DQ current loops,
the encoder's low-pass velocity, current sensors with or without noise, a
constant-speed profile, with or without the damping law
(:func:`run_batch_law_lanes`), one substep count per group of LANES. A drive of
another variant is run by the kernel's own :func:`kernel.run_periods` for the
whole call. A drive that leaves the branch-free path in a period (an angle
beyond 1e6 rad for :func:`fixedmath.sincos_lane`, an RK4 stage shift beyond 1/8
rad for :func:`fixedmath.sincos_rotated`, a NaN) is run again by the kernel
from its state at the period's start.

``StepperDampV1VectorEnv(simd=...)`` steps its drives here; the board does not
(docs/performance.md, "SIMD across drives", has the measurements).
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit, prange

from .fixedmath import log_lane, sincos, sincos_lane, sincos_rotated
from .kernel import (ACC, CONFIG, CTRL, DRIVE, INPUT, LAW, MODE, PLANT, PROFILE, STATE, TRACE, VEL_EST,
                     constant_speed_command, controller_params, current_loop, driving_torque_sc,
                     feedforward_torque, harmonics, law_feedback, motor_derivative_sc, park_sc,
                     plant_params, quantise, resonant_phasor, rk4_combine, rk4_step_stuck, run_periods,
                     run_periods_law, uniform_pair, without_law)

__all__ = ["LANES", "step_lanes", "step_lanes_parallel", "run_batch_lanes",
           "run_batch_law_lanes", "run_batch_lanes_parallel", "run_batch_law_lanes_parallel", "in_lanes", "control_lanes", "plant_lanes", "workspace_size",
           "simd_by_default"]

_jit = njit(cache=True, error_model="numpy")
# The kernel's parameter tuples, inlined: a call in the loop over lanes (or the
# reference count of an array view) stops LLVM from vectorising it.
# getattr: with NUMBA_DISABLE_JIT (the benchmarks' interpreted reference) these are plain.
_plant_params = njit(error_model="numpy", inline="always")(
    getattr(plant_params, "py_func", plant_params))
_controller_params = njit(error_model="numpy", inline="always")(
    getattr(controller_params, "py_func", controller_params))

#: Drives stepped together (a multiple of every vector width).
LANES = 32

Blocks = namedtuple("Blocks", "CFG ST AC IN LW ST0 AC0 LW0 SIN COS VA VB RARE ROWS")


def _blocks(sizes: tuple[int, ...]) -> Blocks:
    starts = [0]
    for size in sizes:
        starts.append(starts[-1] + size)
    return Blocks(*starts)


#: The workspace, LANES wide per row: the first row of each block. CFG, ST, AC,
#: IN, LW hold the drives' CONFIG, STATE, ACC, INPUT, LAW; ST0, AC0, LW0 the
#: state, accumulators and law at the period's start (for the kernel's reruns);
#: SIN, COS the last Park angle's sine and cosine (the law's input); VA, VB the
#: winding voltages applied during the period (V); RARE 1.0 where the kernel runs
#: the lane's period again; ROWS the workspace's rows.
ROW = _blocks((len(CONFIG), len(STATE), len(ACC), len(INPUT), len(LAW), len(STATE), len(ACC),
               len(LAW), 1, 1, 1, 1, 1))


def _column_reader(rows: int):
    """An inlined function (w, first, d): the tuple of lane d's values in the
    workspace rows first..first+rows-1 (a tuple, not a view: no reference count)."""
    values = ", ".join(f"w[(first + {j}) * {LANES} + d]" for j in range(rows))
    namespace: dict = {}
    exec(f"def column(w, first, d):\n    return ({values},)\n", namespace)
    return njit(error_model="numpy", inline="always")(namespace["column"])


_config_column = _column_reader(len(CONFIG))
_input_column = _column_reader(len(INPUT))


@njit(error_model="numpy", inline="always")
def _st(field, d):
    """Index in the workspace of lane d's STATE ``field``."""
    return (ROW.ST + field) * LANES + d


@njit(error_model="numpy", inline="always")
def _ac(field, d):
    """Index in the workspace of lane d's ACC ``field``."""
    return (ROW.AC + field) * LANES + d


def simd_by_default(num_drives: int) -> bool:
    """Whether a vector env of ``num_drives`` drives steps in lanes unless told:
    from LANES drives up, where numba compiles for AVX2 or wider. With SSE4.2's
    two doubles per vector the lanes are no faster than the kernel
    (``benchmarks/bench_simd.py``). A CPU named in ``NUMBA_CPU_NAME`` without
    ``NUMBA_CPU_FEATURES`` counts as unknown: off."""
    from numba.core import config
    from numba.core.codegen import get_host_cpu_features

    if num_drives < LANES:
        return False
    if config.CPU_FEATURES is not None:
        features = config.CPU_FEATURES
    elif config.CPU_NAME is not None:
        return False
    else:
        features = get_host_cpu_features()      # numba's: NUMBA_ENABLE_AVX=0 drops AVX
    return "+avx2" in features.split(",")


def workspace_size() -> int:
    """Length of the workspace :func:`control_lanes` and :func:`plant_lanes` step."""
    return ROW.ROWS * LANES


@_jit
def in_lanes(c, n_sub):
    """True if the drive of CONFIG row ``c`` is of the variant that runs in lanes
    with ``n_sub`` substeps."""
    return (c[CONFIG.MODE] == MODE.OPEN_LOOP and c[CONFIG.DRIVE_MODE] == DRIVE.CURRENT
            and c[CONFIG.VEL_EST] == VEL_EST.LOWPASS
            and c[CONFIG.PROFILE] == PROFILE.CONSTANT and int(c[CONFIG.SUBSTEPS]) == n_sub)


@_jit
def control_lanes(w, law):
    """The sample, control and metrics of one period for every lane (the kernel's
    ``_advance`` before its plant steps, for the lanes' variant); ``law`` None
    (pruned at compile time) or ``w`` for the damping law in the workspace."""
    n = LANES
    for d in range(n):
        c = _config_column(w, ROW.CFG, d)
        q = _controller_params(c)
        u = _input_column(w, ROW.IN, d)
        dt = q[CTRL.DT]
        iq_u = u[INPUT.IQ]
        if law is not None:
            # kernel.law_current from the previous period's samples, its resonant
            # terms computed and selected (stored unconditionally, so it vectorises).
            at = ROW.LW * n + d
            e_w = w[_st(STATE.OMEGA_CMD, d)] - w[_st(STATE.OMEGA_FB, d)]
            i_law = law_feedback(w, at, n, e_w, w[_st(STATE.THETA_CMD, d)] - w[_st(STATE.THETA_FB_PREV, d)])
            limit = w[at + LAW.LIMIT * n]
            on = w[at + LAW.RESONANT * n] != 0.0
            s1, c1 = w[ROW.SIN * n + d], w[ROW.COS * n + d]
            s2, c2, s4, c4 = harmonics(s1, c1)
            a1, b1 = resonant_phasor(w, at, n, 0, e_w, s1, c1, dt, limit)
            a2, b2 = resonant_phasor(w, at, n, 1, e_w, s2, c2, dt, limit)
            a4, b4 = resonant_phasor(w, at, n, 2, e_w, s4, c4, dt, limit)
            i_res = ((i_law + (a1 * s1 + b1 * c1)) + (a2 * s2 + b2 * c2)) + (a4 * s4 + b4 * c4)
            w[at + LAW.A1 * n] = a1 if on else w[at + LAW.A1 * n]
            w[at + LAW.B1 * n] = b1 if on else w[at + LAW.B1 * n]
            w[at + LAW.A2 * n] = a2 if on else w[at + LAW.A2 * n]
            w[at + LAW.B2 * n] = b2 if on else w[at + LAW.B2 * n]
            w[at + LAW.A4 * n] = a4 if on else w[at + LAW.A4 * n]
            w[at + LAW.B4 * n] = b4 if on else w[at + LAW.B4 * n]
            # The law's current, then held for the period.
            # The end of law_current, written out: numba's inlined call to a function
            # that adds into an array element leaves the loop unvectorised.
            i_law = min(max(i_res if on else i_law, -limit), limit)
            w[at + LAW.SUM_I2 * n] += i_law * i_law
            iq_u = iq_u + i_law
        period = w[_st(STATE.PERIOD, d)]
        t = period * dt
        theta, omega, ia, ib = w[_st(STATE.THETA, d)], w[_st(STATE.OMEGA, d)], w[_st(STATE.IA, d)], w[_st(STATE.IB, d)]
        va, vb = w[_st(STATE.VA_NEXT, d)], w[_st(STATE.VB_NEXT, d)]
        # control_step, for the variant: command, encoder, sensors (offsets only),
        # low-pass velocity, open-loop current command, current loops.
        theta_cmd, omega_cmd = constant_speed_command(t, q[CTRL.SPEED], q[CTRL.ACCEL])
        theta_fb = quantise(theta, q[CTRL.ENCODER])
        # sense_currents, both branches computed, one selected.
        u1, u2 = uniform_pair(q[CTRL.NOISE_SEED], period)
        r_noise = math.sqrt(-2.0 * log_lane(u1))
        sin_n, cos_n = sincos_lane(2.0 * math.pi * u2)
        noisy = q[CTRL.I_NOISE] != 0.0
        ia_m = (ia + q[CTRL.I_OFFSET_A] + q[CTRL.I_NOISE] * (r_noise * cos_n) if noisy
                else ia + q[CTRL.I_OFFSET_A])
        ib_m = (ib + q[CTRL.I_OFFSET_B] + q[CTRL.I_NOISE] * (r_noise * sin_n) if noisy
                else ib + q[CTRL.I_OFFSET_B])
        omega_fb = w[_st(STATE.OMEGA_FB, d)]
        omega_fb = omega_fb + q[CTRL.VEL_ALPHA] * ((theta_fb - w[_st(STATE.THETA_FB_PREV, d)]) * (1.0 / dt)
                                                    - omega_fb)
        angle = q[CTRL.NR] * quantise(theta_cmd, q[CTRL.MICROSTEP])
        sin_a, cos_a = sincos_lane(angle)
        iq_inj = feedforward_torque(sin_a, cos_a, q, u) * (1.0 / q[CTRL.KM_EST]) + iq_u
        id_m, iq_m = park_sc(ia_m, ib_m, sin_a, cos_a)
        int_d, int_q, va_next, vb_next = current_loop(w[_st(STATE.INT_D, d)], w[_st(STATE.INT_Q, d)], q[CTRL.HOLD],
                                                      iq_inj, id_m, iq_m, sin_a, cos_a, q)
        # Metrics of the sample at the period's start.
        err = omega_cmd - omega
        lag = abs(theta_cmd - theta)
        w[_ac(ACC.MAX_LAG, d)] = max(w[_ac(ACC.MAX_LAG, d)], lag)
        w[_ac(ACC.MAX_CURRENT, d)] = max(w[_ac(ACC.MAX_CURRENT, d)], abs(ia), abs(ib))
        w[_ac(ACC.SUM_E2_ALL, d)] += err * err
        w[_ac(ACC.SUM_IFF2_ALL, d)] += iq_inj * iq_inj
        w[_ac(ACC.COUNT_ALL, d)] += 1.0
        win_start = c[CONFIG.WINDOW_START]
        ref = c[CONFIG.NR] * c[CONFIG.REF_SPEED] * (t - win_start)
        in_win = t >= win_start
        n_win = w[_ac(ACC.COUNT, d)]
        min_e = err if n_win == 0.0 else w[_ac(ACC.MIN_E, d)]
        max_e = err if n_win == 0.0 else w[_ac(ACC.MAX_E, d)]
        s1, c1 = sincos_lane(ref)
        s2, c2, s4, c4 = harmonics(s1, c1)
        w[_ac(ACC.MIN_E, d)] = min(min_e, err) if in_win else w[_ac(ACC.MIN_E, d)]
        w[_ac(ACC.MAX_E, d)] = max(max_e, err) if in_win else w[_ac(ACC.MAX_E, d)]
        w[_ac(ACC.COUNT, d)] = n_win + 1.0 if in_win else n_win
        w[_ac(ACC.SUM_E, d)] = w[_ac(ACC.SUM_E, d)] + err if in_win else w[_ac(ACC.SUM_E, d)]
        w[_ac(ACC.SUM_E2, d)] = w[_ac(ACC.SUM_E2, d)] + err * err if in_win else w[_ac(ACC.SUM_E2, d)]
        w[_ac(ACC.SUM_IFF2, d)] = w[_ac(ACC.SUM_IFF2, d)] + iq_inj * iq_inj if in_win else w[_ac(ACC.SUM_IFF2, d)]
        w[_ac(ACC.H1_S, d)] = w[_ac(ACC.H1_S, d)] + err * s1 if in_win else w[_ac(ACC.H1_S, d)]
        w[_ac(ACC.H1_C, d)] = w[_ac(ACC.H1_C, d)] + err * c1 if in_win else w[_ac(ACC.H1_C, d)]
        w[_ac(ACC.H2_S, d)] = w[_ac(ACC.H2_S, d)] + err * s2 if in_win else w[_ac(ACC.H2_S, d)]
        w[_ac(ACC.H2_C, d)] = w[_ac(ACC.H2_C, d)] + err * c2 if in_win else w[_ac(ACC.H2_C, d)]
        w[_ac(ACC.H4_S, d)] = w[_ac(ACC.H4_S, d)] + err * s4 if in_win else w[_ac(ACC.H4_S, d)]
        w[_ac(ACC.H4_C, d)] = w[_ac(ACC.H4_C, d)] + err * c4 if in_win else w[_ac(ACC.H4_C, d)]
        # The new controller state and samples, as _advance stores them.
        w[_st(STATE.INT_D, d)] = int_d
        w[_st(STATE.INT_Q, d)] = int_q
        w[_st(STATE.THETA_FB_PREV, d)] = theta_fb
        w[_st(STATE.OMEGA_FB, d)] = omega_fb
        w[_st(STATE.IA_PREV, d)] = ia_m
        w[_st(STATE.IB_PREV, d)] = ib_m
        w[_st(STATE.VA_OLD, d)] = va
        w[_st(STATE.VB_OLD, d)] = vb
        w[_st(STATE.VA_NEXT, d)] = va_next
        w[_st(STATE.VB_NEXT, d)] = vb_next
        w[_st(STATE.THETA_FB, d)] = theta_fb
        w[_st(STATE.THETA_CMD, d)] = theta_cmd
        w[_st(STATE.OMEGA_CMD, d)] = omega_cmd
        w[_st(STATE.ID_MEAS, d)] = id_m
        w[_st(STATE.IQ_MEAS, d)] = iq_m
        w[_st(STATE.IQ_FF, d)] = iq_inj
        w[_st(STATE.PARK_ANGLE, d)] = angle
        w[_st(STATE.PERIOD, d)] = period + 1.0
        w[ROW.VA * n + d] = va
        w[ROW.VB * n + d] = vb
        w[ROW.SIN * n + d] = sin_a
        w[ROW.COS * n + d] = cos_a
        off_path = (abs(angle) >= 1e6) | (angle != angle) | (in_win & ((abs(ref) >= 1e6) | (ref != ref)))
        w[ROW.RARE * n + d] = 1.0 if off_path else 0.0


@_jit
def plant_lanes(w):
    """One plant step (the kernel's ``plant_step``) for every lane, in place."""
    n = LANES
    for d in range(n):
        c = _config_column(w, ROW.CFG, d)
        p = _plant_params(c)
        va, vb = w[ROW.VA * n + d], w[ROW.VB * n + d]
        h = c[CONFIG.DT] / int(c[CONFIG.SUBSTEPS])
        th, om, ia, ib = w[_st(STATE.THETA, d)], w[_st(STATE.OMEGA, d)], w[_st(STATE.IA, d)], w[_st(STATE.IB, d)]
        nr = p[PLANT.NR]
        hh = 0.5 * h
        x0 = nr * th
        s0, c0 = sincos_lane(x0)
        # plant_step's stick decision: the driving torque at rest, at x0.
        stuck = ((abs(om) < c[CONFIG.W_STICK])
                 & (abs(driving_torque_sc(s0, c0, 0.0, ia, ib, p)) <= p[PLANT.FS]))
        # rk4_step
        k1 = motor_derivative_sc(s0, c0, om, ia, ib, va, vb, p)
        shift2 = nr * hh * k1[0]
        s2, c2 = sincos_rotated(s0, c0, shift2)
        k2 = motor_derivative_sc(s2, c2, om + hh * k1[1], ia + hh * k1[2], ib + hh * k1[3], va, vb, p)
        shift3 = nr * hh * k2[0]
        s3, c3 = sincos_rotated(s0, c0, shift3)
        k3 = motor_derivative_sc(s3, c3, om + hh * k2[1], ia + hh * k2[2], ib + hh * k2[3], va, vb, p)
        shift4 = nr * h * k3[0]
        s4, c4 = sincos_rotated(s0, c0, shift4)
        k4 = motor_derivative_sc(s4, c4, om + h * k3[1], ia + h * k3[2], ib + h * k3[3], va, vb, p)
        x = (th, om, ia, ib, w[_st(STATE.E_IN, d)], w[_st(STATE.E_CU, d)], w[_st(STATE.E_DAMP, d)],
             w[_st(STATE.E_FRIC, d)], w[_st(STATE.E_LOAD, d)])
        # Both steps computed, one selected (plant_step's branch).
        moving = rk4_combine(x, k1, k2, k3, k4, h)
        held = rk4_step_stuck(x, va, vb, p, h)
        w[_st(STATE.THETA, d)] = held[0] if stuck else moving[0]
        w[_st(STATE.OMEGA, d)] = held[1] if stuck else moving[1]
        w[_st(STATE.IA, d)] = held[2] if stuck else moving[2]
        w[_st(STATE.IB, d)] = held[3] if stuck else moving[3]
        w[_st(STATE.E_IN, d)] = held[4] if stuck else moving[4]
        w[_st(STATE.E_CU, d)] = held[5] if stuck else moving[5]
        w[_st(STATE.E_DAMP, d)] = held[6] if stuck else moving[6]
        w[_st(STATE.E_FRIC, d)] = held[7] if stuck else moving[7]
        w[_st(STATE.E_LOAD, d)] = held[8] if stuck else moving[8]
        off_path = (abs(x0) >= 1e6) | (x0 != x0) | ((not stuck) & (
            (abs(shift2) > 0.125) | (abs(shift3) > 0.125) | (abs(shift4) > 0.125)))
        w[ROW.RARE * n + d] = 1.0 if off_path | (w[ROW.RARE * n + d] != 0.0) else 0.0


@_jit
def _load(w, first, rows, block, m):
    """Columns of ``rows`` (drives first..first+m-1) into workspace block ``block``;
    the lanes beyond m repeat drive ``first``, so they compute finite numbers."""
    n = LANES
    for j in range(rows.shape[1]):
        for d in range(n):
            w[(block + j) * n + d] = rows[first + (d if d < m else 0), j]


@_jit
def step_lanes(configs, states, accs, inputs, laws, n_periods):
    """:func:`kernel.step_batch`, LANES drives at a time; the same bits. ``laws`` None
    (no damping law; pruned when compiled) or each drive's LAW row.

    A drive whose substep count is not that of the first drive of its group of
    LANES, or that is not of the lanes' variant, runs through the kernel for the
    whole call. Returns the number of drive-periods the kernel ran (those, and
    the periods run again).
    """
    n = LANES
    w = np.zeros(ROW.ROWS * n)
    law = None if laws is None else w
    empty = np.zeros((0, len(TRACE)))
    every = np.int64(1)
    s_one = np.empty(len(STATE))
    a_one = np.empty(len(ACC))
    l_one = np.empty(len(LAW))
    again = 0
    for first in range(0, configs.shape[0], n):
        m = min(n, configs.shape[0] - first)
        n_sub = int(configs[first, CONFIG.SUBSTEPS])
        # Drives of another variant: the kernel, for the whole call.
        fixed = np.zeros(n, dtype=np.bool_)
        for d in range(m):
            i = first + d
            fixed[d] = not in_lanes(configs[i], n_sub)
            if fixed[d]:
                again += n_periods
                if laws is None:
                    run_periods(configs[i], states[i], accs[i], inputs[i], n_periods, empty, every)
                else:
                    run_periods_law(configs[i], states[i], accs[i], inputs[i], laws[i], n_periods,
                                    empty, every)
        if fixed[:m].all():
            continue
        _load(w, first, configs, ROW.CFG, m)
        _load(w, first, states, ROW.ST, m)
        _load(w, first, accs, ROW.AC, m)
        _load(w, first, inputs, ROW.IN, m)
        for d in range(n):
            sin_a, cos_a = sincos(w[_st(STATE.PARK_ANGLE, d)])
            w[ROW.SIN * n + d] = sin_a
            w[ROW.COS * n + d] = cos_a
        if laws is not None:
            _load(w, first, laws, ROW.LW, m)
            # Whether the resonant terms run is set once per call, as in _advance.
            for d in range(n):
                on = 0.0
                for j in range(LAW.KR1, LAW.KI4 + 1):
                    if w[(ROW.LW + j) * n + d] != 0.0:
                        on = 1.0
                for j in range(LAW.A1, LAW.B4 + 1):
                    if w[(ROW.LW + j) * n + d] != 0.0:
                        on = 1.0
                w[(ROW.LW + LAW.RESONANT) * n + d] = on
        for _ in range(n_periods):
            for j in range(ROW.ST * n, ROW.IN * n):
                w[j + (ROW.ST0 - ROW.ST) * n] = w[j]
            if laws is not None:
                for j in range(ROW.LW * n, (ROW.LW + len(LAW)) * n):
                    w[j + (ROW.LW0 - ROW.LW) * n] = w[j]
            control_lanes(w, law)
            for _ in range(n_sub):
                plant_lanes(w)
            for d in range(m):
                if not fixed[d] and w[ROW.RARE * n + d] != 0.0:
                    # The kernel runs this drive's period again from its start.
                    again += 1
                    for j in range(len(STATE)):
                        s_one[j] = w[(ROW.ST0 + j) * n + d]
                    for j in range(len(ACC)):
                        a_one[j] = w[(ROW.AC0 + j) * n + d]
                    if laws is None:
                        run_periods(configs[first + d], s_one, a_one, inputs[first + d], 1, empty, every)
                    else:
                        for j in range(len(LAW)):
                            l_one[j] = w[(ROW.LW0 + j) * n + d]
                        run_periods_law(configs[first + d], s_one, a_one, inputs[first + d], l_one, 1,
                                        empty, every)
                        for j in range(len(LAW)):
                            w[(ROW.LW + j) * n + d] = l_one[j]
                    for j in range(len(STATE)):
                        w[(ROW.ST + j) * n + d] = s_one[j]
                    for j in range(len(ACC)):
                        w[(ROW.AC + j) * n + d] = a_one[j]
                    sin_a, cos_a = sincos(s_one[STATE.PARK_ANGLE])
                    w[ROW.SIN * n + d] = sin_a
                    w[ROW.COS * n + d] = cos_a
        for d in range(m):
            if fixed[d]:
                continue
            for j in range(len(STATE)):
                states[first + d, j] = w[(ROW.ST + j) * n + d]
            for j in range(len(ACC)):
                accs[first + d, j] = w[(ROW.AC + j) * n + d]
            if laws is not None:
                for j in range(len(LAW)):
                    laws[first + d, j] = w[(ROW.LW + j) * n + d]
    return again


# The parallel twin: groups of LANES drives on numba's threads (numba.set_num_threads in
# the calling thread), each group with its own workspace; the bits do not depend
# on the number of threads.
_jit_parallel = njit(cache=True, error_model="numpy", parallel=True)


@_jit_parallel
def step_lanes_parallel(configs, states, accs, inputs, laws, n_periods):
    """:func:`step_lanes`, the groups of lanes spread over numba's threads."""
    groups = (configs.shape[0] + LANES - 1) // LANES
    again = np.zeros(groups, dtype=np.int64)
    for g in prange(groups):
        lo = g * LANES
        hi = min(lo + LANES, configs.shape[0])
        if laws is None:
            again[g] = step_lanes(configs[lo:hi], states[lo:hi], accs[lo:hi], inputs[lo:hi],
                                  None, n_periods)
        else:
            again[g] = step_lanes(configs[lo:hi], states[lo:hi], accs[lo:hi], inputs[lo:hi],
                                  laws[lo:hi], n_periods)
    return again.sum()


# The entry points by their names before 0.18: the law's are the steps themselves; the
# others are Python functions (numba code calls step_lanes with laws None).
run_batch_lanes = without_law(step_lanes)
run_batch_lanes_parallel = without_law(step_lanes_parallel)
run_batch_law_lanes = step_lanes
run_batch_law_lanes_parallel = step_lanes_parallel
