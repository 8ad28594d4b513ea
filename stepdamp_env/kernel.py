"""Numba kernel of the drive: small njit pieces composed into one fused loop.

Everything here is a pure function of plain floats or of flat float64 arrays, so
each piece can be called and tested from Python and the fused loop
(:func:`run_periods`) can advance one drive or a batch (:func:`run_batch`) without
leaving compiled code. The arrays' layouts are declared once below
(:func:`stepdamp_env.fields.layout`): ``CONFIG`` (never changed by a step),
``STATE`` (changed by every step), ``ACC`` (accumulated metrics), ``INPUT``
(external inputs held for a call), ``LAW`` (the damping law's gains and state)
and ``TRACE`` (trace channels); ``PLANT`` and ``CTRL`` name the positions of the
parameter tuples the pieces share. :mod:`stepdamp_env.simulation` builds them.

One PWM period of length dt = 1/pwm_hz, starting at t_k = k*dt, does:

1. sample: the position command at t_k, the winding currents and the encoder;
2. control: Park angle, current commands (holding current or servo law, plus
   the harmonic feedforward and any external residual), PI current loops in DQ
   with back-calculation anti-windup, inverse Park, SVPWM legs clamped to
   [0, Vdc];
3. apply the leg voltages computed in the previous period: a real DSP samples
   at the start of a period and loads its compare registers for the next one,
   so the drive has one PWM period of computation delay on top of the
   zero-order hold of the legs over the period;
4. integrate the plant over the period with ``substeps`` RK4 steps at constant
   winding voltage (exact ZOH: voltages only change at period boundaries).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .fields import describe, layout
from .fixedmath import log, sincos, sincos_shifted

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
# Configuration vector (per drive, float64). Plant truth, drive, controller.
# ---------------------------------------------------------------------------
CONFIG = layout("Config", """
    R             winding resistance (Ohm)
    L             winding inductance (H)
    KM            torque constant of the plant (N*m/A)
    NR            rotor teeth
    J             inertia (kg*m^2)
    D             viscous damping (N*m*s/rad)
    DET_S1        plant detent as sin/cos coefficients (N*m), see detent_torque
    DET_C1
    DET_S2
    DET_C2
    DET_S4
    DET_C4
    FS            Coulomb/breakaway friction (N*m)
    LOAD          constant load torque (N*m)
    VDC           bus voltage (V)
    DT            PWM period (s)
    HOLD          open-loop holding current (A)
    MICROSTEP     shaft angle of one microstep (rad)
    KP_I          current PI proportional gain (V/A)
    KI_I          current PI integral gain (V/(A*s))
    ENCODER       shaft angle of one encoder count (rad)
    VEL_ALPHA     velocity low-pass coefficient per period, 1 - exp(-2*pi*fc*dt)
    KP_VEL        servo velocity gain (N*m*s/rad)
    KP_POS        servo position gain (N*m/rad)
    KI_POS        servo position integral gain (N*m/(rad*s))
    MODE          a MODE code: OPEN_LOOP or SERVO
    BASE_CONTROLLER  1.0 if the base controller is "patent-ff" (its harmonic
                  feedforward and, in servo, its Fs term), 0.0 if "none"
    KM_EST        controller's estimate of Km (N*m/A)
    FS_EST        controller's estimate of Fs (N*m), servo feedforward
    FF_S1         controller's detent estimate as sin/cos coefficients (N*m)
    FF_C1
    FF_S2
    FF_C2
    FF_S4
    FF_C4
    SUBSTEPS      RK4 steps per PWM period
    W_STICK       stiction velocity band (rad/s)
    PROFILE       a PROFILE code: CONSTANT (speed after a ramp) or MOVE (point to point)
    SPEED         command speed (rad/s, signed)
    ACCEL         command acceleration (rad/s^2, > 0)
    DISTANCE      move distance (rad, signed), profile 1 only
    WINDOW_START  metrics window start (s)
    REF_SPEED     speed whose harmonics the metrics lock on to (rad/s)
    I_NOISE       current-sensor noise, standard deviation per sample (A)
    I_OFFSET_A    current-sensor offsets of phases A and B (A)
    I_OFFSET_B
    NOISE_SEED    seed of the sensor noise (an integer below 2**53)
    VEL_EST       velocity estimator, a VEL_EST code: encoder difference + low-pass,
                  Kalman filter, or back-EMF observer (no encoder)
    KF_K0         steady-state Kalman gain on the encoder innovation, position (1)
    KF_K1         the same, velocity (1/s)
    BEMF_G1       back-EMF observer: e = v - G1*i_k + G2*i_(k-1) (Ohm), the exact
                  one-period winding solution, G1 = R/(1-a), G2 = R*a/(1-a),
                  a = exp(-R*dt/L)
    BEMF_G2       (Ohm)
    DRIVE_MODE    a DRIVE code: CURRENT (DQ PI loops) or VOLTAGE (winding-model voltages)
    R_EST         the voltage-mode drive's model of the winding: resistance (Ohm)
    L_EST         and inductance (H)
""")

# Codes of the float fields that select a variant.
DRIVE = layout("Drive", """
    CURRENT    DQ PI current loops
    VOLTAGE    winding-model voltages (mid-band)
""")
VEL_EST = layout("VelocityEstimator", """
    LOWPASS    encoder difference and a first-order low-pass
    KALMAN     steady-state Kalman filter on the encoder
    BACK_EMF   back-EMF observer (no encoder)
""")
MODE = layout("Mode", """
    OPEN_LOOP  holding current, no position feedback
    SERVO      velocity and position loops on the encoder
""")
PROFILE = layout("Profile", """
    CONSTANT   constant speed after a ramp
    MOVE       point-to-point move
""")

# ---------------------------------------------------------------------------
# Positions in the tuple of plant_params (per drive, float64). numba reads a
# module-level layout as a constant: a named read compiles like a literal index.
# ---------------------------------------------------------------------------
PLANT = layout("Plant", """
    R       winding resistance (Ohm)
    INV_L   inverse winding inductance (1/H)
    KM      torque constant (N*m/A)
    NR      rotor teeth (electrical angle per shaft angle)
    INV_J   inverse inertia (1/(kg*m^2))
    D       viscous damping (N*m*s/rad)
    DET_S1  detent as sin/cos coefficients of harmonics 1, 2, 4 (N*m)
    DET_C1
    DET_S2
    DET_C2
    DET_S4
    DET_C4
    FS      Coulomb/breakaway friction (N*m)
    LOAD    constant load torque (N*m)
""")

# ---------------------------------------------------------------------------
# Positions in the tuple of controller_params (per drive, float64).
# ---------------------------------------------------------------------------
CTRL = layout("Controller", """
    DT          PWM period (s)
    NR          rotor teeth (electrical angle per shaft angle)
    HOLD        open-loop holding current (A)
    MICROSTEP   shaft angle of one microstep (rad)
    KP_I        current PI proportional gain (V/A)
    KI_I        current PI integral gain (V/(A*s))
    ENCODER     shaft angle of one encoder count (rad)
    VEL_ALPHA   velocity low-pass coefficient per period (dimensionless)
    KP_VEL      servo velocity gain (N*m*s/rad)
    KP_POS      servo position gain (N*m/rad)
    KI_POS      servo position integral gain (N*m/(rad*s))
    MODE        a MODE code
    BASE_CONTROLLER  1.0 if the base controller is "patent-ff", 0.0 if "none"
    KM_EST      controller's estimate of Km (N*m/A)
    FS_EST      controller's estimate of Fs (N*m)
    FF_S1       controller's detent estimate, sin/cos coefficients (N*m)
    FF_C1
    FF_S2
    FF_C2
    FF_S4
    FF_C4
    VDC         bus voltage (V)
    PROFILE     a PROFILE code
    SPEED       command speed (rad/s, signed)
    ACCEL       command acceleration (rad/s^2)
    DISTANCE    move distance (rad, signed)
    I_NOISE     current-sensor noise, standard deviation per sample (A)
    I_OFFSET_A  current-sensor offsets of phases A and B (A)
    I_OFFSET_B
    NOISE_SEED  seed of the sensor noise (integer-valued)
    VEL_EST     a VEL_EST code
    KF_K0       Kalman gain on the innovation, position (dimensionless)
    KF_K1       Kalman gain on the innovation, velocity (1/s)
    BEMF_G1     back-EMF observer constants (Ohm), see CONFIG.BEMF_G1
    BEMF_G2
    DRIVE_MODE  a DRIVE code
    R_EST       voltage mode's winding model: resistance (Ohm), inductance (H)
    L_EST
""")

# ---------------------------------------------------------------------------
# State vector (per drive, float64).
# ---------------------------------------------------------------------------
STATE = layout("State", """
    PERIOD         PWM periods done (exact integer in a float64)
    THETA          shaft angle (rad)
    OMEGA          shaft speed (rad/s)
    IA             phase A current (A)
    IB             phase B current (A)
    E_IN           energy supplied to the windings (J)
    E_CU           copper loss (J)
    E_DAMP         viscous loss (J)
    E_FRIC         friction loss (J)
    E_LOAD         work done on the load torque (J)
    INT_D          d-axis PI integrator (V)
    INT_Q          q-axis PI integrator (V)
    VA_NEXT        winding voltages computed this period, applied next (V)
    VB_NEXT
    THETA_FB_PREV  previous encoder angle (rad)
    OMEGA_FB       filtered velocity estimate (rad/s)
    POS_INT        servo integral of the position error (rad*s)
    THETA_FB       last encoder angle (rad)
    THETA_CMD      last command angle (rad)
    OMEGA_CMD      last command speed (rad/s)
    ID_MEAS        last measured d/q currents in the Park frame (A)
    IQ_MEAS
    IQ_FF          last injected feedforward + residual q current (A)
    PARK_ANGLE     last Park (electrical) angle (rad)
    THETA_EST      Kalman estimate of the shaft angle (rad)
    IA_PREV        measured phase currents of the previous sample (A), back-EMF observer
    IB_PREV
    VA_OLD         winding voltages applied during the period that just ended (V)
    VB_OLD
""")

# ---------------------------------------------------------------------------
# Accumulated metrics (per drive). Window sums use samples with t >= window start.
# ---------------------------------------------------------------------------
ACC = layout("Accumulators", """
    COUNT         samples in the window
    SUM_E         sum of velocity error w_cmd - w (rad/s)
    SUM_E2        sum of its square
    MIN_E
    MAX_E
    SUM_IFF2      sum of the squared injected q current (A^2)
    H1_S          lock-in sums of the error against h*Nr*theta_ref, h = 1, 2, 4
    H1_C
    H2_S
    H2_C
    H4_S
    H4_C
    MAX_LAG       max |theta_cmd - theta| over all samples (rad)
    MAX_CURRENT   max |i| of either phase over all samples (A)
    SUM_E2_ALL    sum of squared velocity error over all samples
    COUNT_ALL
    SUM_IFF2_ALL
""")

# ---------------------------------------------------------------------------
# External inputs held for one call (per drive): residual policy actions.
# ---------------------------------------------------------------------------
INPUT = layout("Input", """
    DS1  corrections to the feedforward coefficients (N*m)
    DC1
    DS2
    DC2
    DS4
    DC4
    IQ   residual q current (A)
""")

# ---------------------------------------------------------------------------
# Damping law (per drive, float64), evaluated every PWM period by
# :func:`run_periods_law`: gains (set between calls), then its own state.
# iq_law = clip(KV*e_w + KP*hp(e_theta) + sum_h a_h sin(h x) + b_h cos(h x), +-limit),
# e_w = w_cmd - w_fb, e_theta = theta_cmd - theta_fb (the drive's own samples),
# hp a first-order high-pass (removes the static lag), x the Park angle; the
# resonant phasor a_h + j b_h integrates (KR_h + j KI_h) times the velocity
# error demodulated at h*x (sin + j cos), clamped to +-limit.
# ---------------------------------------------------------------------------
LAW = layout("Law", """
    KV        velocity gain (A per rad/s)
    KP        high-passed position gain (A per rad): with KV, a phase lead
    KR1       resonant gains, real and imaginary, h = 1, 2, 4 (A/s per rad/s)
    KI1
    KR2
    KI2
    KR4
    KI4
    HP_ALPHA  high-pass coefficient per period, 1 - exp(-2*pi*fc*dt)
    LIMIT     bound of the law's current and of each resonant coefficient (A)
    E_LP      state: low-passed position error (rad)
    A1        state: resonant coefficients of sin/cos h x, h = 1, 2, 4 (A)
    B1
    A2
    B2
    A4
    B4
    SUM_I2    sum over periods of the law's current squared (A^2), zeroed by the caller
    RESONANT  1.0 while a resonant gain or coefficient is non-zero (set at each call)
""")

# ---------------------------------------------------------------------------
# Trace channels: one row per recorded PWM period.
# ---------------------------------------------------------------------------
TRACE = layout("Trace", """
    T           s
    THETA       rad
    OMEGA       rad/s
    THETA_CMD   rad
    OMEGA_CMD   rad/s
    IA          A
    IB          A
    VA          V, winding voltages applied during the period
    VB          V
    ID          A
    IQ          A
    IQ_CMD      A
    IQ_FF       A
    THETA_FB    rad
    OMEGA_FB    rad/s
""")
TRACE_NAMES = tuple(name.lower() for name in TRACE._fields)
#: SI unit of each trace channel.
TRACE_UNITS = {name.lower(): text.split(",")[0] for name, text in describe(TRACE).items()}

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
    th, w, ia, ib = x[0], x[1], x[2], x[3]
    nr = p[PLANT.NR]
    hh = 0.5 * h
    x0 = nr * th
    s0, c0 = sincos(x0)
    k1 = motor_derivative_sc(s0, c0, w, ia, ib, va, vb, p)
    s2, c2 = sincos_shifted(x0, s0, c0, nr * hh * k1[0])
    k2 = motor_derivative_sc(s2, c2, w + hh * k1[1], ia + hh * k1[2], ib + hh * k1[3],
                             va, vb, p)
    s3, c3 = sincos_shifted(x0, s0, c0, nr * hh * k2[0])
    k3 = motor_derivative_sc(s3, c3, w + hh * k2[1], ia + hh * k2[2], ib + hh * k2[3],
                             va, vb, p)
    s4, c4 = sincos_shifted(x0, s0, c0, nr * h * k3[0])
    k4 = motor_derivative_sc(s4, c4, w + h * k3[1], ia + h * k3[2], ib + h * k3[3],
                             va, vb, p)
    return rk4_combine(x, k1, k2, k3, k4, h)


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
    w = x[1]
    if abs(w) < w_stick and abs(driving_torque(x[0], 0.0, x[2], x[3], p)) <= p[PLANT.FS]:
        return rk4_step_stuck(x, va, vb, p, h)
    return rk4_step(x, va, vb, p, h)


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


_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_TWO_M53 = 1.0 / 9007199254740992.0


@_jit_inline
def splitmix64(x):
    """SplitMix64 finaliser: a well-mixed 64-bit hash of ``x`` (uint64)."""
    z = x + _GOLDEN
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    return z ^ (z >> np.uint64(31))


@_jit_inline
def uniform_pair(seed, counter):
    """Two uniform samples for (seed, counter): u1 in (0, 1], u2 in [0, 1)."""
    key = splitmix64(np.uint64(seed))
    c2 = np.uint64(counter) * np.uint64(2)
    u1 = (float(splitmix64(key ^ c2) >> np.uint64(11)) + 1.0) * _TWO_M53
    u2 = float(splitmix64(key ^ (c2 + np.uint64(1))) >> np.uint64(11)) * _TWO_M53
    return u1, u2


@_jit
def gaussian_pair(seed, counter):
    """Two independent standard normal samples for (seed, counter).

    Counter-based (Box-Muller on hashed counters, :func:`uniform_pair`): the noise
    of PWM period k is a function of k alone, so it does not depend on how a run
    is chunked.
    """
    u1, u2 = uniform_pair(seed, counter)
    r = math.sqrt(-2.0 * log(u1))
    s, c = sincos(2.0 * math.pi * u2)
    return r * c, r * s


@_jit_inline
def quantise(x, q):
    """x rounded down to a whole number of steps of size q (encoder, microstep)."""
    return math.floor(x * (1.0 / q)) * q


@_jit_inline
def constant_speed_command(t, speed, accel):
    """Position (rad) and speed (rad/s) at time t (s) of :func:`command`'s kind 0:
    from rest with acceleration ``accel`` up to ``speed`` (signed), then held."""
    a = accel
    sgn = 1.0 if speed >= 0.0 else -1.0
    t_ramp = abs(speed) / a
    if t < t_ramp:
        return sgn * 0.5 * a * t * t, sgn * a * t
    return sgn * 0.5 * a * t_ramp * t_ramp + speed * (t - t_ramp), speed


@_jit_inline
def move_command(t, speed, accel, distance):
    """Position (rad) and speed (rad/s) at time t (s) of :func:`command`'s kind 1:
    a trapezoidal (or triangular) move of ``distance`` (signed) at up to |speed|."""
    a = accel
    sgn = 1.0 if distance >= 0.0 else -1.0
    d = abs(distance)
    vmax = abs(speed)
    t_acc = vmax / a
    if a * t_acc * t_acc > d:      # triangular: never reaches vmax
        t_acc = math.sqrt(d / a)
        vmax = a * t_acc
    d_acc = 0.5 * a * t_acc * t_acc
    t_flat = (d - 2.0 * d_acc) / vmax if vmax > 0.0 else 0.0
    if t < t_acc:
        return sgn * 0.5 * a * t * t, sgn * a * t
    if t < t_acc + t_flat:
        return sgn * (d_acc + vmax * (t - t_acc)), sgn * vmax
    td = t - t_acc - t_flat
    if td < t_acc:
        return sgn * (d - d_acc + vmax * td - 0.5 * a * td * td), sgn * (vmax - a * td)
    return sgn * d, 0.0


@_jit_inline
def command(t, kind, speed, accel, distance):
    """Position (rad) and speed (rad/s) command at time t (s).

    kind 0: from rest with acceleration ``accel`` up to ``speed`` (signed), then held.
    kind 1: trapezoidal (or triangular) move of ``distance`` (signed) at up to |speed|.
    """
    if kind == PROFILE.CONSTANT:
        return constant_speed_command(t, speed, accel)
    return move_command(t, speed, accel, distance)


@_jit
def controller_params(c):
    """The controller's constants as a tuple, the form :func:`control_step` takes.

    Positions are the ``Q_*`` names: (dt, Nr, holding current, microstep angle,
    Kp_i, Ki_i, encoder angle, velocity filter alpha, Kp_vel, Kp_pos, Ki_pos,
    mode, ff_on, Km_est, Fs_est, ff s1, c1, s2, c2, s4, c4, Vdc, profile kind,
    speed, accel, distance, current noise, offset a, offset b, noise seed,
    velocity estimator, Kalman k0, k1, back-EMF G1, G2, drive mode, R and L of
    the voltage mode's winding model).
    """
    return (c[CONFIG.DT], c[CONFIG.NR], c[CONFIG.HOLD], c[CONFIG.MICROSTEP], c[CONFIG.KP_I], c[CONFIG.KI_I],
            c[CONFIG.ENCODER], c[CONFIG.VEL_ALPHA], c[CONFIG.KP_VEL], c[CONFIG.KP_POS], c[CONFIG.KI_POS],
            c[CONFIG.MODE], c[CONFIG.BASE_CONTROLLER], c[CONFIG.KM_EST], c[CONFIG.FS_EST],
            c[CONFIG.FF_S1], c[CONFIG.FF_C1], c[CONFIG.FF_S2], c[CONFIG.FF_C2], c[CONFIG.FF_S4], c[CONFIG.FF_C4],
            c[CONFIG.VDC], c[CONFIG.PROFILE], c[CONFIG.SPEED], c[CONFIG.ACCEL], c[CONFIG.DISTANCE],
            c[CONFIG.I_NOISE], c[CONFIG.I_OFFSET_A], c[CONFIG.I_OFFSET_B], c[CONFIG.NOISE_SEED], c[CONFIG.VEL_EST],
            c[CONFIG.KF_K0], c[CONFIG.KF_K1], c[CONFIG.BEMF_G1], c[CONFIG.BEMF_G2], c[CONFIG.DRIVE_MODE],
            c[CONFIG.R_EST], c[CONFIG.L_EST])


@_jit_inline
def feedforward_torque(sin_x, cos_x, q, u):
    """Detent compensation torque (N*m) at the angle whose sin and cos are given.

    The base model (eq. 8 / eq. 15 harmonics, scaled by ff_on) plus the
    external coefficient corrections in ``u`` (see ``U_*``).
    """
    on = q[CTRL.BASE_CONTROLLER]
    return harmonic_series(sin_x, cos_x,
                           on * q[CTRL.FF_S1] + u[INPUT.DS1], on * q[CTRL.FF_C1] + u[INPUT.DC1],
                           on * q[CTRL.FF_S2] + u[INPUT.DS2], on * q[CTRL.FF_C2] + u[INPUT.DC2],
                           on * q[CTRL.FF_S4] + u[INPUT.DS4], on * q[CTRL.FF_C4] + u[INPUT.DC4])


@_jit_inline
def sense_currents(period, ia, ib, q):
    """The current sensors' readings (A) of the true ``ia``, ``ib``: offset and,
    if set, noise drawn for ``period``."""
    if q[CTRL.I_NOISE] != 0.0:
        noise_a, noise_b = gaussian_pair(q[CTRL.NOISE_SEED], period)
        return (ia + q[CTRL.I_OFFSET_A] + q[CTRL.I_NOISE] * noise_a,
                ib + q[CTRL.I_OFFSET_B] + q[CTRL.I_NOISE] * noise_b)
    return ia + q[CTRL.I_OFFSET_A], ib + q[CTRL.I_OFFSET_B]


@_jit_inline
def estimate_velocity(theta_fb, theta_fb_prev, omega_fb, theta_est, ia, ib, ia_prev, ib_prev,
                      va_old, vb_old, theta_cmd, omega_cmd, q):
    """The drive's velocity estimate (rad/s) by ``q[CTRL.VEL_EST]``; returns
    (omega_fb, theta_est), the Kalman filter's angle (rad) unchanged by the others."""
    dt, nr = q[CTRL.DT], q[CTRL.NR]
    if q[CTRL.VEL_EST] == VEL_EST.BACK_EMF:
        # No encoder for the speed: the back-EMF over the period that just
        # ended, from its applied voltage and the measured currents at both
        # ends, projected on the electrical angle at the period's middle (open
        # loop: the command's, which the rotor trails by its load angle) and
        # low-passed like the encoder's difference.
        ea = va_old - q[CTRL.BEMF_G1] * ia + q[CTRL.BEMF_G2] * ia_prev
        eb = vb_old - q[CTRL.BEMF_G1] * ib + q[CTRL.BEMF_G2] * ib_prev
        if q[CTRL.MODE] == MODE.OPEN_LOOP:
            x_mid = nr * (theta_cmd - 0.5 * dt * omega_cmd)
        else:
            x_mid = nr * (theta_fb + 0.5 * q[CTRL.ENCODER])
        s_p, c_p = sincos(x_mid)
        w_raw = (c_p * eb - s_p * ea) * (1.0 / q[CTRL.KM_EST])
        return omega_fb + q[CTRL.VEL_ALPHA] * (w_raw - omega_fb), theta_est
    if q[CTRL.VEL_EST] == VEL_EST.KALMAN:
        # Steady-state Kalman filter, constant-velocity model, measuring the
        # centre of the encoder count.
        predicted = theta_est + dt * omega_fb
        innovation = theta_fb + 0.5 * q[CTRL.ENCODER] - predicted
        return (omega_fb + q[CTRL.KF_K1] * innovation,
                predicted + q[CTRL.KF_K0] * innovation)
    return (omega_fb + q[CTRL.VEL_ALPHA] * ((theta_fb - theta_fb_prev) * (1.0 / dt) - omega_fb),
            theta_est)


@_jit_inline
def current_command(theta_fb, omega_fb, pos_int, theta_cmd, omega_cmd, q, u):
    """The mode's current command: returns (pos_int, Park angle (rad), its sine
    and cosine, id_cmd, iq_cmd, iq_injected (A))."""
    nr, dt = q[CTRL.NR], q[CTRL.DT]
    if q[CTRL.MODE] == MODE.OPEN_LOOP:
        # Eqs. 7-8: Park angle and feedforward at the microstep-quantised command.
        angle = nr * quantise(theta_cmd, q[CTRL.MICROSTEP])
        sin_a, cos_a = sincos(angle)
        iq_inj = feedforward_torque(sin_a, cos_a, q, u) * (1.0 / q[CTRL.KM_EST]) + u[INPUT.IQ]
        return pos_int, angle, sin_a, cos_a, q[CTRL.HOLD], iq_inj, iq_inj
    # Eqs. 14-15 at the encoder angle, taken at the centre of its count (a
    # floored count lags by half a count on average); Fs is fed forward
    # with the command's sign.
    theta_meas = theta_fb + 0.5 * q[CTRL.ENCODER]
    angle = nr * theta_meas
    sin_a, cos_a = sincos(angle)
    theta_err = theta_cmd - theta_meas
    pos_int = pos_int + theta_err * dt
    fs_ff = 0.0
    if omega_cmd > 0.0:
        fs_ff = q[CTRL.FS_EST]
    elif omega_cmd < 0.0:
        fs_ff = -q[CTRL.FS_EST]
    iq_inj = ((feedforward_torque(sin_a, cos_a, q, u) + q[CTRL.BASE_CONTROLLER] * fs_ff)
              * (1.0 / q[CTRL.KM_EST]) + u[INPUT.IQ])
    tau_fb = (q[CTRL.KP_VEL] * (omega_cmd - omega_fb) + q[CTRL.KP_POS] * theta_err
              + q[CTRL.KI_POS] * pos_int)
    return pos_int, angle, sin_a, cos_a, 0.0, tau_fb * (1.0 / q[CTRL.KM_EST]) + iq_inj, iq_inj


@_jit_inline
def voltage_drive(angle, sin_a, cos_a, id_cmd, iq_cmd, omega_cmd, q):
    """Voltage mode: no current feedback; the winding voltages (va, vb in V) for
    the commanded currents.

    The steady-state winding voltages in the frame of the angle at the command's
    electrical speed, the back-EMF estimated from the command speed (docs/model.md,
    "Voltage-mode drive"). They are applied during the next period, so the
    inverse Park turns them to that period's middle, 1.5 periods on.
    """
    w_e = q[CTRL.NR] * omega_cmd
    r_est, l_est = q[CTRL.R_EST], q[CTRL.L_EST]
    vd = r_est * id_cmd - w_e * l_est * iq_cmd
    vq = r_est * iq_cmd + w_e * l_est * id_cmd + q[CTRL.KM_EST] * omega_cmd
    sin_v, cos_v = sincos_shifted(angle, sin_a, cos_a, 1.5 * q[CTRL.DT] * w_e)
    va_dem, vb_dem = inverse_park_sc(vd, vq, sin_v, cos_v)
    v_alpha, v_beta, v_gamma = svpwm_legs(va_dem, vb_dem, q[CTRL.VDC])
    return v_alpha - v_gamma, v_beta - v_gamma


@_jit_inline
def current_loop(int_d, int_q, id_cmd, iq_cmd, id_m, iq_m, sin_a, cos_a, q):
    """The DQ current PI loops, inverse Park and SVPWM, all at one sine and cosine;
    returns (int_d, int_q, va, vb in V)."""
    kp, ki, dt = q[CTRL.KP_I], q[CTRL.KI_I], q[CTRL.DT]
    err_d = id_cmd - id_m
    err_q = iq_cmd - iq_m
    vd = pi_output(err_d, int_d, kp)
    vq = pi_output(err_q, int_q, kp)
    va_dem, vb_dem = inverse_park_sc(vd, vq, sin_a, cos_a)
    v_alpha, v_beta, v_gamma = svpwm_legs(va_dem, vb_dem, q[CTRL.VDC])
    va = v_alpha - v_gamma
    vb = v_beta - v_gamma
    vd_app, vq_app = park_sc(va, vb, sin_a, cos_a)
    return (pi_update(err_d, int_d, vd, vd_app, kp, ki, dt),
            pi_update(err_q, int_q, vq, vq_app, kp, ki, dt), va, vb)


@_jit_inline
def control_step(period, theta, ia, ib, cs, q, u):
    """The controller of PWM period ``period`` (a count): a pure function, one
    job per piece: the command, the sensors (:func:`sense_currents`), the
    velocity estimate (:func:`estimate_velocity`), the mode's current command
    (:func:`current_command`) and the drive (:func:`current_loop`, or
    :func:`voltage_drive`).

    ``theta``, ``ia``, ``ib`` are the true shaft angle and winding currents;
    ``cs`` = (integrator d, integrator q, previous encoder angle, velocity
    estimate, position-error integral, Kalman angle estimate, previous measured
    ia, ib, voltages va, vb applied during the period that just ended) is the
    controller's state (the caller sets the last two);
    ``q`` is :func:`controller_params`, ``u`` the external inputs.

    Returns (new cs, (va, vb) winding voltages to apply next period,
    (theta_fb, theta_cmd, omega_cmd, id, iq, iq_cmd, iq_injected, angle, sin angle,
    cos angle)).
    """
    int_d, int_q, theta_fb_prev, omega_fb, pos_int, theta_est, ia_prev, ib_prev, va_old, \
        vb_old = cs
    t = period * q[CTRL.DT]
    theta_cmd, omega_cmd = command(t, q[CTRL.PROFILE], q[CTRL.SPEED], q[CTRL.ACCEL], q[CTRL.DISTANCE])
    # Velocity estimate from the encoder (a drive senses it in either mode).
    theta_fb = quantise(theta, q[CTRL.ENCODER])
    ia, ib = sense_currents(period, ia, ib, q)
    omega_fb, theta_est = estimate_velocity(theta_fb, theta_fb_prev, omega_fb, theta_est, ia, ib,
                                            ia_prev, ib_prev, va_old, vb_old, theta_cmd,
                                            omega_cmd, q)
    pos_int, angle, sin_a, cos_a, id_cmd, iq_cmd, iq_inj = current_command(
        theta_fb, omega_fb, pos_int, theta_cmd, omega_cmd, q, u)
    id_m, iq_m = park_sc(ia, ib, sin_a, cos_a)
    if q[CTRL.DRIVE_MODE] == DRIVE.VOLTAGE:
        va, vb = voltage_drive(angle, sin_a, cos_a, id_cmd, iq_cmd, omega_cmd, q)
    else:
        int_d, int_q, va, vb = current_loop(int_d, int_q, id_cmd, iq_cmd, id_m, iq_m, sin_a,
                                            cos_a, q)
    return ((int_d, int_q, theta_fb, omega_fb, pos_int, theta_est, ia, ib, va_old, vb_old),
            (va, vb),
            (theta_fb, theta_cmd, omega_cmd, id_m, iq_m, iq_cmd, iq_inj, angle, sin_a, cos_a))


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
            row[TRACE.T] = t
            row[TRACE.THETA] = x[0]
            row[TRACE.OMEGA] = x[1]
            row[TRACE.THETA_CMD] = obs[1]
            row[TRACE.OMEGA_CMD] = obs[2]
            row[TRACE.IA] = x[2]
            row[TRACE.IB] = x[3]
            row[TRACE.VA] = va
            row[TRACE.VB] = vb
            row[TRACE.ID] = obs[3]
            row[TRACE.IQ] = obs[4]
            row[TRACE.IQ_CMD] = obs[5]
            row[TRACE.IQ_FF] = obs[6]
            row[TRACE.THETA_FB] = obs[0]
            row[TRACE.OMEGA_FB] = cs[3]
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
def run_batch(configs, states, accs, inputs, n_periods):
    """Advance N drives (rows of the arrays) by ``n_periods`` each, without trace."""
    empty = np.zeros((0, len(TRACE)))
    # int64 as from Python: a literal 1 would compile the whole loop once more for its type.
    every = np.int64(1)
    for i in range(configs.shape[0]):
        run_periods(configs[i], states[i], accs[i], inputs[i], n_periods, empty, every)


@_jit
def run_batch_law(configs, states, accs, inputs, laws, n_periods):
    """:func:`run_batch` with each drive's damping law (rows of ``laws``)."""
    empty = np.zeros((0, len(TRACE)))
    every = np.int64(1)
    for i in range(configs.shape[0]):
        _advance(configs[i], states[i], accs[i], inputs[i], laws[i], n_periods, empty, every)


# Parallel twins: the drives of a batch on numba's threads (numba.set_num_threads
# in the calling thread). Each drive's arithmetic is the serial loop's, in its own
# row, so the results do not depend on the number of threads.
_jit_parallel = njit(cache=True, error_model="numpy", parallel=True)


@_jit_parallel
def run_batch_parallel(configs, states, accs, inputs, n_periods):
    """:func:`run_batch`, the drives spread over numba's threads."""
    empty = np.zeros((0, len(TRACE)))
    every = np.int64(1)
    for i in prange(configs.shape[0]):
        run_periods(configs[i], states[i], accs[i], inputs[i], n_periods, empty, every)


@_jit_parallel
def run_batch_law_parallel(configs, states, accs, inputs, laws, n_periods):
    """:func:`run_batch_law`, the drives spread over numba's threads."""
    empty = np.zeros((0, len(TRACE)))
    every = np.int64(1)
    for i in prange(configs.shape[0]):
        run_periods_law(configs[i], states[i], accs[i], inputs[i], laws[i], n_periods, empty,
                        every)


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
