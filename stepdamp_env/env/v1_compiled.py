"""Compiled per-step helpers of ``StepperDamp-v1``, and the layouts they write.

Positions are defined here, in the module whose compiled code uses them (numba
freezes module globals into its on-disk cache and only notices changes to this
file). The kernel's state and accumulator positions come in as the array
``ix`` (:data:`stepdamp_env.env.compiled.KERNEL_INDEX`), the law's as ``lx``
(:data:`LAW_INDEX`), bounds as arguments.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import kernel as K
from ..fixedmath import sincos
from . import compiled as C

__all__ = ["N_BASE_OBS", "N_CONTEXT", "N_PRIVILEGED", "N_HISTORY_SIGNALS", "N_PAR", "N_OUT",
           "MAX_ACT_DIM", "LAW_INDEX", "load_actions", "observe"]

_jit = njit(cache=True, error_model="numpy")

# Observation entries (float32 row), in units the motor sets (see the env docstring).
OBS_POSITION_ERROR = 0   # (theta_cmd - encoder angle) / ripple position unit
OBS_VELOCITY_ERROR = 1   # (omega_cmd - velocity estimate) / ripple velocity unit
OBS_SIN_X = 2            # sin, cos of the electrical (Park) angle x, 2x, 4x
OBS_COS_X = 3
OBS_SIN_2X = 4
OBS_COS_2X = 5
OBS_SIN_4X = 6
OBS_COS_4X = 7
OBS_SPEED_COMMAND = 8    # omega_cmd / (2*pi * predicted h = 1 resonance of the nominal motor)
OBS_ID_ERROR = 9         # (measured id - its command) / ripple current unit
OBS_IQ = 10              # measured iq / ripple current unit
N_BASE_OBS = 11          # then last action (k), history (2*h), context, privileged
N_HISTORY_SIGNALS = 2    # position error, velocity error per history sample
N_CONTEXT = 9            # see env docstring: speed over 3 resonances, 6 model coefficients
N_PRIVILEGED = 4         # true position error, velocity error (units above), ia, ib / hold

# Per-drive episode constants (float64 row).
P_POS_UNIT = 0      # ripple position unit (rad)
P_VEL_UNIT = 1      # ripple velocity unit (rad/s)
P_CUR_UNIT = 2      # ripple current unit (A)
P_SPEED_UNIT = 3    # normaliser of the speed command (rad/s)
P_ID_CMD = 4        # the drive's d current command (A)
P_FULL_STEP = 5     # one full step (rad): step loss
P_HOLD = 6          # holding current (A)
P_I_LIMIT = 7       # unsafe phase current (A)
P_CUR_PEN = 8       # weight of the current penalty
P_ACT_SCALE = 9     # first of MAX_ACT_DIM columns: physical size of action entry j at 1.0
MAX_ACT_DIM = 8
N_PAR = P_ACT_SCALE + MAX_ACT_DIM

# Per-step physical outputs (float64 row).
O_REWARD = 0
O_VEL_RMS = 1       # rms of w_cmd - w over the step's PWM samples (rad/s)
O_LAG = 2           # max |theta_cmd - theta| over the step (rad)
O_IINJ_RMS = 3      # rms injected q current (base, residual and law) (A)
O_PEAK_I = 4        # max |phase current| (A)
O_STEP_LOSS = 5
O_OVERCURRENT = 6
O_NONFINITE = 7
O_TERMINATED = 8
O_LAW_RMS = 9       # rms current of the damping law (A)
N_OUT = 10

IX_LAW_SUM_I2 = 0
LAW_INDEX = np.array([K.LAW.SUM_I2], dtype=np.int64)

# Positions in compiled.KERNEL_INDEX, copied so that this module's cache never
# depends on another file; the import fails if they drift apart.
IX_THETA_FB, IX_OMEGA_FB, IX_THETA_CMD, IX_OMEGA_CMD = 0, 1, 2, 3
IX_ID_MEAS, IX_IQ_MEAS, IX_PARK_ANGLE, IX_THETA, IX_OMEGA, IX_IA, IX_IB = 4, 5, 6, 7, 8, 9, 10
IX_SUM_E2_ALL, IX_COUNT_ALL, IX_SUM_IFF2_ALL, IX_MAX_LAG, IX_MAX_CURRENT = 11, 12, 13, 14, 15
assert (IX_THETA_FB, IX_OMEGA_FB, IX_THETA_CMD, IX_OMEGA_CMD, IX_ID_MEAS, IX_IQ_MEAS,
        IX_PARK_ANGLE, IX_THETA, IX_OMEGA, IX_IA, IX_IB, IX_SUM_E2_ALL, IX_COUNT_ALL,
        IX_SUM_IFF2_ALL, IX_MAX_LAG, IX_MAX_CURRENT) == (
    C.IX_THETA_FB, C.IX_OMEGA_FB, C.IX_THETA_CMD, C.IX_OMEGA_CMD, C.IX_ID_MEAS, C.IX_IQ_MEAS,
    C.IX_PARK_ANGLE, C.IX_THETA, C.IX_OMEGA, C.IX_IA, C.IX_IB, C.IX_SUM_E2_ALL, C.IX_COUNT_ALL,
    C.IX_SUM_IFF2_ALL, C.IX_MAX_LAG, C.IX_MAX_CURRENT)


@_jit
def _clip(x, bound):
    if x > bound:
        return bound
    if x < -bound:
        return -bound
    return x


@_jit
def _store(obs, i, j, value, bound):
    """obs[i, j] = value clipped to +-bound (0 if non-finite); returns non-finite."""
    if not math.isfinite(value):
        obs[i, j] = 0.0
        return True
    obs[i, j] = _clip(value, bound)
    return False


@_jit
def load_actions(a, dest, offset, par, acc, law, lx):
    """Scale the action rows ``a`` into ``dest[:, offset:]`` (kernel inputs or law gains),
    zero the step's accumulators. Returns the first row that is not finite or has
    an entry outside [-1, 1] (nothing changed then), or -1."""
    n, k = a.shape
    for i in range(n):
        for j in range(k):
            x = a[i, j]
            if not (-1.0 <= x <= 1.0):      # also catches NaN
                return i
    for i in range(n):
        for j in range(k):
            dest[i, offset + j] = a[i, j] * par[i, P_ACT_SCALE + j]
        for j in range(acc.shape[1]):
            acc[i, j] = 0.0
        law[i, lx[IX_LAW_SUM_I2]] = 0.0
    return -1


@_jit
def observe(s, acc, law, a, par, ix, lx, history, context, privileged, bound, reward_bound,
            obs, out):
    """Observation of each drive (row) into ``obs``, its step's physics into ``out``.

    ``history`` (n, 2*h) holds the error signals of the h previous calls, newest
    first; this call writes it into the observation, then pushes its own.
    """
    n_hist = history.shape[1]
    for i in range(s.shape[0]):
        p_unit, v_unit, c_unit = par[i, P_POS_UNIT], par[i, P_VEL_UNIT], par[i, P_CUR_UNIT]
        theta_fb, omega_fb = s[i, ix[IX_THETA_FB]], s[i, ix[IX_OMEGA_FB]]
        theta_cmd, omega_cmd = s[i, ix[IX_THETA_CMD]], s[i, ix[IX_OMEGA_CMD]]
        angle = s[i, ix[IX_PARK_ANGLE]]
        s1, c1 = sincos(angle)
        s2, c2 = 2.0 * s1 * c1, c1 * c1 - s1 * s1
        s4, c4 = 2.0 * s2 * c2, c2 * c2 - s2 * s2
        vals = (
            (theta_cmd - theta_fb) / p_unit,
            (omega_cmd - omega_fb) / v_unit,
            s1, c1, s2, c2, s4, c4,
            omega_cmd / par[i, P_SPEED_UNIT],
            (s[i, ix[IX_ID_MEAS]] - par[i, P_ID_CMD]) / c_unit,
            s[i, ix[IX_IQ_MEAS]] / c_unit,
        )
        nonfinite = False
        for j in range(N_BASE_OBS):
            nonfinite |= _store(obs, i, j, vals[j], bound)
        k = N_BASE_OBS
        for j in range(a.shape[1]):
            obs[i, k] = a[i, j]
            k += 1
        for j in range(n_hist):
            obs[i, k + j] = history[i, j]
        for j in range(n_hist - 1, N_HISTORY_SIGNALS - 1, -1):
            history[i, j] = history[i, j - N_HISTORY_SIGNALS]
        if n_hist > 0:
            history[i, 0] = obs[i, OBS_POSITION_ERROR]
            history[i, 1] = obs[i, OBS_VELOCITY_ERROR]
        k += n_hist
        for j in range(context.shape[1]):
            _store(obs, i, k + j, context[i, j], bound)
        k += context.shape[1]
        if privileged:
            hold = par[i, P_HOLD]
            pv = ((theta_cmd - s[i, ix[IX_THETA]]) / p_unit,
                  (omega_cmd - s[i, ix[IX_OMEGA]]) / v_unit,
                  s[i, ix[IX_IA]] / hold, s[i, ix[IX_IB]] / hold)
            for j in range(N_PRIVILEGED):
                nonfinite |= _store(obs, i, k + j, pv[j], bound)

        n = max(acc[i, ix[IX_COUNT_ALL]], 1.0)
        e2 = acc[i, ix[IX_SUM_E2_ALL]] / n
        i2 = acc[i, ix[IX_SUM_IFF2_ALL]] / n
        l2 = law[i, lx[IX_LAW_SUM_I2]] / n
        lag = acc[i, ix[IX_MAX_LAG]]
        peak = acc[i, ix[IX_MAX_CURRENT]]
        step_loss = lag > par[i, P_FULL_STEP]
        overcurrent = peak > par[i, P_I_LIMIT]
        if not (math.isfinite(e2) and math.isfinite(i2) and math.isfinite(lag)
                and math.isfinite(peak) and math.isfinite(l2)):
            nonfinite = True
        terminated = step_loss or overcurrent or nonfinite
        vel_rms = math.sqrt(e2) if math.isfinite(e2) else math.inf
        cur_rms = math.sqrt(i2) if math.isfinite(i2) else math.inf
        reward = -min(vel_rms / v_unit, reward_bound) - par[i, P_CUR_PEN] * min(
            cur_rms / c_unit, reward_bound)
        if not math.isfinite(reward):
            reward = -reward_bound * (1.0 + par[i, P_CUR_PEN])
        out[i, O_REWARD] = reward
        out[i, O_VEL_RMS] = vel_rms
        out[i, O_LAG] = lag
        out[i, O_IINJ_RMS] = cur_rms
        out[i, O_PEAK_I] = peak
        out[i, O_STEP_LOSS] = 1.0 if step_loss else 0.0
        out[i, O_OVERCURRENT] = 1.0 if overcurrent else 0.0
        out[i, O_NONFINITE] = 1.0 if nonfinite else 0.0
        out[i, O_TERMINATED] = 1.0 if terminated else 0.0
        out[i, O_LAW_RMS] = math.sqrt(l2) if math.isfinite(l2) else math.inf
