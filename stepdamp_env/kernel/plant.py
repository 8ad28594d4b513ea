"""The plant: Park transforms, SVPWM, PI steps, the detent and friction torques,
the motor's derivative and its RK4 step (moving, or held by static friction)."""

from __future__ import annotations

from numba import njit

from ..fixedmath import sincos, sincos_in, sincos_shifted_in
from .layout import CONFIG, PLANT

__all__ = ["park_sc", "inverse_park_sc", "park", "inverse_park", "svpwm_legs", "pi_output",
           "pi_update", "harmonics", "harmonic_series", "plant_params", "detent_torque",
           "detent_potential", "electromagnetic_torque", "friction_torque", "driving_torque",
           "driving_torque_sc", "motor_derivative_sc", "motor_derivative", "rk4_step",
           "rk4_moving", "rk4_combine", "plant_step", "plant_step_in", "rk4_step_stuck"]

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
# Small pieces. Each is a pure function of floats and float tuples.
# ---------------------------------------------------------------------------
@_jit_inline
def park_sc(ia, ib, sin_a, cos_a):
    """:func:`park` given the sine and cosine of the angle."""
    return ia * cos_a + ib * sin_a, -ia * sin_a + ib * cos_a


@_jit_inline
def inverse_park_sc(d, q, sin_a, cos_a):
    """:func:`inverse_park` given the sine and cosine of the angle."""
    return d * cos_a - q * sin_a, d * sin_a + q * cos_a


@_jit
def park(ia, ib, angle):
    """Stationary (a, b) to rotating (d, q) at electrical angle ``angle`` (rad)."""
    s, c = sincos(angle)
    return park_sc(ia, ib, s, c)


@_jit
def inverse_park(d, q, angle):
    """Rotating (d, q) to stationary (a, b) at electrical angle ``angle`` (rad)."""
    s, c = sincos(angle)
    return inverse_park_sc(d, q, s, c)


@_jit_inline
def svpwm_legs(va, vb, vdc):
    """Leg voltages (V) of the three-leg chopper, eqs. 10-13, each clamped to [0, Vdc].

    Phase A sits between legs alpha and gamma, phase B between beta and gamma.
    The common-mode offset v0 centres the span of (va, vb, 0) in the bus; when
    the span exceeds Vdc the demand is infeasible and the clamp saturates it.
    """
    vmax = max(va, vb, 0.0)
    vmin = min(va, vb, 0.0)
    v0 = 0.5 * vdc - 0.5 * (vmax + vmin)
    v_alpha = min(max(va + v0, 0.0), vdc)
    v_beta = min(max(vb + v0, 0.0), vdc)
    v_gamma = min(max(v0, 0.0), vdc)
    return v_alpha, v_beta, v_gamma


@_jit_inline
def pi_output(error, integrator, kp):
    """Unsaturated PI output kp*e + integrator (V)."""
    return kp * error + integrator


@_jit_inline
def pi_update(error, integrator, demanded, achieved, kp, ki, dt):
    """Integrator (V) after one step, with back-calculation anti-windup.

    The integrator integrates ki*(e + (achieved - demanded)/kp): while the
    output is not limited this is the plain PI; while it is, the integrator
    is pulled toward the achievable output at the rate ki/kp instead of winding up.
    """
    return integrator + dt * ki * (error + (achieved - demanded) * (1.0 / kp))


@_jit_inline
def harmonics(s1, c1):
    """sin and cos of 2x and 4x from sin x and cos x (no further trig calls)."""
    s2 = 2.0 * s1 * c1
    c2 = c1 * c1 - s1 * s1
    s4 = 2.0 * s2 * c2
    c4 = c2 * c2 - s2 * s2
    return s2, c2, s4, c4


@_jit_inline
def harmonic_series(s1, c1, a1, b1, a2, b2, a4, b4):
    """a1 sin x + b1 cos x + a2 sin 2x + b2 cos 2x + a4 sin 4x + b4 cos 4x."""
    s2, c2, s4, c4 = harmonics(s1, c1)
    return a1 * s1 + b1 * c1 + a2 * s2 + b2 * c2 + a4 * s4 + b4 * c4


@_jit
def plant_params(c):
    """The plant's constants as a tuple, the form the derivative takes.

    Positions are the ``P_*`` names: (R, 1/L, Km, Nr, 1/J, D, detent s1, c1,
    s2, c2, s4, c4, Fs, load_torque).
    """
    return (c[CONFIG.R], 1.0 / c[CONFIG.L], c[CONFIG.KM], c[CONFIG.NR], 1.0 / c[CONFIG.J], c[CONFIG.D],
            c[CONFIG.DET_S1], c[CONFIG.DET_C1], c[CONFIG.DET_S2], c[CONFIG.DET_C2], c[CONFIG.DET_S4], c[CONFIG.DET_C4],
            c[CONFIG.FS], c[CONFIG.LOAD])


@_jit
def detent_torque(theta, p):
    """Detent torque (N*m): -Kd4 sin 4x - Kd2 sin(2x + phi2) - Kd1 sin(x + phi1), x = Nr*theta."""
    s1, c1 = sincos(p[PLANT.NR] * theta)
    return -harmonic_series(s1, c1, p[PLANT.DET_S1], p[PLANT.DET_C1], p[PLANT.DET_S2], p[PLANT.DET_C2],
                            p[PLANT.DET_S4], p[PLANT.DET_C4])


@_jit
def detent_potential(theta, p):
    """Potential energy V(theta) (J) of the detent torque: torque = -dV/dtheta."""
    nr = p[PLANT.NR]
    s1, c1 = sincos(nr * theta)
    s2, c2, s4, c4 = harmonics(s1, c1)
    # a sin hx + b cos hx integrates over theta to -(a cos hx - b sin hx)/(h Nr).
    return -((p[PLANT.DET_S1] * c1 - p[PLANT.DET_C1] * s1) / nr
             + (p[PLANT.DET_S2] * c2 - p[PLANT.DET_C2] * s2) / (2.0 * nr)
             + (p[PLANT.DET_S4] * c4 - p[PLANT.DET_C4] * s4) / (4.0 * nr))


@_jit_inline
def electromagnetic_torque(ia, ib, sin_x, cos_x, km):
    """tau_em = Km(-ia sin x + ib cos x) (N*m), x = Nr*theta (eq. 3)."""
    return km * (-ia * sin_x + ib * cos_x)


@_jit_inline
def friction_torque(omega, tau_drive, fs):
    """Friction while sliding (N*m, positive opposes positive rotation).

    Coulomb friction Fs*sign(omega); exactly at rest it balances the driving
    torque up to the breakaway level Fs. Sticking is decided per plant step
    in :func:`plant_step` (Karnopp model).
    """
    if omega == 0.0:
        return min(max(tau_drive, -fs), fs)
    if omega > 0.0:
        return fs
    return -fs


@_jit
def driving_torque(theta, omega, ia, ib, p):
    """Every torque on the rotor except friction (N*m)."""
    s1, c1 = sincos(p[PLANT.NR] * theta)
    return driving_torque_sc(s1, c1, omega, ia, ib, p)


@_jit_inline
def driving_torque_sc(sin_x, cos_x, omega, ia, ib, p):
    """:func:`driving_torque` given sin and cos of x = Nr*theta."""
    det = harmonic_series(sin_x, cos_x, p[PLANT.DET_S1], p[PLANT.DET_C1], p[PLANT.DET_S2],
                          p[PLANT.DET_C2], p[PLANT.DET_S4], p[PLANT.DET_C4])
    return (electromagnetic_torque(ia, ib, sin_x, cos_x, p[PLANT.KM]) - det - p[PLANT.D] * omega
            - p[PLANT.LOAD])


@_jit_inline
def motor_derivative_sc(sin_x, cos_x, omega, ia, ib, va, vb, p):
    """:func:`motor_derivative` given sin and cos of x = Nr*theta."""
    r, inv_l, km, d = p[PLANT.R], p[PLANT.INV_L], p[PLANT.KM], p[PLANT.D]
    tau_det = harmonic_series(sin_x, cos_x, p[PLANT.DET_S1], p[PLANT.DET_C1], p[PLANT.DET_S2],
                              p[PLANT.DET_C2], p[PLANT.DET_S4], p[PLANT.DET_C4])
    tau_drive = (electromagnetic_torque(ia, ib, sin_x, cos_x, km) - tau_det - d * omega
                 - p[PLANT.LOAD])
    fric = friction_torque(omega, tau_drive, p[PLANT.FS])
    # Back-EMF ea = -Km w sin x, eb = Km w cos x (eq. 2 with the cosine).
    dia = (va - r * ia + km * omega * sin_x) * inv_l
    dib = (vb - r * ib - km * omega * cos_x) * inv_l
    return (omega, (tau_drive - fric) * p[PLANT.INV_J], dia, dib,
            va * ia + vb * ib, r * (ia * ia + ib * ib), d * omega * omega,
            fric * omega, p[PLANT.LOAD] * omega)


@_jit
def motor_derivative(theta, omega, ia, ib, va, vb, p):
    """Right-hand side of the plant (docs/model.md, "The plant").

    ``p`` is :func:`plant_params`. Returns (dtheta, domega, dia, dib, p_in,
    p_cu, p_damp, p_fric, p_load): the state derivatives and the powers (W)
    supplied to the windings, lost in copper, in viscous damping, in friction
    and delivered to the load torque.
    """
    s1, c1 = sincos(p[PLANT.NR] * theta)
    return motor_derivative_sc(s1, c1, omega, ia, ib, va, vb, p)


@_jit_inline
def rk4_step(x, va, vb, p, h):
    """RK4 step of ``h`` s of the plant state plus energy accumulators.

    ``x`` = (theta, omega, ia, ib, E_in, E_cu, E_damp, E_fric, E_load); the
    energies (J) are integrated with the same stages, so the balance closes to
    the integrator's accuracy. Returns the new ``x``.
    """
    x0 = p[PLANT.NR] * x[0]
    s0, c0 = sincos(x0)
    return rk4_moving(x, x0, s0, c0, va, vb, p, h, None, None)[0]


@_jit_inline
def rk4_moving(x, x0, s0, c0, va, vb, p, h, lanes, wide):
    """:func:`rk4_step` given x0 = Nr*theta and its sine and cosine; returns the
    new ``x`` and whether a stage left the lanes' branch-free path (only lanes,
    ``lanes`` not None, need to know): shifted x0 by more than 1/8 rad (beyond
    :func:`..fixedmath.sincos_rotated`'s range), or, ``wide`` not None (wide
    shifts computed too), to an angle beyond 1e6 rad or NaN."""
    w, ia, ib = x[1], x[2], x[3]
    nr = p[PLANT.NR]
    hh = 0.5 * h
    k1 = motor_derivative_sc(s0, c0, w, ia, ib, va, vb, p)
    shift2 = nr * hh * k1[0]
    s2, c2 = sincos_shifted_in(x0, s0, c0, shift2, lanes, wide)
    k2 = motor_derivative_sc(s2, c2, w + hh * k1[1], ia + hh * k1[2], ib + hh * k1[3],
                             va, vb, p)
    shift3 = nr * hh * k2[0]
    s3, c3 = sincos_shifted_in(x0, s0, c0, shift3, lanes, wide)
    k3 = motor_derivative_sc(s3, c3, w + hh * k2[1], ia + hh * k2[2], ib + hh * k2[3],
                             va, vb, p)
    shift4 = nr * h * k3[0]
    s4, c4 = sincos_shifted_in(x0, s0, c0, shift4, lanes, wide)
    k4 = motor_derivative_sc(s4, c4, w + h * k3[1], ia + h * k3[2], ib + h * k3[3],
                             va, vb, p)
    far = (abs(shift2) > 0.125) | (abs(shift3) > 0.125) | (abs(shift4) > 0.125)
    if wide is not None:
        far = _out_of_range(x0 + shift2) | _out_of_range(x0 + shift3) | _out_of_range(x0 + shift4)
    return rk4_combine(x, k1, k2, k3, k4, h), far


@_jit_inline
def _out_of_range(angle):
    """Beyond :func:`..fixedmath.sincos_lane`'s range: |angle| >= 1e6 rad, or NaN."""
    return (abs(angle) >= 1e6) | (angle != angle)


@_jit_inline
def rk4_combine(x, k1, k2, k3, k4, h):
    """x + h/6 (k1 + 2 (k2 + k3) + k4), each of the nine components."""
    h6 = h * (1.0 / 6.0)
    return (x[0] + h6 * (k1[0] + 2.0 * (k2[0] + k3[0]) + k4[0]),
            x[1] + h6 * (k1[1] + 2.0 * (k2[1] + k3[1]) + k4[1]),
            x[2] + h6 * (k1[2] + 2.0 * (k2[2] + k3[2]) + k4[2]),
            x[3] + h6 * (k1[3] + 2.0 * (k2[3] + k3[3]) + k4[3]),
            x[4] + h6 * (k1[4] + 2.0 * (k2[4] + k3[4]) + k4[4]),
            x[5] + h6 * (k1[5] + 2.0 * (k2[5] + k3[5]) + k4[5]),
            x[6] + h6 * (k1[6] + 2.0 * (k2[6] + k3[6]) + k4[6]),
            x[7] + h6 * (k1[7] + 2.0 * (k2[7] + k3[7]) + k4[7]),
            x[8] + h6 * (k1[8] + 2.0 * (k2[8] + k3[8]) + k4[8]))


@_jit_inline
def plant_step(x, va, vb, p, h, w_stick):
    """One plant step of ``h`` s with the stick-slip decision at its start.

    The rotor sticks when it turns slower than ``w_stick`` (rad/s) and the
    driving torque is within the breakaway level Fs: its speed is set to zero
    (the kinetic energy removed, 0.5*J*w^2, is booked as friction loss) and
    friction holds it for the step. Returns the new ``x`` (see rk4_step).
    """
    return plant_step_in(x, va, vb, p, h, w_stick, None, None)[0]


@_jit_inline
def plant_step_in(x, va, vb, p, h, w_stick, lanes, wide):
    """:func:`plant_step`, the one definition for a drive's own loop (``lanes``
    None: branches) and for SIMD lanes (``lanes`` not None, chosen when
    compiled: both steps computed, one selected; ``wide`` not None: stage
    shifts beyond 1/8 rad too, :func:`rk4_moving`). Returns the new ``x`` and,
    for lanes, whether the step left their branch-free path (an angle beyond
    1e6 rad or NaN, a stage shift beyond 1/8 rad unless wide); False for a
    drive's loop."""
    x0 = p[PLANT.NR] * x[0]
    s0, c0 = sincos_in(x0, lanes)
    # The stick decision: the driving torque at rest, at x0 (computed only for a
    # slow rotor, except in lanes).
    stuck = abs(x[1]) < w_stick
    if lanes is not None or stuck:
        stuck = stuck & (abs(driving_torque_sc(s0, c0, 0.0, x[2], x[3], p)) <= p[PLANT.FS])
    if lanes is None and stuck:
        return rk4_step_stuck(x, va, vb, p, h), False
    moving, far = rk4_moving(x, x0, s0, c0, va, vb, p, h, lanes, wide)
    if lanes is None:
        return moving, False
    held = rk4_step_stuck(x, va, vb, p, h)
    off_path = (abs(x0) >= 1e6) | (x0 != x0) | ((not stuck) & far)
    return ((held[0] if stuck else moving[0], held[1] if stuck else moving[1],
             held[2] if stuck else moving[2], held[3] if stuck else moving[3],
             held[4] if stuck else moving[4], held[5] if stuck else moving[5],
             held[6] if stuck else moving[6], held[7] if stuck else moving[7],
             held[8] if stuck else moving[8]), off_path)


@_jit_inline
def rk4_step_stuck(x, va, vb, p, h):
    """RK4 step of the windings with the rotor held by stiction.

    Speed is set to zero (the kinetic energy removed, 0.5*J*w^2, is booked as
    friction loss) and friction balances the driving torque, so the shaft stays
    put for the step; only the currents and the electrical energies move.
    """
    w = x[1]
    e_fric = x[7] + 0.5 * w * w / p[PLANT.INV_J]
    r, inv_l = p[PLANT.R], p[PLANT.INV_L]
    ia, ib = x[2], x[3]
    hh = 0.5 * h
    a1, b1 = (va - r * ia) * inv_l, (vb - r * ib) * inv_l
    a2, b2 = (va - r * (ia + hh * a1)) * inv_l, (vb - r * (ib + hh * b1)) * inv_l
    a3, b3 = (va - r * (ia + hh * a2)) * inv_l, (vb - r * (ib + hh * b2)) * inv_l
    a4, b4 = (va - r * (ia + h * a3)) * inv_l, (vb - r * (ib + h * b3)) * inv_l
    h6 = h * (1.0 / 6.0)
    ia1 = ia + h6 * (a1 + 2.0 * (a2 + a3) + a4)
    ib1 = ib + h6 * (b1 + 2.0 * (b2 + b3) + b4)
    # Power in and copper loss at the stage currents, weighted like the states.
    ia_s = (ia, ia + hh * a1, ia + hh * a2, ia + h * a3)
    ib_s = (ib, ib + hh * b1, ib + hh * b2, ib + h * b3)
    p_in = 0.0
    p_cu = 0.0
    for k in range(4):
        wk = 1.0 if k == 0 or k == 3 else 2.0
        p_in += wk * (va * ia_s[k] + vb * ib_s[k])
        p_cu += wk * r * (ia_s[k] * ia_s[k] + ib_s[k] * ib_s[k])
    return (x[0], 0.0, ia1, ib1, x[4] + h6 * p_in, x[5] + h6 * p_cu, x[6], e_fric, x[8])


