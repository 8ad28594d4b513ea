"""The kernel with SIMD across drives (structure of arrays).

:func:`run_batch_lanes` advances a batch of drives like :func:`kernel.run_batch`
and gives the same bits, but steps ``LANES`` drives at once: each field of the
drives' CONFIG, STATE, ACC, INPUT and LAW rows is one row of a workspace, so that
a loop over the drives is a loop over contiguous lanes that LLVM vectorises (8
doubles per AVX-512 instruction, 4 per AVX2). The code per drive is the
kernel's own (:func:`kernel.control_period`, :func:`kernel.plant_step_in`,
compiled for lanes: no branches), in the kernel's order (no FMA, no
reassociation), so vectorising cannot change a bit.

Lanes run every variant of the drive: open loop or servo, current or voltage
mode, any velocity estimator, any profile, with or without the damping law
(:func:`run_batch_law_lanes`). Each variant's branches are computed and the
drive's selected, so one group of LANES may mix variants, but a group computes
only the variants its lanes use (:func:`group_variants`): the move profiles
only in a group where a lane moves, the sensor noise only in one where a lane
has noise (:func:`given_lanes`, before the period's control), and a group of
current-mode drives without the back-EMF estimate runs a control compiled
without the voltage mode (:func:`control_lanes`). A group shares one substep
count, and a drive of another count is run by the kernel's own
:func:`kernel.run_periods` for the whole call. A drive that leaves the
branch-free path in a period (an angle beyond 1e6 rad for
:func:`fixedmath.sincos_lane`, an RK4 stage shift beyond 1/8 rad for
:func:`fixedmath.sincos_rotated`, a NaN) is run again by the kernel from its
state at the period's start. In a period that starts with a rotor of its group
turning fast (an RK4 stage shift near 1/8 rad, :data:`WIDE_SHIFT`), the group's
plant computes each stage's full sine as well and selects as the kernel does,
so a fast rotor stays in lanes.

``StepperDampV1VectorEnv(simd=...)`` steps its drives here, and the board's
batches of 32 runs or more (``StepperDampBatch.simd``; docs/performance.md,
"SIMD across drives", has the measurements).
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit, prange

from .fixedmath import bits_float, float_bits, sincos
from .kernel import (ACC, CONFIG, CTRL, DRIVE, INPUT, LAW, PROFILE, STATE, TRACE, VEL_EST,
                     command_in,
                     constant_speed_command, control_period, controller_params,
                     gaussian_pair_keyed, law_input, load_controller, load_law, load_metrics,
                     load_plant, noise_key, plant_params, plant_step_in, run_periods,
                     run_periods_law, store_controller, store_law, store_metrics, store_plant,
                     without_law)

__all__ = ["LANES", "step_lanes", "step_lanes_parallel", "run_batch_lanes",
           "run_batch_law_lanes", "run_batch_lanes_parallel", "run_batch_law_lanes_parallel",
           "in_lanes", "group_variants", "given_lanes", "control_lanes", "plant_lanes",
           "workspace_size", "simd_by_default"]

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
#: A group's plant computes wide RK4 stage shifts (each stage's full sine as well
#: as the rotation) in periods that start with a rotor turning Nr * h * omega past
#: this (rad; the rotation alone holds to 1/8 rad).
WIDE_SHIFT = 0.1

Blocks = namedtuple("Blocks", "CFG ST AC IN LW ST0 AC0 LW0 SIN COS VA VB RARE KEY GIVEN ROWS")


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
#: the lane's period again; KEY the bits of the noise seed's hash key
#: (``kernel.noise_key``); GIVEN the period's command position (rad) and speed
#: (rad/s) and noise pair (``control_step``'s ``given``); ROWS the workspace's rows.
ROW = _blocks((len(CONFIG), len(STATE), len(ACC), len(INPUT), len(LAW), len(STATE), len(ACC),
               len(LAW), 1, 1, 1, 1, 1, 1, 4))


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
    """True if the drive of CONFIG row ``c`` runs in a group of lanes of ``n_sub``
    substeps: any variant, one substep count per group."""
    return int(c[CONFIG.SUBSTEPS]) == n_sub


@_jit
def group_variants(configs):
    """What a group of lanes whose drives have the CONFIG rows ``configs``
    computes: (``moves``: a drive's profile is not a constant speed,
    ``noisy``: a drive has current-sensor noise, ``current_only``: every drive
    is in current mode without the back-EMF estimate). The tests are those the
    kernel's branches make, so a NaN setting computes the variant."""
    moves = False
    noisy = False
    current_only = True
    for c in configs:
        moves = moves | (c[CONFIG.PROFILE] != PROFILE.CONSTANT)
        noisy = noisy | (c[CONFIG.I_NOISE] != 0.0)
        current_only = (current_only & (c[CONFIG.DRIVE_MODE] == DRIVE.CURRENT)
                        & (c[CONFIG.VEL_EST] != VEL_EST.BACK_EMF))
    return moves, noisy, current_only


@_jit
def given_lanes(w, moves, noisy):
    """The period's command and sensor noise for every lane (``control_step``'s
    ``given``: what depends on the period and the drive's constants alone), in
    loops of their own so that a group skips what none of its lanes uses: the
    move profiles where every lane runs at a constant speed (``moves`` False),
    the noise where no lane has any (``noisy`` False; the lanes' selects then
    never read it). The values are those ``control_step`` computes."""
    n = LANES
    if moves:
        for d in range(n):
            t = w[_st(STATE.PERIOD, d)] * w[(ROW.CFG + CONFIG.DT) * n + d]
            p, v = command_in(t, w[(ROW.CFG + CONFIG.PROFILE) * n + d],
                              w[(ROW.CFG + CONFIG.SPEED) * n + d],
                              w[(ROW.CFG + CONFIG.ACCEL) * n + d],
                              w[(ROW.CFG + CONFIG.DISTANCE) * n + d], n)
            w[ROW.GIVEN * n + d] = p
            w[(ROW.GIVEN + 1) * n + d] = v
    else:
        for d in range(n):
            t = w[_st(STATE.PERIOD, d)] * w[(ROW.CFG + CONFIG.DT) * n + d]
            p, v = constant_speed_command(t, w[(ROW.CFG + CONFIG.SPEED) * n + d],
                                          w[(ROW.CFG + CONFIG.ACCEL) * n + d])
            w[ROW.GIVEN * n + d] = p
            w[(ROW.GIVEN + 1) * n + d] = v
    if noisy:
        for d in range(n):
            a, b = gaussian_pair_keyed(float_bits(w[ROW.KEY * n + d]), w[_st(STATE.PERIOD, d)], n)
            w[(ROW.GIVEN + 2) * n + d] = a
            w[(ROW.GIVEN + 3) * n + d] = b
    else:
        for d in range(n):
            w[(ROW.GIVEN + 2) * n + d] = 0.0
            w[(ROW.GIVEN + 3) * n + d] = 0.0


@_jit
def control_lanes(w, law, current_only):
    """The sample, law, control and metrics of one period for every lane
    (:func:`kernel.control_period`, compiled for lanes); ``law`` None (pruned
    at compile time) or ``w`` for the damping law in the workspace;
    ``current_only`` None, or (a group of current-mode drives without the
    back-EMF estimate) not None: the other variants' branches are not compiled."""
    n = LANES
    for d in range(n):
        c = _config_column(w, ROW.CFG, d)
        q = _controller_params(c, n)
        u = _input_column(w, ROW.IN, d)
        at = ROW.ST * n + d
        x = load_plant(w, at, n)
        period, cs, v_next, obs = load_controller(w, at, n, w[ROW.SIN * n + d], w[ROW.COS * n + d])
        m = load_metrics(w, ROW.AC * n + d, n)
        win_start, win_end = c[CONFIG.WINDOW_START], c[CONFIG.WINDOW_END]
        ref_rate = c[CONFIG.NR] * c[CONFIG.REF_SPEED]
        if law is not None:
            lw, u = law_input(load_law(w, ROW.LW * n + d, n), u, cs, obs, q[CTRL.DT], n)
            store_law(w, ROW.LW * n + d, n, lw)
        given = (w[ROW.GIVEN * n + d], w[(ROW.GIVEN + 1) * n + d], w[(ROW.GIVEN + 2) * n + d],
                 w[(ROW.GIVEN + 3) * n + d])
        cs, v, v_next, obs, m, off_path = control_period(period, x, cs, v_next, obs, m, q, u,
                                                         win_start, win_end, ref_rate, n, given,
                                                         current_only)
        store_controller(w, at, n, period + 1.0, cs, v_next, obs)
        store_metrics(w, ROW.AC * n + d, n, m)
        w[ROW.VA * n + d] = v[0]
        w[ROW.VB * n + d] = v[1]
        w[ROW.SIN * n + d] = obs.sin_angle
        w[ROW.COS * n + d] = obs.cos_angle
        w[ROW.RARE * n + d] = 1.0 if off_path else 0.0


@_jit
def plant_lanes(w, wide):
    """One plant step (:func:`kernel.plant_step_in`, compiled for lanes) for every
    lane, in place; ``wide`` not None: RK4 stage shifts beyond 1/8 rad computed
    too (a fast rotor stays in lanes; each variant compiled once)."""
    n = LANES
    for d in range(n):
        c = _config_column(w, ROW.CFG, d)
        at = ROW.ST * n + d
        x, off_path = plant_step_in(load_plant(w, at, n), w[ROW.VA * n + d], w[ROW.VB * n + d],
                                    _plant_params(c), c[CONFIG.DT] / int(c[CONFIG.SUBSTEPS]),
                                    c[CONFIG.W_STICK], n, wide)
        store_plant(w, at, n, x)
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
    LANES runs through the kernel for the whole call. Returns the number of
    drive-periods the kernel ran (those, and the periods run again).
    """
    n = LANES
    w = np.zeros(ROW.ROWS * n)
    law = None if laws is None else w
    empty = np.zeros((0, len(TRACE)))
    # Typed int64, not a literal 1: a literal would compile the kernel's loop (and
    # the wide plant) once more for it, minutes of compiling.
    one = np.int64(1)
    every = one
    s_one = np.empty(len(STATE))
    a_one = np.empty(len(ACC))
    l_one = np.empty(len(LAW))
    shift_per_speed = np.empty(n)
    again = 0
    for first in range(0, configs.shape[0], n):
        m = min(n, configs.shape[0] - first)
        n_sub = int(configs[first, CONFIG.SUBSTEPS])
        # Drives of another substep count: the kernel, for the whole call.
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
        # The padding lanes copy the group's first drive: its drives decide.
        moves, noisy, current_only = group_variants(configs[first:first + m])
        for d in range(n):
            sin_a, cos_a = sincos(w[_st(STATE.PARK_ANGLE, d)])
            w[ROW.SIN * n + d] = sin_a
            w[ROW.COS * n + d] = cos_a
            # The uint64 key kept as a double's bits (possibly a NaN's): only
            # moved, never computed with, so every bit survives.
            w[ROW.KEY * n + d] = bits_float(noise_key(w[(ROW.CFG + CONFIG.NOISE_SEED) * n + d]))
        if laws is not None:
            _load(w, first, laws, ROW.LW, m)
            # Whether the resonant terms run is set once per call, as in run_periods_law.
            for d in range(n):
                on = 0.0
                for j in range(LAW.KR1, LAW.KI4 + 1):
                    if w[(ROW.LW + j) * n + d] != 0.0:
                        on = 1.0
                for j in range(LAW.A1, LAW.B4 + 1):
                    if w[(ROW.LW + j) * n + d] != 0.0:
                        on = 1.0
                w[(ROW.LW + LAW.RESONANT) * n + d] = on
        # A stage shift of the electrical angle is about Nr * h * omega (rad).
        for d in range(n):
            shift_per_speed[d] = (w[(ROW.CFG + CONFIG.NR) * n + d]
                                  * w[(ROW.CFG + CONFIG.DT) * n + d] / n_sub)
        for _ in range(n_periods):
            # The wide plant where a rotor turns fast enough to shift past 1/8 rad
            # (near it: a period it shifts past is run again by the kernel).
            wide = False
            for d in range(n):
                wide = wide | (abs(w[_st(STATE.OMEGA, d)]) * shift_per_speed[d] > WIDE_SHIFT)
            for j in range(ROW.ST * n, ROW.IN * n):
                w[j + (ROW.ST0 - ROW.ST) * n] = w[j]
            if laws is not None:
                for j in range(ROW.LW * n, (ROW.LW + len(LAW)) * n):
                    w[j + (ROW.LW0 - ROW.LW) * n] = w[j]
            given_lanes(w, moves, noisy)
            if current_only:
                control_lanes(w, law, one)
            else:
                control_lanes(w, law, None)
            for _ in range(n_sub):
                if wide:
                    plant_lanes(w, one)
                else:
                    plant_lanes(w, None)
            for d in range(m):
                if not fixed[d] and w[ROW.RARE * n + d] != 0.0:
                    # The kernel runs this drive's period again from its start.
                    again += 1
                    for j in range(len(STATE)):
                        s_one[j] = w[(ROW.ST0 + j) * n + d]
                    for j in range(len(ACC)):
                        a_one[j] = w[(ROW.AC0 + j) * n + d]
                    if laws is None:
                        run_periods(configs[first + d], s_one, a_one, inputs[first + d], one, empty,
                                    every)
                    else:
                        for j in range(len(LAW)):
                            l_one[j] = w[(ROW.LW0 + j) * n + d]
                        run_periods_law(configs[first + d], s_one, a_one, inputs[first + d], l_one,
                                        one, empty, every)
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
