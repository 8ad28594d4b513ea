"""The kernel's packed rows, declared once (:func:`stepdamp_env.fields.layout`):
``CONFIG`` (never changed by a step), ``STATE``, ``ACC`` (metrics), ``INPUT``
(external inputs held for a call), ``LAW`` (the damping law's gains and state),
``TRACE``; ``PLANT`` and ``CTRL``, the parameter tuples the pieces share; the
codes ``DRIVE``, ``VEL_EST``, ``MODE``, ``PROFILE``."""

from __future__ import annotations

from collections import namedtuple

from ..fields import describe, layout

__all__ = ["CONFIG", "DRIVE", "VEL_EST", "MODE", "PROFILE", "PLANT", "CTRL", "STATE", "ACC",
           "INPUT", "LAW", "TRACE", "TRACE_NAMES", "TRACE_UNITS", "ControllerState", "Sample",
           "Metrics", "LawState"]

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
    PROFILE       a PROFILE code: CONSTANT (speed after a ramp), MOVE or S_CURVE (point
                  to point)
    SPEED         command speed (rad/s, signed)
    ACCEL         command acceleration (rad/s^2, > 0)
    DISTANCE      move distance (rad, signed), moves only
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
    WINDOW_END    metrics window end (s; inf: the window stays open)
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
    MOVE       point-to-point move, trapezoidal speed (constant-acceleration ramps)
    S_CURVE    point-to-point move, sinusoidal ramps (jerk-limited, an S-curve)
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
    SUM_P         sum of the position error theta_cmd - theta in the window (rad)
    SUM_P2        sum of its square
    SUM_P2_ALL    sum of the squared position error over all samples (rad^2)
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
# The tuples the loop carries from period to period (numba keeps them in
# registers); :mod:`.period` loads them from, and stores them in, the rows.
# ---------------------------------------------------------------------------
#: The controller's state: the PI integrators (V), the previous encoder angle
#: (rad), the velocity estimate (rad/s), the servo's position-error integral
#: (rad*s), the Kalman angle (rad), the previous measured phase currents (A),
#: the voltages applied during the period that just ended (V).
ControllerState = namedtuple("ControllerState", "int_d int_q theta_fb_prev omega_fb pos_int "
                                                "theta_est ia_prev ib_prev va_old vb_old")
#: A period's sample and command: encoder angle, command angle (rad) and speed
#: (rad/s), measured d/q currents, q current command, injected q current (A),
#: Park angle (rad), its sine and cosine.
Sample = namedtuple("Sample", "theta_fb theta_cmd omega_cmd id iq iq_cmd iq_ff angle sin_angle "
                              "cos_angle")
#: The accumulated metrics, in ACC's order (ACC's fields, lower case).
Metrics = namedtuple("Metrics", [name.lower() for name in ACC._fields])
#: The damping law's gains and state, in LAW's order (LAW's fields, lower case).
LawState = namedtuple("LawState", [name.lower() for name in LAW._fields])
