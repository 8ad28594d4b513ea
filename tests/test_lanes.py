"""SIMD across drives (``stepdamp_env.lanes``): the kernel's bits, vectorised.

The branch-free pieces equal the kernel's branchy ones bit for bit on their
domain; a batch stepped in lanes equals ``kernel.run_batch`` (and ``run_batch_law``)
bit for bit, for a group of lanes that mixes every variant of the drive (open
loop and servo, current and voltage mode, each velocity estimator and profile),
the periods that leave the branch-free path being run again by the kernel; and
LLVM really did vectorise the loops over lanes.
"""

from __future__ import annotations

import math
import re

import numba
import numpy as np
import pytest

from stepdamp_env import fixedmath as fm
from stepdamp_env import kernel as K
from stepdamp_env import lanes
from stepdamp_env.motorfile import load_system
from stepdamp_env.simulation import (RunSettings, SpeedProfile, build_config, initial_state,
                                     new_accumulators)

RNG = np.random.default_rng(77)


@numba.njit
def _sincos_both(x):
    out = np.empty((x.size, 4))
    for i in range(x.size):
        out[i, 0], out[i, 1] = fm.sincos(x[i])
        out[i, 2], out[i, 3] = fm.sincos_lane(x[i])
    return out


@numba.njit
def _shift_both(x0, delta, wide):
    """sincos_shifted beside the lanes' rotation (wide: the wide lanes' shift)."""
    out = np.empty((x0.size, 4))
    for i in range(x0.size):
        s0, c0 = fm.sincos(x0[i])
        out[i, 0], out[i, 1] = fm.sincos_shifted(x0[i], s0, c0, delta[i])
        if wide:
            out[i, 2], out[i, 3] = fm.sincos_shifted_in(x0[i], s0, c0, delta[i], 1, 1)
        else:
            out[i, 2], out[i, 3] = fm.sincos_rotated(s0, c0, delta[i])
    return out


@numba.njit
def _log_both(x):
    out = np.empty((x.size, 2))
    for i in range(x.size):
        out[i, 0] = fm.log(x[i])
        out[i, 1] = fm.log_lane(x[i])
    return out


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a).view(np.uint64)


def test_sincos_lane_is_sincos_below_1e6():
    x = np.concatenate([RNG.uniform(-1e6, 1e6, 20000), RNG.uniform(-10, 10, 20000),
                        np.arange(-64, 65) * (math.pi / 4), [0.0, -0.0, 5e-324, -1e-300, 999999.9]])
    out = _sincos_both(x)
    assert np.array_equal(_bits(out[:, :2]), _bits(out[:, 2:]))
    assert math.copysign(1.0, _sincos_both(np.array([-0.0]))[0, 2]) == -1.0


def test_sincos_rotated_is_sincos_shifted_up_to_an_eighth():
    x0 = RNG.uniform(-1e4, 1e4, 20000)
    delta = RNG.uniform(-0.125, 0.125, 20000)
    out = _shift_both(x0, delta, False)
    assert np.array_equal(_bits(out[:, :2]), _bits(out[:, 2:]))


def test_the_wide_shift_is_sincos_shifted_at_any_shift():
    x0 = RNG.uniform(-1e4, 1e4, 20000)
    delta = np.concatenate([RNG.uniform(-4.0, 4.0, 19996), [0.125, -0.125, 0.13, -0.5]])
    out = _shift_both(x0, delta, True)
    assert np.array_equal(_bits(out[:, :2]), _bits(out[:, 2:]))


def test_a_fast_rotor_stays_in_lanes_with_the_kernels_bits():
    # 6-16 rev/s on 50-tooth rotors at 20 kHz: every RK4 stage shifts the
    # electrical angle by 1/8 rad or more (before the wide plant: all run again).
    names = ("patent", "qsh4218-51-10-049", "qsh5718-56-28-126", "qsh6018-65-28-210")
    configs = [build_config(load_system(names[i % 4]).replace(current_noise_a=0.02),
                            SpeedProfile(6.0 + 10.0 * i / 31, accel_rps2=4000.0),
                            RunSettings(noise_seed=i, mode="servo" if i % 3 == 0 else "open-loop",
                                        base_controller="patent-ff"), window_start_s=0.01)
               for i in range(lanes.LANES)]
    c = np.array(configs)
    s = np.array([initial_state(row) for row in c])
    a, u = new_accumulators(len(c)), np.zeros((len(c), len(K.INPUT)))
    s_k, a_k = s.copy(), a.copy()
    K.run_batch(c, s_k, a_k, u, 2000)
    assert lanes.run_batch_lanes(c, s, a, u, 2000) == 0
    assert np.array_equal(_bits(s), _bits(s_k)) and np.array_equal(_bits(a), _bits(a_k))
    assert np.abs(s[:, K.STATE.OMEGA] * 50 / 20000).max() > 0.125


def test_log_lane_is_log_for_positive_normal_numbers():
    x = np.concatenate([RNG.random(20000), np.exp(RNG.uniform(-700, 700, 20000)),
                        [1.0, 0.5, 2.0, 2.0 ** -53, 2.0 ** -1022, np.nextafter(1.0, 0.0),
                         math.sqrt(0.5), np.nextafter(math.sqrt(0.5), 1.0)]])
    out = _log_both(x)
    assert np.array_equal(_bits(out[:, 0]), _bits(out[:, 1]))


def _batch(n: int):
    """n drives of every variant (noise on some, inputs on some), mixed in each
    group of lanes, drives that leave the branch-free path (beyond 1e6 rad of
    rotor or command angle) and one turning fast enough for an RK4 stage to
    shift the angle by more than 1/8 rad (the wide plant). The second group of LANES
    starts with a drive of two substeps, so its others are left to the kernel."""
    names = ("patent", "qsh4218-51-10-049", "qsh5718-56-28-126", "qsh6018-65-28-210")
    configs, states = [], []
    for i in range(n):
        system = load_system(names[i % len(names)])
        kind = i % KINDS
        settings = RunSettings(noise_seed=i)
        profile = SpeedProfile(0.2 + 0.13 * i)
        if i == lanes.LANES:
            settings = RunSettings(substeps=2)
        elif kind == 1:
            system = system.replace(current_noise_a=0.02)
        elif kind == 2:
            settings = RunSettings(mode="servo", base_controller="patent-ff")
        elif kind == 3:
            system = system.replace(drive_mode="voltage")
        elif kind == 4:
            settings = RunSettings(velocity_estimator="kalman")
        elif kind == 5:
            settings = RunSettings(velocity_estimator="back-emf")
        elif kind == 6:
            profile = SpeedProfile(2.0, kind="move", distance_rev=0.3)
        elif kind == 7:
            settings = RunSettings(substeps=2)
        elif kind == 8:
            settings = RunSettings(base_controller="patent-ff")
        elif kind == 9:
            profile = SpeedProfile(0.0)       # at rest: the rotor sticks
        elif kind == 13:
            profile = SpeedProfile(-3.0, kind="move", distance_rev=-0.05, ramp="s-curve",
                                   accel_rps2=400.0)
            settings = RunSettings(mode="servo", base_controller="patent-ff")
        elif kind == 14:
            system = system.replace(drive_mode="voltage", current_noise_a=0.02)
            settings = RunSettings(mode="servo", velocity_estimator="kalman")
        elif kind == 15:
            # Voltage mode fast enough that its angle turns by more than 1/8 rad a period.
            system = system.replace(drive_mode="voltage")
            profile = SpeedProfile(9.0, accel_rps2=2000.0)
        elif kind == 16:
            settings = RunSettings(mode="servo", velocity_estimator="back-emf")
        # Half the drives' windows close inside the run (a move's cruise, v4).
        c = build_config(system, profile, settings, window_start_s=0.02,
                         window_end_s=0.06 if i % 2 else math.inf)
        s = initial_state(c, theta0=2.5e4 if kind == 10 else 0.0)   # Nr*theta beyond 1e6 rad
        if kind == 11:
            s[K.STATE.PERIOD] = 8.0e7          # 4000 s on: the command angle beyond 1e6 rad
        if kind == 12:
            s[K.STATE.OMEGA] = 120.0           # rad/s: shifts beyond 1/8 rad
        configs.append(c)
        states.append(s)
    inputs = np.zeros((n, len(K.INPUT)))
    inputs[1::3] = RNG.normal(0.0, 0.01, inputs[1::3].shape)
    return np.array(configs), np.array(states), new_accumulators(n), inputs


KINDS = 17


def _laws(n: int) -> np.ndarray:
    laws = np.zeros((n, len(K.LAW)))
    laws[:, K.LAW.KV] = RNG.uniform(0.0, 0.05, n)
    laws[:, K.LAW.KP] = RNG.uniform(0.0, 0.5, n)
    laws[::2, K.LAW.KR1:K.LAW.KI4 + 1] = RNG.uniform(-50.0, 50.0, (len(laws[::2]), 6))
    laws[:, K.LAW.HP_ALPHA] = 0.01
    laws[:, K.LAW.LIMIT] = RNG.choice([0.01, 0.3], n)     # some clamp
    return laws


@pytest.mark.parametrize("with_law", [False, True])
def test_a_batch_in_lanes_is_the_kernels_batch(with_law):
    n = lanes.LANES + KINDS             # a full group of lanes and a part of one
    c, s, a, u = _batch(n)
    laws = _laws(n)
    got = [s.copy(), a.copy(), laws.copy()]
    want = [s.copy(), a.copy(), laws.copy()]
    again = 0
    for periods in (1, 400, 1600):      # chunked calls, as an env steps
        if with_law:
            K.run_batch_law(c, want[0], want[1], u, want[2], periods)
            again += lanes.run_batch_law_lanes(c, got[0], got[1], u, got[2], periods)
        else:
            K.run_batch(c, want[0], want[1], u, periods)
            again += lanes.run_batch_lanes(c, got[0], got[1], u, periods)
    for x, y in zip(got, want):
        assert np.array_equal(_bits(x), _bits(y))
    # The kernel ran the drives of another substep count and the far ones'
    # periods; the fast one stays in lanes (their wide plant).
    first = (np.arange(n) // lanes.LANES) * lanes.LANES
    others = sum(not lanes.in_lanes(c[i], int(c[first[i], K.CONFIG.SUBSTEPS])) for i in range(n))
    far = sum(i % KINDS in (10, 11) and lanes.in_lanes(c[i], int(c[first[i], K.CONFIG.SUBSTEPS]))
              for i in range(n))
    assert again == (others + far) * 2001
    assert np.all(np.isfinite(got[0])) and got[1][0, K.ACC.COUNT] > 0
    assert got[0][9, K.STATE.OMEGA] == 0.0                # stuck


# (moves, noisy, current_only) of a group of one kind: what it computes.
VARIANTS_OF_KIND = {0: (False, False, True), 1: (False, True, True), 2: (False, False, True),
                    3: (False, False, False), 4: (False, False, True), 5: (False, False, False),
                    6: (True, False, True), 13: (True, False, True), 14: (False, True, False),
                    16: (False, False, False)}


def test_a_group_computes_only_the_variants_its_lanes_use():
    c, _, _, _ = _batch(2 * KINDS)
    for kind, want in VARIANTS_OF_KIND.items():
        assert lanes.group_variants(c[[kind, kind + KINDS]]) == want, kind
    # One lane of another kind is enough for the group to compute its variant.
    assert lanes.group_variants(c[[0, 6]]) == (True, False, True)
    assert lanes.group_variants(c[[0, 1]]) == (False, True, True)
    assert lanes.group_variants(c[[0, 3]]) == (False, False, False)
    assert lanes.group_variants(c[[0, 5]]) == (False, False, False)
    assert lanes.group_variants(c) == (True, True, False)


@pytest.mark.parametrize("kind", [0, 1, 2, 3, 4, 5, 6, 13, 14])
def test_a_group_of_one_variant_has_the_kernels_bits(kind):
    # A group computes only what one of its lanes uses (the move profiles, the
    # noise, the voltage mode and the back-EMF estimate are skipped where no
    # lane has them): every lane of kind 0 (open loop, no noise) skips all four;
    # a mixed group (above) skips none.
    c, s, a, u = _batch(2 * KINDS)
    pick = [kind, kind + KINDS] * (lanes.LANES // 2)
    c, s, a, u = c[pick], s[pick], a[pick], u[pick]
    laws = _laws(len(c))
    for law in (None, laws):
        want = [s.copy(), a.copy(), None if law is None else law.copy()]
        got = [s.copy(), a.copy(), None if law is None else law.copy()]
        # The trapezoid move (kind 6) decelerates from 0.15 s to 0.19 s: run past it,
        # where its command leaves the constant-speed one's.
        for periods in (1, 700) if kind != 6 else (1, 700, 3400):
            if law is None:
                K.run_batch(c, want[0], want[1], u, periods)
                assert lanes.run_batch_lanes(c, got[0], got[1], u, periods) == 0
            else:
                K.run_batch_law(c, want[0], want[1], u, want[2], periods)
                assert lanes.run_batch_law_lanes(c, got[0], got[1], u, got[2], periods) == 0
        for x, y in zip(got, want):
            if x is not None:
                assert np.array_equal(_bits(x), _bits(y))


def test_a_nan_command_is_the_kernels_nan():
    # An S-curve whose ramp time underflows (accel/speed beyond 1e308): the
    # command is NaN from the first period; the lanes leave such a period to the
    # kernel, so even the NaNs' bits are the kernel's.
    c, s, a, u = _batch(lanes.LANES)
    profile = SpeedProfile(1e-6, kind="move", distance_rev=0.05, ramp="s-curve",
                           accel_rps2=1e307)
    system = load_system("patent")
    for i in (3, 20):
        c[i] = build_config(system, profile, RunSettings(mode="servo"), window_start_s=0.0)
        s[i] = initial_state(c[i])
    want, got = [s.copy(), a.copy()], [s.copy(), a.copy()]
    for periods in (1, 49):
        K.run_batch(c, want[0], want[1], u, periods)
        lanes.run_batch_lanes(c, got[0], got[1], u, periods)
        if periods == 1:
            assert np.isnan(want[0][3, K.STATE.THETA_CMD])
        for x, y in zip(got, want):
            assert np.array_equal(_bits(x), _bits(y))


def test_resonant_terms_switched_on_between_calls():
    c, s, a, u = _batch(lanes.LANES)
    keep = np.array([i % KINDS in (0, 1, 8) for i in range(lanes.LANES)])
    c, s, a, u = c[keep], s[keep], a[keep], u[keep]
    laws = _laws(len(c))
    laws[:, K.LAW.KR1:K.LAW.KI4 + 1] = 0.0
    want, got = [s.copy(), a.copy(), laws.copy()], [s.copy(), a.copy(), laws.copy()]
    for gains in (0.0, 40.0, 0.0):      # off, on, then off with the coefficients held
        want[2][:, K.LAW.KR1:K.LAW.KI4 + 1] = gains
        got[2][:, K.LAW.KR1:K.LAW.KI4 + 1] = gains
        K.run_batch_law(c, want[0], want[1], u, want[2], 300)
        assert lanes.run_batch_law_lanes(c, got[0], got[1], u, got[2], 300) == 0
    assert np.any(got[2][:, K.LAW.A1] != 0.0)
    for x, y in zip(got, want):
        assert np.array_equal(_bits(x), _bits(y))


def test_the_loops_over_lanes_are_vectorised():
    # The code users run (loaded from numba's cache, or compiled here if cold),
    # with the argument types step_lanes passes (the law: none, or an optional
    # row; the board's cache index lists these): its optimised LLVM must multiply
    # vectors of doubles in both controls and both plants. A cached function
    # cannot be inspected by numba's public API; the module it links into
    # callers can (numba's private _get_module_for_linking: if numba renames it,
    # this fails).
    row = numba.typeof(np.zeros(lanes.workspace_size()))
    none, law, one = numba.types.none, numba.types.Optional(row), numba.types.int64
    for fn, sig in ((lanes.control_lanes, (row, none, none)),
                    (lanes.control_lanes, (row, none, one)),
                    (lanes.control_lanes, (row, law, none)),
                    (lanes.control_lanes, (row, law, one)),
                    (lanes.given_lanes, (row, numba.types.boolean, numba.types.boolean)),
                    (lanes.plant_lanes, (row, none)),
                    (lanes.plant_lanes, (row, one))):
        fn.compile(sig)
        cres = fn.overloads[sig]
        # The function's own body, not the callees linked into its module.
        ir = str(cres.library._get_module_for_linking().get_function(cres.fndesc.llvm_func_name))
        assert re.search(r"fmul (\w+ )*<\d+ x double>", ir), f"{fn.__name__}{sig}: not vectorised"


def test_lanes_give_up_no_drive_of_their_variant():
    c, s, a, u = _batch(lanes.LANES)
    keep = np.array([i % KINDS in (0, 1, 8) for i in range(lanes.LANES)])
    c, s, a, u = c[keep], s[keep], a[keep], u[keep]
    assert lanes.run_batch_lanes(c, s, a, u, 500) == 0


def test_a_noise_key_with_a_nan_pattern_keeps_the_kernels_bits():
    # The lanes keep each drive's uint64 noise key as a double's bits; about one
    # seed in 2048 gives a NaN's pattern (seed 2794: a signalling NaN, which an
    # arithmetic operation would quieten).
    seed = next(s for s in range(20000) if (int(K.noise_key(s)) >> 52) & 0x7FF == 0x7FF)
    assert seed == 2794 and not (int(K.noise_key(seed)) >> 51) & 1
    c, s, a, u = _batch(2 * KINDS)
    pick = [1, 1 + KINDS] * (lanes.LANES // 2)                  # noisy open loop
    c, s, a, u = c[pick].copy(), s[pick], a[pick], u[pick]
    c[:, K.CONFIG.NOISE_SEED] = seed
    want, got = [s.copy(), a.copy()], [s.copy(), a.copy()]
    K.run_batch(c, want[0], want[1], u, 300)
    assert lanes.run_batch_lanes(c, got[0], got[1], u, 300) == 0
    for x, y in zip(got, want):
        assert np.array_equal(_bits(x), _bits(y))
