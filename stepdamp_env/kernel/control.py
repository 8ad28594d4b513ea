"""The drive's controller for one PWM period: the noise of the current sensors,
the position command, the velocity estimate, the current command (holding
current or servo law, with the harmonic feedforward) and the current loops."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..fixedmath import log_in, sincos, sincos_in, sincos_lane, sincos_rotated, sincos_shifted
from .layout import CONFIG, CTRL, DRIVE, INPUT, MODE, PROFILE, VEL_EST, ControllerState, Sample
from .plant import harmonic_series, inverse_park_sc, park_sc, pi_output, pi_update, svpwm_legs

__all__ = ["splitmix64", "noise_key", "uniform_pair_keyed", "uniform_pair", "gaussian_pair_keyed",
           "gaussian_pair", "quantise", "constant_speed_command",
           "move_command", "s_curve_command", "s_curve_lanes", "command", "command_in",
           "controller_params", "feedforward_torque", "sense_currents", "estimate_velocity",
           "estimate_velocity_lanes", "current_command", "current_command_lanes", "voltage_drive",
           "voltage_drive_lanes", "current_loop", "control_step"]

# No Python error checks on division: the inputs are validated before they get here.
# No fastmath, not even contraction: a fused multiply-add rounds once where a CPU
# without FMA rounds twice, and the result must not depend on the CPU
# (:mod:`.fixedmath`).
_jit = njit(cache=True, error_model="numpy")
# The pieces of the hot loop are inlined at numba-IR level: LLVM's own inliner
# leaves many as calls that return tuples through memory (measured with
# benchmarks/bench_sim.py: about 10 % of the loop's time).
_jit_inline = njit(cache=True, error_model="numpy", inline="always")

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
def noise_key(seed):
    """The hash key (uint64) of a noise ``seed``: :func:`uniform_pair`'s first
    step, the same for every counter (the SIMD lanes compute it once per call)."""
    return splitmix64(np.uint64(seed))


@_jit_inline
def uniform_pair_keyed(key, counter):
    """:func:`uniform_pair` of the seed whose :func:`noise_key` is ``key``."""
    c2 = np.uint64(counter) * np.uint64(2)
    u1 = (float(splitmix64(key ^ c2) >> np.uint64(11)) + 1.0) * _TWO_M53
    u2 = float(splitmix64(key ^ (c2 + np.uint64(1))) >> np.uint64(11)) * _TWO_M53
    return u1, u2


@_jit_inline
def uniform_pair(seed, counter):
    """Two uniform samples for (seed, counter): u1 in (0, 1], u2 in [0, 1)."""
    return uniform_pair_keyed(noise_key(seed), counter)


@_jit_inline
def gaussian_pair_keyed(key, counter, lanes=None):
    """:func:`gaussian_pair` of the seed whose :func:`noise_key` is ``key``."""
    u1, u2 = uniform_pair_keyed(key, counter)
    r = math.sqrt(-2.0 * log_in(u1, lanes))
    s, c = sincos_in(2.0 * math.pi * u2, lanes)
    return r * c, r * s


@_jit_inline
def gaussian_pair(seed, counter, lanes=None):
    """Two independent standard normal samples for (seed, counter).

    Counter-based (Box-Muller on hashed counters, :func:`uniform_pair`): the noise
    of PWM period k is a function of k alone, so it does not depend on how a run
    is chunked. ``lanes``: see :func:`control_step`.
    """
    return gaussian_pair_keyed(noise_key(seed), counter, lanes)


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
def s_curve_command(t, speed, accel, distance):
    """Position (rad) and speed (rad/s) at time t (s) of :func:`command`'s kind 2:
    a move of ``distance`` (signed) at up to |speed| whose ramps are half
    cosines, v = vmax*(1 - cos(pi*t/T))/2 with T = pi*vmax/(2*accel): the
    acceleration rises and falls smoothly to its peak ``accel`` (bounded jerk,
    an S-curve); each ramp covers vmax*T/2. Too short for vmax: the peak speed
    is lowered to sqrt(2*accel*d/pi) (no cruise)."""
    sgn = 1.0 if distance >= 0.0 else -1.0
    d = abs(distance)
    vmax = abs(speed)
    if math.pi * vmax * vmax / (2.0 * accel) > d:
        vmax = math.sqrt(2.0 * accel * d / math.pi)
    t_acc = math.pi * vmax / (2.0 * accel)
    d_acc = 0.5 * vmax * t_acc
    t_flat = (d - 2.0 * d_acc) / vmax if vmax > 0.0 else 0.0
    k = math.pi / t_acc if t_acc > 0.0 else 0.0
    # fixedmath's sine and cosine: libm's differ in the last bit between CPUs.
    if t < t_acc:
        sk, ck = sincos(k * t)
        return (sgn * 0.5 * vmax * (t - sk / k),
                sgn * 0.5 * vmax * (1.0 - ck))
    if t < t_acc + t_flat:
        return sgn * (d_acc + vmax * (t - t_acc)), sgn * vmax
    td = t - t_acc - t_flat
    if td < t_acc:
        sk, ck = sincos(k * td)
        return (sgn * (d - d_acc + 0.5 * vmax * (td + sk / k)),
                sgn * 0.5 * vmax * (1.0 + ck))
    return sgn * d, 0.0


@_jit_inline
def command(t, kind, speed, accel, distance):
    """Position (rad) and speed (rad/s) command at time t (s).

    kind 0: from rest with acceleration ``accel`` up to ``speed`` (signed), then held.
    kind 1: trapezoidal (or triangular) move of ``distance`` (signed) at up to |speed|.
    kind 2: the same move with half-cosine ramps of peak acceleration ``accel``
    (:func:`s_curve_command`).
    """
    if kind == PROFILE.CONSTANT:
        return constant_speed_command(t, speed, accel)
    if kind == PROFILE.MOVE:
        return move_command(t, speed, accel, distance)
    return s_curve_command(t, speed, accel, distance)


@_jit_inline
def s_curve_lanes(t, speed, accel, distance):
    """:func:`s_curve_command` without branches, for SIMD lanes: the same bits
    (one branch-free sine and cosine at the ramp that applies; its argument is
    at most pi there)."""
    sgn = 1.0 if distance >= 0.0 else -1.0
    d = abs(distance)
    vmax = abs(speed)
    vmax = math.sqrt(2.0 * accel * d / math.pi) if math.pi * vmax * vmax / (2.0 * accel) > d else vmax
    t_acc = math.pi * vmax / (2.0 * accel)
    d_acc = 0.5 * vmax * t_acc
    t_flat = (d - 2.0 * d_acc) / vmax if vmax > 0.0 else 0.0
    k = math.pi / t_acc if t_acc > 0.0 else 0.0
    td = t - t_acc - t_flat
    rising = t < t_acc
    sk, ck = sincos_lane(k * t if rising else k * td)
    up = (sgn * 0.5 * vmax * (t - sk / k), sgn * 0.5 * vmax * (1.0 - ck))
    cruise = (sgn * (d_acc + vmax * (t - t_acc)), sgn * vmax)
    down = (sgn * (d - d_acc + 0.5 * vmax * (td + sk / k)), sgn * 0.5 * vmax * (1.0 + ck))
    falling = td < t_acc
    flat = t < t_acc + t_flat
    return ((up[0] if rising else (cruise[0] if flat else (down[0] if falling else sgn * d))),
            (up[1] if rising else (cruise[1] if flat else (down[1] if falling else 0.0))))


@_jit_inline
def command_in(t, kind, speed, accel, distance, lanes):
    """:func:`command`; for SIMD lanes (``lanes`` not None) every profile
    computed and the drive's selected (a group of lanes may mix them)."""
    if lanes is None:
        return command(t, kind, speed, accel, distance)
    p0, v0 = constant_speed_command(t, speed, accel)
    p1, v1 = move_command(t, speed, accel, distance)
    p2, v2 = s_curve_lanes(t, speed, accel, distance)
    constant = kind == PROFILE.CONSTANT
    move = kind == PROFILE.MOVE
    return (p0 if constant else (p1 if move else p2)), (v0 if constant else (v1 if move else v2))


@_jit
def controller_params(c, lanes=None):
    """The controller's constants as a tuple, the form :func:`control_step` takes
    (``lanes``: kept for the callers that pass it; the same tuple).

    Positions are the ``Q_*`` names: (dt, Nr, holding current, microstep angle,
    Kp_i, Ki_i, encoder angle, velocity filter alpha, Kp_vel, Kp_pos, Ki_pos,
    mode, ff_on, Km_est, Fs_est, ff s1, c1, s2, c2, s4, c4, Vdc, profile kind,
    speed, accel, distance, current noise, offset a, offset b, noise seed,
    velocity estimator, Kalman k0, k1, back-EMF G1, G2, drive mode, R and L of
    the voltage mode's winding model).
    """
    mode, drive = c[CONFIG.MODE], c[CONFIG.DRIVE_MODE]
    vel_est, profile = c[CONFIG.VEL_EST], c[CONFIG.PROFILE]
    return (c[CONFIG.DT], c[CONFIG.NR], c[CONFIG.HOLD], c[CONFIG.MICROSTEP], c[CONFIG.KP_I], c[CONFIG.KI_I],
            c[CONFIG.ENCODER], c[CONFIG.VEL_ALPHA], c[CONFIG.KP_VEL], c[CONFIG.KP_POS], c[CONFIG.KI_POS],
            mode, c[CONFIG.BASE_CONTROLLER], c[CONFIG.KM_EST], c[CONFIG.FS_EST],
            c[CONFIG.FF_S1], c[CONFIG.FF_C1], c[CONFIG.FF_S2], c[CONFIG.FF_C2], c[CONFIG.FF_S4], c[CONFIG.FF_C4],
            c[CONFIG.VDC], profile, c[CONFIG.SPEED], c[CONFIG.ACCEL], c[CONFIG.DISTANCE],
            c[CONFIG.I_NOISE], c[CONFIG.I_OFFSET_A], c[CONFIG.I_OFFSET_B], c[CONFIG.NOISE_SEED],
            vel_est, c[CONFIG.KF_K0], c[CONFIG.KF_K1], c[CONFIG.BEMF_G1], c[CONFIG.BEMF_G2],
            drive, c[CONFIG.R_EST], c[CONFIG.L_EST])


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
def sense_currents(period, ia, ib, q, noise=None):
    """The current sensors' readings (A) of the true ``ia``, ``ib``: offset and,
    if set, noise drawn for ``period`` (or ``noise``, the pair
    :func:`gaussian_pair` gives for it, drawn beforehand: the SIMD lanes')."""
    noisy = q[CTRL.I_NOISE] != 0.0
    noise_a = noise_b = 0.0
    if noise is not None:
        noise_a, noise_b = noise
    elif noisy:
        noise_a, noise_b = gaussian_pair(q[CTRL.NOISE_SEED], period)
    return (ia + q[CTRL.I_OFFSET_A] + q[CTRL.I_NOISE] * noise_a if noisy
            else ia + q[CTRL.I_OFFSET_A],
            ib + q[CTRL.I_OFFSET_B] + q[CTRL.I_NOISE] * noise_b if noisy
            else ib + q[CTRL.I_OFFSET_B])


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
def estimate_velocity_lanes(theta_fb, theta_fb_prev, omega_fb, theta_est, ia, ib, ia_prev, ib_prev,
                            va_old, vb_old, theta_cmd, omega_cmd, q, encoder_only=None):
    """:func:`estimate_velocity` for SIMD lanes: the three estimates computed and
    the drive's selected (the same bits); also whether the back-EMF's angle
    left the branch-free sine's range (beyond 1e6 rad, or NaN).
    ``encoder_only`` not None: no lane estimates from the back-EMF, which is
    then not computed (chosen when compiled)."""
    dt, nr = q[CTRL.DT], q[CTRL.NR]
    x_mid = (nr * (theta_cmd - 0.5 * dt * omega_cmd) if q[CTRL.MODE] == MODE.OPEN_LOOP
             else nr * (theta_fb + 0.5 * q[CTRL.ENCODER]))
    w_bemf = omega_fb
    if encoder_only is None:
        ea = va_old - q[CTRL.BEMF_G1] * ia + q[CTRL.BEMF_G2] * ia_prev
        eb = vb_old - q[CTRL.BEMF_G1] * ib + q[CTRL.BEMF_G2] * ib_prev
        s_p, c_p = sincos_lane(x_mid)
        w_raw = (c_p * eb - s_p * ea) * (1.0 / q[CTRL.KM_EST])
        w_bemf = omega_fb + q[CTRL.VEL_ALPHA] * (w_raw - omega_fb)
    predicted = theta_est + dt * omega_fb
    innovation = theta_fb + 0.5 * q[CTRL.ENCODER] - predicted
    w_kf = omega_fb + q[CTRL.KF_K1] * innovation
    theta_kf = predicted + q[CTRL.KF_K0] * innovation
    w_lp = omega_fb + q[CTRL.VEL_ALPHA] * ((theta_fb - theta_fb_prev) * (1.0 / dt) - omega_fb)
    bemf = q[CTRL.VEL_EST] == VEL_EST.BACK_EMF
    kalman = q[CTRL.VEL_EST] == VEL_EST.KALMAN
    far = bemf & ((abs(x_mid) >= 1e6) | (x_mid != x_mid))
    return (w_bemf if bemf else (w_kf if kalman else w_lp)), (theta_kf if kalman else theta_est), far


@_jit_inline
def current_command(theta_fb, omega_fb, pos_int, theta_cmd, omega_cmd, q, u, lanes=None):
    """The mode's current command: returns (pos_int, Park angle (rad), its sine
    and cosine, id_cmd, iq_cmd, iq_injected (A)). ``lanes``: see :func:`control_step`."""
    nr, dt = q[CTRL.NR], q[CTRL.DT]
    if q[CTRL.MODE] == MODE.OPEN_LOOP:
        # Eqs. 7-8: Park angle and feedforward at the microstep-quantised command.
        angle = nr * quantise(theta_cmd, q[CTRL.MICROSTEP])
        sin_a, cos_a = sincos_in(angle, lanes)
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
def current_command_lanes(theta_fb, omega_fb, pos_int, theta_cmd, omega_cmd, q, u):
    """:func:`current_command` for SIMD lanes: both modes computed, the drive's
    selected, one branch-free sine and cosine at its angle (the same bits)."""
    nr, dt = q[CTRL.NR], q[CTRL.DT]
    open_loop = q[CTRL.MODE] == MODE.OPEN_LOOP
    theta_meas = theta_fb + 0.5 * q[CTRL.ENCODER]
    angle = nr * quantise(theta_cmd, q[CTRL.MICROSTEP]) if open_loop else nr * theta_meas
    sin_a, cos_a = sincos_lane(angle)
    ff = feedforward_torque(sin_a, cos_a, q, u)
    iq_open = ff * (1.0 / q[CTRL.KM_EST]) + u[INPUT.IQ]
    theta_err = theta_cmd - theta_meas
    pos_int_servo = pos_int + theta_err * dt
    fs_ff = q[CTRL.FS_EST] if omega_cmd > 0.0 else (-q[CTRL.FS_EST] if omega_cmd < 0.0 else 0.0)
    iq_inj = (ff + q[CTRL.BASE_CONTROLLER] * fs_ff) * (1.0 / q[CTRL.KM_EST]) + u[INPUT.IQ]
    tau_fb = (q[CTRL.KP_VEL] * (omega_cmd - omega_fb) + q[CTRL.KP_POS] * theta_err
              + q[CTRL.KI_POS] * pos_int_servo)
    iq_servo = tau_fb * (1.0 / q[CTRL.KM_EST]) + iq_inj
    return ((pos_int if open_loop else pos_int_servo), angle, sin_a, cos_a,
            (q[CTRL.HOLD] if open_loop else 0.0), (iq_open if open_loop else iq_servo),
            (iq_open if open_loop else iq_inj))


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
def voltage_drive_lanes(angle, sin_a, cos_a, id_cmd, iq_cmd, omega_cmd, q):
    """:func:`voltage_drive` for SIMD lanes: both of :func:`.fixedmath.sincos_shifted`'s
    ways computed and the one it takes selected (the same bits); also whether
    its angle left the branch-free sine's range."""
    w_e = q[CTRL.NR] * omega_cmd
    r_est, l_est = q[CTRL.R_EST], q[CTRL.L_EST]
    vd = r_est * id_cmd - w_e * l_est * iq_cmd
    vq = r_est * iq_cmd + w_e * l_est * id_cmd + q[CTRL.KM_EST] * omega_cmd
    delta = 1.5 * q[CTRL.DT] * w_e
    wide = abs(delta) > 0.125
    s_far, c_far = sincos_lane(angle + delta)
    s_near, c_near = sincos_rotated(sin_a, cos_a, delta)
    sin_v, cos_v = (s_far if wide else s_near), (c_far if wide else c_near)
    va_dem, vb_dem = inverse_park_sc(vd, vq, sin_v, cos_v)
    v_alpha, v_beta, v_gamma = svpwm_legs(va_dem, vb_dem, q[CTRL.VDC])
    far = wide & ((abs(angle + delta) >= 1e6) | (angle + delta != angle + delta))
    return v_alpha - v_gamma, v_beta - v_gamma, far


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
def control_step(period, theta, ia, ib, cs, q, u, lanes=None, given=None, current_only=None):
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

    ``lanes`` None: a drive's own loop. Not None: compiled for SIMD lanes
    (:mod:`stepdamp_env.lanes`): every variant's branch computed and the
    drive's selected (the ``*_lanes`` pieces), the branch-free sine, cosine and
    logarithm, so a loop over lanes of any mix of variants vectorises; the same
    arithmetic, so the same bits.

    ``given`` None (a drive's own loop), or what depends on the period and
    the drive's constants alone, computed beforehand (the SIMD lanes always
    pass it, from loops of their own that a group skips where none of its
    lanes needs them): (the command's position
    (rad) and speed (rad/s), the current sensors' noise pair), the values this
    function would compute (the noise pair may be anything for a drive
    without noise: it is not read). ``current_only`` not None (lanes; chosen when compiled):
    every lane is a current-mode drive with an encoder or Kalman velocity
    estimate, so the voltage mode and the back-EMF estimate are not computed.

    Returns (the new :class:`.layout.ControllerState`, (va, vb) winding voltages
    to apply next period, the period's :class:`.layout.Sample`, whether a
    lane's back-EMF or voltage-mode angle left the branch-free path (beyond
    1e6 rad or NaN) or its command is NaN; False for a drive's loop).
    """
    int_d, int_q, theta_fb_prev, omega_fb, pos_int, theta_est, ia_prev, ib_prev, va_old, \
        vb_old = cs
    if given is None:
        t = period * q[CTRL.DT]
        theta_cmd, omega_cmd = command(t, q[CTRL.PROFILE], q[CTRL.SPEED], q[CTRL.ACCEL],
                                       q[CTRL.DISTANCE])
        ia, ib = sense_currents(period, ia, ib, q)
    else:
        theta_cmd, omega_cmd = given[0], given[1]
        ia, ib = sense_currents(period, ia, ib, q, (given[2], given[3]))
    # Velocity estimate from the encoder (a drive senses it in either mode).
    theta_fb = quantise(theta, q[CTRL.ENCODER])
    if lanes is None:
        omega_fb, theta_est = estimate_velocity(theta_fb, theta_fb_prev, omega_fb, theta_est, ia,
                                                ib, ia_prev, ib_prev, va_old, vb_old, theta_cmd,
                                                omega_cmd, q)
        pos_int, angle, sin_a, cos_a, id_cmd, iq_cmd, iq_inj = current_command(
            theta_fb, omega_fb, pos_int, theta_cmd, omega_cmd, q, u, lanes)
        id_m, iq_m = park_sc(ia, ib, sin_a, cos_a)
        if q[CTRL.DRIVE_MODE] == DRIVE.VOLTAGE:
            va, vb = voltage_drive(angle, sin_a, cos_a, id_cmd, iq_cmd, omega_cmd, q)
        else:
            int_d, int_q, va, vb = current_loop(int_d, int_q, id_cmd, iq_cmd, id_m, iq_m, sin_a,
                                                cos_a, q)
        far = False
    else:
        omega_fb, theta_est, far_est = estimate_velocity_lanes(
            theta_fb, theta_fb_prev, omega_fb, theta_est, ia, ib, ia_prev, ib_prev, va_old,
            vb_old, theta_cmd, omega_cmd, q, current_only)
        pos_int, angle, sin_a, cos_a, id_cmd, iq_cmd, iq_inj = current_command_lanes(
            theta_fb, omega_fb, pos_int, theta_cmd, omega_cmd, q, u)
        id_m, iq_m = park_sc(ia, ib, sin_a, cos_a)
        int_d_c, int_q_c, va_c, vb_c = current_loop(int_d, int_q, id_cmd, iq_cmd, id_m, iq_m,
                                                    sin_a, cos_a, q)
        # A NaN command (an S-curve whose ramp time underflows): the kernel's NaN, not the lanes'.
        far = far_est | (theta_cmd != theta_cmd) | (omega_cmd != omega_cmd)
        if current_only is None:
            va_v, vb_v, far_v = voltage_drive_lanes(angle, sin_a, cos_a, id_cmd, iq_cmd,
                                                    omega_cmd, q)
            voltage = q[CTRL.DRIVE_MODE] == DRIVE.VOLTAGE
            va, vb = (va_v if voltage else va_c), (vb_v if voltage else vb_c)
            int_d, int_q = (int_d if voltage else int_d_c), (int_q if voltage else int_q_c)
            far = far | (voltage & far_v)
        else:
            va, vb, int_d, int_q = va_c, vb_c, int_d_c, int_q_c
    return (ControllerState(int_d, int_q, theta_fb, omega_fb, pos_int, theta_est, ia, ib, va_old,
                            vb_old),
            (va, vb),
            Sample(theta_fb, theta_cmd, omega_cmd, id_m, iq_m, iq_cmd, iq_inj, angle, sin_a, cos_a),
            far)


