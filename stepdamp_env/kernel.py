"""Numba kernel of the drive: small njit pieces composed into one fused loop.

Everything here is a pure function of plain floats or of flat float64 arrays, so
each piece can be called and tested from Python and the fused loop
(:func:`run_periods`) can advance one drive or a batch (:func:`run_batch`) without
leaving compiled code. Layouts of the arrays are the ``C_*`` (configuration,
never changed by a step), ``S_*`` (state, changed by every step), ``A_*``
(accumulated metrics), ``U_*`` (external inputs held for a call) and ``T_*``
(trace channels) indices below; :mod:`stepdamp_env.simulation` builds them.

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
from numba import njit

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
C_R = 0            # winding resistance (Ohm)
C_L = 1            # winding inductance (H)
C_KM = 2           # torque constant of the plant (N*m/A)
C_NR = 3           # rotor teeth
C_J = 4            # inertia (kg*m^2)
C_D = 5            # viscous damping (N*m*s/rad)
C_DET_S1 = 6       # plant detent as sin/cos coefficients (N*m), see detent_torque
C_DET_C1 = 7
C_DET_S2 = 8
C_DET_C2 = 9
C_DET_S4 = 10
C_DET_C4 = 11
C_FS = 12          # Coulomb/breakaway friction (N*m)
C_LOAD = 13        # constant load torque (N*m)
C_VDC = 14         # bus voltage (V)
C_DT = 15          # PWM period (s)
C_HOLD = 16        # open-loop holding current (A)
C_MICROSTEP = 17   # shaft angle of one microstep (rad)
C_KP_I = 18        # current PI proportional gain (V/A)
C_KI_I = 19        # current PI integral gain (V/(A*s))
C_ENCODER = 20     # shaft angle of one encoder count (rad)
C_VEL_ALPHA = 21   # velocity low-pass coefficient per period, 1 - exp(-2*pi*fc*dt)
C_KP_VEL = 22      # servo velocity gain (N*m*s/rad)
C_KP_POS = 23      # servo position gain (N*m/rad)
C_KI_POS = 24      # servo position integral gain (N*m/(rad*s))
C_MODE = 25        # 0 open loop, 1 servo
C_FF_ON = 26       # 1 if the base harmonic feedforward is on ("patent-ff")
C_KM_EST = 27      # controller's estimate of Km (N*m/A)
C_FS_EST = 28      # controller's estimate of Fs (N*m), servo feedforward
C_FF_S1 = 29       # controller's detent estimate as sin/cos coefficients (N*m)
C_FF_C1 = 30
C_FF_S2 = 31
C_FF_C2 = 32
C_FF_S4 = 33
C_FF_C4 = 34
C_SUBSTEPS = 35    # RK4 steps per PWM period
C_W_STICK = 36     # stiction velocity band (rad/s)
C_PROFILE = 37     # 0 constant speed after a ramp, 1 point-to-point move
C_SPEED = 38       # command speed (rad/s, signed)
C_ACCEL = 39       # command acceleration (rad/s^2, > 0)
C_DISTANCE = 40    # move distance (rad, signed), profile 1 only
C_WINDOW_START = 41  # metrics window start (s)
C_REF_SPEED = 42   # speed whose harmonics the metrics lock on to (rad/s)
C_I_NOISE = 43     # current-sensor noise, standard deviation per sample (A)
C_I_OFFSET_A = 44  # current-sensor offsets of phases A and B (A)
C_I_OFFSET_B = 45
C_NOISE_SEED = 46  # seed of the sensor noise (an integer below 2**53)
C_VEL_EST = 47     # velocity estimator: 0 encoder difference + low-pass, 1 Kalman filter,
                   # 2 back-EMF observer (no encoder)
C_KF_K0 = 48       # steady-state Kalman gains on the encoder innovation
C_KF_K1 = 49       # (position: dimensionless, velocity: 1/s)
C_BEMF_G1 = 50     # back-EMF observer: e = v - G1*i_k + G2*i_(k-1) (Ohm), the exact
C_BEMF_G2 = 51     # one-period winding solution, G1 = R/(1-a), G2 = R*a/(1-a), a = exp(-R*dt/L)
C_DRIVE_MODE = 52  # DRIVE_CURRENT (DQ PI loops) or DRIVE_VOLTAGE (winding-model voltages)
C_R_EST = 53       # the voltage-mode drive's model of the winding: resistance (Ohm)
C_L_EST = 54       # and inductance (H)
N_CONFIG = 55

DRIVE_CURRENT = 0
DRIVE_VOLTAGE = 1

VEL_EST_LOWPASS = 0
VEL_EST_KALMAN = 1
VEL_EST_BACK_EMF = 2

MODE_OPEN_LOOP = 0
MODE_SERVO = 1
PROFILE_CONSTANT = 0
PROFILE_MOVE = 1

# ---------------------------------------------------------------------------
# Positions in the tuple of plant_params (per drive, float64). The kernel reads
# it by these names; numba folds module-level ints to constants, so a named
# read compiles exactly like a literal index.
# ---------------------------------------------------------------------------
P_R = 0            # winding resistance (Ohm)
P_INV_L = 1        # inverse winding inductance (1/H)
P_KM = 2           # torque constant (N*m/A)
P_NR = 3           # rotor teeth (electrical angle per shaft angle)
P_INV_J = 4        # inverse inertia (1/(kg*m^2))
P_D = 5            # viscous damping (N*m*s/rad)
P_DET_S1 = 6       # detent as sin/cos coefficients of harmonics 1, 2, 4 (N*m)
P_DET_C1 = 7
P_DET_S2 = 8
P_DET_C2 = 9
P_DET_S4 = 10
P_DET_C4 = 11
P_FS = 12          # Coulomb/breakaway friction (N*m)
P_LOAD = 13        # constant load torque (N*m)

# ---------------------------------------------------------------------------
# Positions in the tuple of controller_params (per drive, float64).
# ---------------------------------------------------------------------------
Q_DT = 0           # PWM period (s)
Q_NR = 1           # rotor teeth (electrical angle per shaft angle)
Q_HOLD = 2         # open-loop holding current (A)
Q_MICROSTEP = 3    # shaft angle of one microstep (rad)
Q_KP_I = 4         # current PI proportional gain (V/A)
Q_KI_I = 5         # current PI integral gain (V/(A*s))
Q_ENCODER = 6      # shaft angle of one encoder count (rad)
Q_VEL_ALPHA = 7    # velocity low-pass coefficient per period (dimensionless)
Q_KP_VEL = 8       # servo velocity gain (N*m*s/rad)
Q_KP_POS = 9       # servo position gain (N*m/rad)
Q_KI_POS = 10      # servo position integral gain (N*m/(rad*s))
Q_MODE = 11        # MODE_OPEN_LOOP or MODE_SERVO
Q_FF_ON = 12       # 1.0 if the base harmonic feedforward is on, else 0.0
Q_KM_EST = 13      # controller's estimate of Km (N*m/A)
Q_FS_EST = 14      # controller's estimate of Fs (N*m)
Q_FF_S1 = 15       # controller's detent estimate, sin/cos coefficients (N*m)
Q_FF_C1 = 16
Q_FF_S2 = 17
Q_FF_C2 = 18
Q_FF_S4 = 19
Q_FF_C4 = 20
Q_VDC = 21         # bus voltage (V)
Q_PROFILE = 22     # PROFILE_CONSTANT or PROFILE_MOVE
Q_SPEED = 23       # command speed (rad/s, signed)
Q_ACCEL = 24       # command acceleration (rad/s^2)
Q_DISTANCE = 25    # move distance (rad, signed)
Q_I_NOISE = 26     # current-sensor noise, standard deviation per sample (A)
Q_I_OFFSET_A = 27  # current-sensor offsets of phases A and B (A)
Q_I_OFFSET_B = 28
Q_NOISE_SEED = 29  # seed of the sensor noise (integer-valued)
Q_VEL_EST = 30     # VEL_EST_LOWPASS or VEL_EST_KALMAN
Q_KF_K0 = 31       # Kalman gain on the innovation, position (dimensionless)
Q_KF_K1 = 32       # Kalman gain on the innovation, velocity (1/s)
Q_BEMF_G1 = 33     # back-EMF observer constants (Ohm), see C_BEMF_G1
Q_BEMF_G2 = 34
Q_DRIVE_MODE = 35  # DRIVE_CURRENT or DRIVE_VOLTAGE
Q_R_EST = 36       # voltage mode's winding model: resistance (Ohm), inductance (H)
Q_L_EST = 37

# ---------------------------------------------------------------------------
# State vector (per drive, float64).
# ---------------------------------------------------------------------------
S_PERIOD = 0       # PWM periods done (exact integer in a float64)
S_THETA = 1        # shaft angle (rad)
S_OMEGA = 2        # shaft speed (rad/s)
S_IA = 3           # phase A current (A)
S_IB = 4           # phase B current (A)
S_E_IN = 5         # energy supplied to the windings (J)
S_E_CU = 6         # copper loss (J)
S_E_DAMP = 7       # viscous loss (J)
S_E_FRIC = 8       # friction loss (J)
S_E_LOAD = 9       # work done on the load torque (J)
S_INT_D = 10       # d-axis PI integrator (V)
S_INT_Q = 11       # q-axis PI integrator (V)
S_VA_NEXT = 12     # winding voltages computed this period, applied next (V)
S_VB_NEXT = 13
S_THETA_FB_PREV = 14  # previous encoder angle (rad)
S_OMEGA_FB = 15    # filtered velocity estimate (rad/s)
S_POS_INT = 16     # servo integral of the position error (rad*s)
S_THETA_FB = 17    # last encoder angle (rad)
S_THETA_CMD = 18   # last command angle (rad)
S_OMEGA_CMD = 19   # last command speed (rad/s)
S_ID_MEAS = 20     # last measured d/q currents in the Park frame (A)
S_IQ_MEAS = 21
S_IQ_FF = 22       # last injected feedforward + residual q current (A)
S_PARK_ANGLE = 23  # last Park (electrical) angle (rad)
S_THETA_EST = 24   # Kalman estimate of the shaft angle (rad)
S_IA_PREV = 25     # measured phase currents of the previous sample (A), back-EMF observer
S_IB_PREV = 26
S_VA_OLD = 27      # winding voltages applied during the period that just ended (V)
S_VB_OLD = 28
N_STATE = 29

# ---------------------------------------------------------------------------
# Accumulated metrics (per drive). Window sums use samples with t >= window start.
# ---------------------------------------------------------------------------
A_COUNT = 0        # samples in the window
A_SUM_E = 1        # sum of velocity error w_cmd - w (rad/s)
A_SUM_E2 = 2       # sum of its square
A_MIN_E = 3
A_MAX_E = 4
A_SUM_IFF2 = 5     # sum of the squared injected q current (A^2)
A_H1_S = 6         # lock-in sums of the error against h*Nr*theta_ref, h = 1, 2, 4
A_H1_C = 7
A_H2_S = 8
A_H2_C = 9
A_H4_S = 10
A_H4_C = 11
A_MAX_LAG = 12     # max |theta_cmd - theta| over all samples (rad)
A_MAX_CURRENT = 13  # max |i| of either phase over all samples (A)
A_SUM_E2_ALL = 14  # sum of squared velocity error over all samples
A_COUNT_ALL = 15
A_SUM_IFF2_ALL = 16
N_ACC = 17

# ---------------------------------------------------------------------------
# External inputs held for one call (per drive): residual policy actions.
# ---------------------------------------------------------------------------
U_DS1 = 0          # corrections to the feedforward coefficients (N*m)
U_DC1 = 1
U_DS2 = 2
U_DC2 = 3
U_DS4 = 4
U_DC4 = 5
U_IQ = 6           # residual q current (A)
N_INPUT = 7

# ---------------------------------------------------------------------------
# Damping law (per drive, float64), evaluated every PWM period by
# :func:`run_periods_law`: gains (set between calls), then its own state.
# iq_law = clip(KV*e_w + KP*hp(e_theta) + sum_h a_h sin(h x) + b_h cos(h x), +-limit),
# e_w = w_cmd - w_fb, e_theta = theta_cmd - theta_fb (the drive's own samples),
# hp a first-order high-pass (removes the static lag), x the Park angle; the
# resonant phasor a_h + j b_h integrates (KR_h + j KI_h) times the velocity
# error demodulated at h*x (sin + j cos), clamped to +-limit.
# ---------------------------------------------------------------------------
L_KV = 0           # velocity gain (A per rad/s)
L_KP = 1           # high-passed position gain (A per rad): with L_KV, a phase lead
L_KR1 = 2          # resonant gains, real and imaginary, h = 1, 2, 4 (A/s per rad/s)
L_KI1 = 3
L_KR2 = 4
L_KI2 = 5
L_KR4 = 6
L_KI4 = 7
L_HP_ALPHA = 8     # high-pass coefficient per period, 1 - exp(-2*pi*fc*dt)
L_LIMIT = 9        # bound of the law's current and of each resonant coefficient (A)
L_E_LP = 10        # state: low-passed position error (rad)
L_A1 = 11          # state: resonant coefficients of sin/cos h x, h = 1, 2, 4 (A)
L_B1 = 12
L_A2 = 13
L_B2 = 14
L_A4 = 15
L_B4 = 16
L_SUM_I2 = 17      # sum over periods of the law's current squared (A^2), zeroed by the caller
L_RESONANT = 18    # 1.0 while a resonant gain or coefficient is non-zero (set at each call)
N_LAW = 19
N_LAW_GAINS = 8    # L_KV .. L_KI4: what an agent sets

# ---------------------------------------------------------------------------
# Trace channels: one row per recorded PWM period.
# ---------------------------------------------------------------------------
T_T = 0
T_THETA = 1
T_OMEGA = 2
T_THETA_CMD = 3
T_OMEGA_CMD = 4
T_IA = 5
T_IB = 6
T_VA = 7           # winding voltages applied during the period (V)
T_VB = 8
T_ID = 9
T_IQ = 10
T_IQ_CMD = 11
T_IQ_FF = 12
T_THETA_FB = 13
T_OMEGA_FB = 14
N_TRACE = 15
TRACE_NAMES = ("t", "theta", "omega", "theta_cmd", "omega_cmd", "ia", "ib", "va",
               "vb", "id", "iq", "iq_cmd", "iq_ff", "theta_fb", "omega_fb")
#: SI unit of each trace channel.
TRACE_UNITS = {"t": "s", "theta": "rad", "omega": "rad/s", "theta_cmd": "rad",
               "omega_cmd": "rad/s", "ia": "A", "ib": "A", "va": "V", "vb": "V", "id": "A",
               "iq": "A", "iq_cmd": "A", "iq_ff": "A", "theta_fb": "rad", "omega_fb": "rad/s"}


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
    return (c[C_R], 1.0 / c[C_L], c[C_KM], c[C_NR], 1.0 / c[C_J], c[C_D],
            c[C_DET_S1], c[C_DET_C1], c[C_DET_S2], c[C_DET_C2], c[C_DET_S4], c[C_DET_C4],
            c[C_FS], c[C_LOAD])


@_jit
def detent_torque(theta, p):
    """Detent torque (N*m): -Kd4 sin 4x - Kd2 sin(2x + phi2) - Kd1 sin(x + phi1), x = Nr*theta."""
    s1, c1 = sincos(p[P_NR] * theta)
    return -harmonic_series(s1, c1, p[P_DET_S1], p[P_DET_C1], p[P_DET_S2], p[P_DET_C2],
                            p[P_DET_S4], p[P_DET_C4])


@_jit
def detent_potential(theta, p):
    """Potential energy V(theta) (J) of the detent torque: torque = -dV/dtheta."""
    nr = p[P_NR]
    s1, c1 = sincos(nr * theta)
    s2, c2, s4, c4 = harmonics(s1, c1)
    # a sin hx + b cos hx integrates over theta to -(a cos hx - b sin hx)/(h Nr).
    return -((p[P_DET_S1] * c1 - p[P_DET_C1] * s1) / nr
             + (p[P_DET_S2] * c2 - p[P_DET_C2] * s2) / (2.0 * nr)
             + (p[P_DET_S4] * c4 - p[P_DET_C4] * s4) / (4.0 * nr))


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
    s1, c1 = sincos(p[P_NR] * theta)
    det = harmonic_series(s1, c1, p[P_DET_S1], p[P_DET_C1], p[P_DET_S2], p[P_DET_C2],
                          p[P_DET_S4], p[P_DET_C4])
    return (electromagnetic_torque(ia, ib, s1, c1, p[P_KM]) - det - p[P_D] * omega
            - p[P_LOAD])


@_jit_inline
def motor_derivative_sc(sin_x, cos_x, omega, ia, ib, va, vb, p):
    """:func:`motor_derivative` given sin and cos of x = Nr*theta."""
    r, inv_l, km, d = p[P_R], p[P_INV_L], p[P_KM], p[P_D]
    tau_det = harmonic_series(sin_x, cos_x, p[P_DET_S1], p[P_DET_C1], p[P_DET_S2],
                              p[P_DET_C2], p[P_DET_S4], p[P_DET_C4])
    tau_drive = (electromagnetic_torque(ia, ib, sin_x, cos_x, km) - tau_det - d * omega
                 - p[P_LOAD])
    fric = friction_torque(omega, tau_drive, p[P_FS])
    # Back-EMF ea = -Km w sin x, eb = Km w cos x (eq. 2 with the cosine).
    dia = (va - r * ia + km * omega * sin_x) * inv_l
    dib = (vb - r * ib - km * omega * cos_x) * inv_l
    return (omega, (tau_drive - fric) * p[P_INV_J], dia, dib,
            va * ia + vb * ib, r * (ia * ia + ib * ib), d * omega * omega,
            fric * omega, p[P_LOAD] * omega)


@_jit
def motor_derivative(theta, omega, ia, ib, va, vb, p):
    """Right-hand side of the plant (docs/model.md, "The plant").

    ``p`` is :func:`plant_params`. Returns (dtheta, domega, dia, dib, p_in,
    p_cu, p_damp, p_fric, p_load): the state derivatives and the powers (W)
    supplied to the windings, lost in copper, in viscous damping, in friction
    and delivered to the load torque.
    """
    s1, c1 = sincos(p[P_NR] * theta)
    return motor_derivative_sc(s1, c1, omega, ia, ib, va, vb, p)


@_jit_inline
def rk4_step(x, va, vb, p, h):
    """RK4 step of ``h`` s of the plant state plus energy accumulators.

    ``x`` = (theta, omega, ia, ib, E_in, E_cu, E_damp, E_fric, E_load); the
    energies (J) are integrated with the same stages, so the balance closes to
    the integrator's accuracy. Returns the new ``x``.
    """
    th, w, ia, ib = x[0], x[1], x[2], x[3]
    nr = p[P_NR]
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
    h6 = h * (1.0 / 6.0)
    return (th + h6 * (k1[0] + 2.0 * (k2[0] + k3[0]) + k4[0]),
            w + h6 * (k1[1] + 2.0 * (k2[1] + k3[1]) + k4[1]),
            ia + h6 * (k1[2] + 2.0 * (k2[2] + k3[2]) + k4[2]),
            ib + h6 * (k1[3] + 2.0 * (k2[3] + k3[3]) + k4[3]),
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
    if abs(w) < w_stick and abs(driving_torque(x[0], 0.0, x[2], x[3], p)) <= p[P_FS]:
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
    e_fric = x[7] + 0.5 * w * w / p[P_INV_J]
    r, inv_l = p[P_R], p[P_INV_L]
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


@_jit
def gaussian_pair(seed, counter):
    """Two independent standard normal samples for (seed, counter).

    Counter-based (Box-Muller on hashed counters): the noise of PWM period k
    is a function of k alone, so it does not depend on how a run is chunked.
    """
    key = splitmix64(np.uint64(seed))
    c2 = np.uint64(counter) * np.uint64(2)
    u1 = (float(splitmix64(key ^ c2) >> np.uint64(11)) + 1.0) * _TWO_M53      # (0, 1]
    u2 = float(splitmix64(key ^ (c2 + np.uint64(1))) >> np.uint64(11)) * _TWO_M53
    r = math.sqrt(-2.0 * log(u1))
    s, c = sincos(2.0 * math.pi * u2)
    return r * c, r * s


@_jit_inline
def quantise(x, q):
    """x rounded down to a whole number of steps of size q (encoder, microstep)."""
    return math.floor(x * (1.0 / q)) * q


@_jit_inline
def command(t, kind, speed, accel, distance):
    """Position (rad) and speed (rad/s) command at time t (s).

    kind 0: from rest with acceleration ``accel`` up to ``speed`` (signed), then held.
    kind 1: trapezoidal (or triangular) move of ``distance`` (signed) at up to |speed|.
    """
    a = accel
    if kind == PROFILE_CONSTANT:
        sgn = 1.0 if speed >= 0.0 else -1.0
        t_ramp = abs(speed) / a
        if t < t_ramp:
            return sgn * 0.5 * a * t * t, sgn * a * t
        return sgn * 0.5 * a * t_ramp * t_ramp + speed * (t - t_ramp), speed
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
    return (c[C_DT], c[C_NR], c[C_HOLD], c[C_MICROSTEP], c[C_KP_I], c[C_KI_I],
            c[C_ENCODER], c[C_VEL_ALPHA], c[C_KP_VEL], c[C_KP_POS], c[C_KI_POS],
            c[C_MODE], c[C_FF_ON], c[C_KM_EST], c[C_FS_EST],
            c[C_FF_S1], c[C_FF_C1], c[C_FF_S2], c[C_FF_C2], c[C_FF_S4], c[C_FF_C4],
            c[C_VDC], c[C_PROFILE], c[C_SPEED], c[C_ACCEL], c[C_DISTANCE],
            c[C_I_NOISE], c[C_I_OFFSET_A], c[C_I_OFFSET_B], c[C_NOISE_SEED], c[C_VEL_EST],
            c[C_KF_K0], c[C_KF_K1], c[C_BEMF_G1], c[C_BEMF_G2], c[C_DRIVE_MODE],
            c[C_R_EST], c[C_L_EST])


@_jit_inline
def feedforward_torque(sin_x, cos_x, q, u):
    """Detent compensation torque (N*m) at the angle whose sin and cos are given.

    The base model (eq. 8 / eq. 15 harmonics, scaled by ff_on) plus the
    external coefficient corrections in ``u`` (see ``U_*``).
    """
    on = q[Q_FF_ON]
    return harmonic_series(sin_x, cos_x,
                           on * q[Q_FF_S1] + u[U_DS1], on * q[Q_FF_C1] + u[U_DC1],
                           on * q[Q_FF_S2] + u[U_DS2], on * q[Q_FF_C2] + u[U_DC2],
                           on * q[Q_FF_S4] + u[U_DS4], on * q[Q_FF_C4] + u[U_DC4])


@_jit_inline
def control_step(period, theta, ia, ib, cs, q, u):
    """The controller of PWM period ``period`` (a count) : a pure function.

    ``theta``, ``ia``, ``ib`` are the true shaft angle and winding currents
    (the current sensors add their offset and noise here); ``cs`` =
    (integrator d, integrator q, previous encoder angle, velocity estimate,
    position-error integral, Kalman angle estimate, previous measured ia, ib,
    voltages va, vb applied during the period that just ended) is the
    controller's state (the caller sets the last two);
    ``q`` is :func:`controller_params`, ``u`` the external inputs.

    Returns (new cs, (va, vb) winding voltages to apply next period,
    (theta_fb, theta_cmd, omega_cmd, id, iq, iq_cmd, iq_injected, angle, sin angle,
    cos angle)).
    """
    int_d, int_q, theta_fb_prev, omega_fb, pos_int, theta_est, ia_prev, ib_prev, va_old, \
        vb_old = cs
    dt, nr = q[Q_DT], q[Q_NR]
    t = period * dt
    theta_cmd, omega_cmd = command(t, q[Q_PROFILE], q[Q_SPEED], q[Q_ACCEL], q[Q_DISTANCE])
    # Velocity estimate from the encoder (a drive senses it in either mode).
    theta_fb = quantise(theta, q[Q_ENCODER])
    if q[Q_I_NOISE] != 0.0:
        noise_a, noise_b = gaussian_pair(q[Q_NOISE_SEED], period)
        ia = ia + q[Q_I_OFFSET_A] + q[Q_I_NOISE] * noise_a
        ib = ib + q[Q_I_OFFSET_B] + q[Q_I_NOISE] * noise_b
    else:
        ia = ia + q[Q_I_OFFSET_A]
        ib = ib + q[Q_I_OFFSET_B]
    if q[Q_VEL_EST] == VEL_EST_BACK_EMF:
        # No encoder for the speed: the back-EMF over the period that just
        # ended, from its applied voltage and the measured currents at both
        # ends, projected on the electrical angle at the period's middle (open
        # loop: the command's, which the rotor trails by its load angle) and
        # low-passed like the encoder's difference.
        ea = va_old - q[Q_BEMF_G1] * ia + q[Q_BEMF_G2] * ia_prev
        eb = vb_old - q[Q_BEMF_G1] * ib + q[Q_BEMF_G2] * ib_prev
        if q[Q_MODE] == MODE_OPEN_LOOP:
            x_mid = nr * (theta_cmd - 0.5 * dt * omega_cmd)
        else:
            x_mid = nr * (theta_fb + 0.5 * q[Q_ENCODER])
        s_p, c_p = sincos(x_mid)
        w_raw = (c_p * eb - s_p * ea) * (1.0 / q[Q_KM_EST])
        omega_fb = omega_fb + q[Q_VEL_ALPHA] * (w_raw - omega_fb)
    elif q[Q_VEL_EST] == VEL_EST_KALMAN:
        # Steady-state Kalman filter, constant-velocity model, measuring the
        # centre of the encoder count.
        predicted = theta_est + dt * omega_fb
        innovation = theta_fb + 0.5 * q[Q_ENCODER] - predicted
        theta_est = predicted + q[Q_KF_K0] * innovation
        omega_fb = omega_fb + q[Q_KF_K1] * innovation
    else:
        omega_fb = omega_fb + q[Q_VEL_ALPHA] * ((theta_fb - theta_fb_prev) * (1.0 / dt)
                                               - omega_fb)

    if q[Q_MODE] == MODE_OPEN_LOOP:
        # Eqs. 7-8: Park angle and feedforward at the microstep-quantised command.
        angle = nr * quantise(theta_cmd, q[Q_MICROSTEP])
        sin_a, cos_a = sincos(angle)
        id_cmd = q[Q_HOLD]
        iq_inj = feedforward_torque(sin_a, cos_a, q, u) * (1.0 / q[Q_KM_EST]) + u[U_IQ]
        iq_cmd = iq_inj
    else:
        # Eqs. 14-15 at the encoder angle, taken at the centre of its count (a
        # floored count lags by half a count on average); Fs is fed forward
        # with the command's sign.
        theta_meas = theta_fb + 0.5 * q[Q_ENCODER]
        angle = nr * theta_meas
        sin_a, cos_a = sincos(angle)
        id_cmd = 0.0
        theta_err = theta_cmd - theta_meas
        pos_int = pos_int + theta_err * dt
        fs_ff = 0.0
        if omega_cmd > 0.0:
            fs_ff = q[Q_FS_EST]
        elif omega_cmd < 0.0:
            fs_ff = -q[Q_FS_EST]
        iq_inj = ((feedforward_torque(sin_a, cos_a, q, u) + q[Q_FF_ON] * fs_ff)
                  * (1.0 / q[Q_KM_EST]) + u[U_IQ])
        tau_fb = (q[Q_KP_VEL] * (omega_cmd - omega_fb) + q[Q_KP_POS] * theta_err
                  + q[Q_KI_POS] * pos_int)
        iq_cmd = tau_fb * (1.0 / q[Q_KM_EST]) + iq_inj

    id_m, iq_m = park_sc(ia, ib, sin_a, cos_a)
    if q[Q_DRIVE_MODE] == DRIVE_VOLTAGE:
        # No current feedback: the steady-state winding voltages in the frame
        # of the angle for the commanded currents at the command's electrical
        # speed, the back-EMF estimated from the command speed (docs/model.md,
        # "Voltage-mode drive"). They are applied during the next period, so
        # the inverse Park turns them to that period's middle, 1.5 periods on.
        w_e = nr * omega_cmd
        r_est, l_est = q[Q_R_EST], q[Q_L_EST]
        vd = r_est * id_cmd - w_e * l_est * iq_cmd
        vq = r_est * iq_cmd + w_e * l_est * id_cmd + q[Q_KM_EST] * omega_cmd
        sin_v, cos_v = sincos_shifted(angle, sin_a, cos_a, 1.5 * dt * w_e)
        va_dem, vb_dem = inverse_park_sc(vd, vq, sin_v, cos_v)
        v_alpha, v_beta, v_gamma = svpwm_legs(va_dem, vb_dem, q[Q_VDC])
        return ((int_d, int_q, theta_fb, omega_fb, pos_int, theta_est, ia, ib, va_old,
                 vb_old),
                (v_alpha - v_gamma, v_beta - v_gamma),
                (theta_fb, theta_cmd, omega_cmd, id_m, iq_m, iq_cmd, iq_inj, angle, sin_a,
                 cos_a))
    # PI in DQ, inverse Park, SVPWM, all at one sine and cosine.
    kp, ki = q[Q_KP_I], q[Q_KI_I]
    err_d = id_cmd - id_m
    err_q = iq_cmd - iq_m
    vd = pi_output(err_d, int_d, kp)
    vq = pi_output(err_q, int_q, kp)
    va_dem, vb_dem = inverse_park_sc(vd, vq, sin_a, cos_a)
    v_alpha, v_beta, v_gamma = svpwm_legs(va_dem, vb_dem, q[Q_VDC])
    va = v_alpha - v_gamma
    vb = v_beta - v_gamma
    vd_app, vq_app = park_sc(va, vb, sin_a, cos_a)
    int_d = pi_update(err_d, int_d, vd, vd_app, kp, ki, dt)
    int_q = pi_update(err_q, int_q, vq, vq_app, kp, ki, dt)
    return ((int_d, int_q, theta_fb, omega_fb, pos_int, theta_est, ia, ib, va_old, vb_old),
            (va, vb),
            (theta_fb, theta_cmd, omega_cmd, id_m, iq_m, iq_cmd, iq_inj, angle, sin_a, cos_a))


# ---------------------------------------------------------------------------
# The fused loop
# ---------------------------------------------------------------------------
@_jit
def run_periods(c, s, acc, u_arr, n_periods, trace, trace_every):
    """Advance one drive by ``n_periods`` PWM periods, in place on ``s`` and ``acc``.

    ``u_arr`` (N_INPUT) is held for the whole call. ``trace`` receives one row
    every ``trace_every`` periods (counted from this call's start) while it has
    room; pass a (0, N_TRACE) array for none. Returns the rows written.
    """
    return _advance(c, s, acc, u_arr, None, n_periods, trace, trace_every)


@_jit
def run_periods_law(c, s, acc, u_arr, law, n_periods, trace, trace_every):
    """:func:`run_periods` with the damping law ``law`` (``L_*``) on top.

    Each period the law reads the drive's samples of the period before (one
    PWM period of computation) and adds its current to the q residual
    ``U_IQ``; gains of zero add exactly nothing.
    """
    return _advance(c, s, acc, u_arr, law, n_periods, trace, trace_every)


@_jit_inline
def law_current(law, e_w, e_theta, s1, c1, dt):
    """One period of the damping law (see ``L_*``) at the Park angle whose sin and
    cos are given: updates its state, returns its current (A)."""
    e_lp = law[L_E_LP] + law[L_HP_ALPHA] * (e_theta - law[L_E_LP])
    law[L_E_LP] = e_lp
    i = law[L_KV] * e_w + law[L_KP] * (e_theta - e_lp)
    limit = law[L_LIMIT]
    if law[L_RESONANT] != 0.0:
        s2, c2, s4, c4 = harmonics(s1, c1)
        sn = (s1, s2, s4)
        cn = (c1, c2, c4)
        for k in range(3):
            kr, ki = law[L_KR1 + 2 * k], law[L_KI1 + 2 * k]
            es, ec = e_w * sn[k], e_w * cn[k]
            a = law[L_A1 + 2 * k] + dt * (kr * es - ki * ec)
            b = law[L_B1 + 2 * k] + dt * (ki * es + kr * ec)
            a = min(max(a, -limit), limit)
            b = min(max(b, -limit), limit)
            law[L_A1 + 2 * k] = a
            law[L_B1 + 2 * k] = b
            i += a * sn[k] + b * cn[k]
    i = min(max(i, -limit), limit)
    law[L_SUM_I2] += i * i
    return i


@_jit
def _advance(c, s, acc, u_arr, law, n_periods, trace, trace_every):
    """The fused loop; ``law`` None (pruned at compile time) or an ``L_*`` row."""
    if law is not None:
        # The resonant terms cost a third of the law: they run only while a gain
        # or a coefficient is non-zero (gains are held for the call).
        on = 0.0
        for j in range(L_KR1, L_KI4 + 1):
            if law[j] != 0.0:
                on = 1.0
        for j in range(L_A1, L_B4 + 1):
            if law[j] != 0.0:
                on = 1.0
        law[L_RESONANT] = on
    p = plant_params(c)
    q = controller_params(c)
    u = (u_arr[0], u_arr[1], u_arr[2], u_arr[3], u_arr[4], u_arr[5], u_arr[6])
    dt = q[Q_DT]
    n_sub = int(c[C_SUBSTEPS])
    h = dt / n_sub
    w_stick = c[C_W_STICK]
    win_start = c[C_WINDOW_START]
    ref_rate = c[C_NR] * c[C_REF_SPEED]
    x = (s[S_THETA], s[S_OMEGA], s[S_IA], s[S_IB], s[S_E_IN], s[S_E_CU], s[S_E_DAMP],
         s[S_E_FRIC], s[S_E_LOAD])
    cs = (s[S_INT_D], s[S_INT_Q], s[S_THETA_FB_PREV], s[S_OMEGA_FB], s[S_POS_INT],
          s[S_THETA_EST], s[S_IA_PREV], s[S_IB_PREV], s[S_VA_OLD], s[S_VB_OLD])
    va_next, vb_next = s[S_VA_NEXT], s[S_VB_NEXT]
    period = s[S_PERIOD]
    sin_prev, cos_prev = sincos(s[S_PARK_ANGLE])
    obs = (s[S_THETA_FB], s[S_THETA_CMD], s[S_OMEGA_CMD], s[S_ID_MEAS], s[S_IQ_MEAS], 0.0,
           s[S_IQ_FF], s[S_PARK_ANGLE], sin_prev, cos_prev)
    n_win, sum_e, sum_e2, min_e, max_e, sum_iff2 = (acc[A_COUNT], acc[A_SUM_E],
                                                     acc[A_SUM_E2], acc[A_MIN_E],
                                                     acc[A_MAX_E], acc[A_SUM_IFF2])
    h1s, h1c, h2s, h2c, h4s, h4c = (acc[A_H1_S], acc[A_H1_C], acc[A_H2_S], acc[A_H2_C],
                                    acc[A_H4_S], acc[A_H4_C])
    max_lag, max_i = acc[A_MAX_LAG], acc[A_MAX_CURRENT]
    sum_e2_all, n_all, sum_iff2_all = acc[A_SUM_E2_ALL], acc[A_COUNT_ALL], acc[A_SUM_IFF2_ALL]
    rows = 0
    for i in range(n_periods):
        t = period * dt
        # Computation delay: this period applies what the previous one computed.
        va, vb = va_next, vb_next
        if law is None:
            cs, v_next, obs = control_step(period, x[0], x[2], x[3], cs, q, u)
        else:
            # The law's current from the previous period's samples, then held.
            i_law = law_current(law, obs[2] - cs[3], obs[1] - cs[2], obs[8], obs[9], dt)
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
            row[T_T] = t
            row[T_THETA] = x[0]
            row[T_OMEGA] = x[1]
            row[T_THETA_CMD] = obs[1]
            row[T_OMEGA_CMD] = obs[2]
            row[T_IA] = x[2]
            row[T_IB] = x[3]
            row[T_VA] = va
            row[T_VB] = vb
            row[T_ID] = obs[3]
            row[T_IQ] = obs[4]
            row[T_IQ_CMD] = obs[5]
            row[T_IQ_FF] = obs[6]
            row[T_THETA_FB] = obs[0]
            row[T_OMEGA_FB] = cs[3]
            rows += 1

        for _ in range(n_sub):
            x = plant_step(x, va, vb, p, h, w_stick)
        period += 1.0

    s[S_PERIOD] = period
    (s[S_THETA], s[S_OMEGA], s[S_IA], s[S_IB], s[S_E_IN], s[S_E_CU], s[S_E_DAMP],
     s[S_E_FRIC], s[S_E_LOAD]) = x
    (s[S_INT_D], s[S_INT_Q], s[S_THETA_FB_PREV], s[S_OMEGA_FB], s[S_POS_INT], s[S_THETA_EST],
     s[S_IA_PREV], s[S_IB_PREV], s[S_VA_OLD], s[S_VB_OLD]) = cs
    s[S_VA_NEXT], s[S_VB_NEXT] = va_next, vb_next
    (s[S_THETA_FB], s[S_THETA_CMD], s[S_OMEGA_CMD], s[S_ID_MEAS], s[S_IQ_MEAS], _iq_cmd,
     s[S_IQ_FF], s[S_PARK_ANGLE], _sin, _cos) = obs
    acc[A_COUNT], acc[A_SUM_E], acc[A_SUM_E2], acc[A_MIN_E], acc[A_MAX_E] = (
        n_win, sum_e, sum_e2, min_e, max_e)
    acc[A_SUM_IFF2] = sum_iff2
    acc[A_H1_S], acc[A_H1_C], acc[A_H2_S], acc[A_H2_C], acc[A_H4_S], acc[A_H4_C] = (
        h1s, h1c, h2s, h2c, h4s, h4c)
    acc[A_MAX_LAG], acc[A_MAX_CURRENT] = max_lag, max_i
    acc[A_SUM_E2_ALL], acc[A_COUNT_ALL], acc[A_SUM_IFF2_ALL] = sum_e2_all, n_all, sum_iff2_all
    return rows


@_jit
def run_batch(configs, states, accs, inputs, n_periods):
    """Advance N drives (rows of the arrays) by ``n_periods`` each, without trace."""
    empty = np.zeros((0, N_TRACE))
    for i in range(configs.shape[0]):
        run_periods(configs[i], states[i], accs[i], inputs[i], n_periods, empty, 1)


@_jit
def run_batch_law(configs, states, accs, inputs, laws, n_periods):
    """:func:`run_batch` with each drive's damping law (rows of ``laws``)."""
    empty = np.zeros((0, N_TRACE))
    for i in range(configs.shape[0]):
        _advance(configs[i], states[i], accs[i], inputs[i], laws[i], n_periods, empty, 1)


@njit(cache=True)
def merge_rows(totals, parts):
    """``simulation.merge_accumulators`` row by row (no fast-math: the same sums,
    and ``min``/``max`` as Python's: the first unless the second is strictly
    smaller/larger)."""
    for i in range(totals.shape[0]):
        t = totals[i]
        p = parts[i]
        if p[A_COUNT] > 0:
            if t[A_COUNT] > 0:
                if p[A_MIN_E] < t[A_MIN_E]:
                    t[A_MIN_E] = p[A_MIN_E]
                if p[A_MAX_E] > t[A_MAX_E]:
                    t[A_MAX_E] = p[A_MAX_E]
            else:
                t[A_MIN_E] = p[A_MIN_E]
                t[A_MAX_E] = p[A_MAX_E]
        for j in (A_COUNT, A_SUM_E, A_SUM_E2, A_SUM_IFF2, A_H1_S, A_H1_C, A_H2_S, A_H2_C,
                  A_H4_S, A_H4_C, A_SUM_E2_ALL, A_COUNT_ALL, A_SUM_IFF2_ALL):
            t[j] += p[j]
        if p[A_MAX_LAG] > t[A_MAX_LAG]:
            t[A_MAX_LAG] = p[A_MAX_LAG]
        if p[A_MAX_CURRENT] > t[A_MAX_CURRENT]:
            t[A_MAX_CURRENT] = p[A_MAX_CURRENT]
