"""Compiled per-step helpers of the environments, and the layouts they write.

The observation and parameter-row positions are defined here, in the module
whose compiled code uses them: numba freezes module globals into its on-disk
cache and only notices changes to this file, so a layout defined elsewhere
could go stale in the cache. The helpers depend on no other module's compiled
code either (the kernel's layout indices come in as the array ``KERNEL_INDEX``)
for the same reason. :mod:`stepdamp_env.env.layout` gives the positions names.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import kernel as K
from ..fixedmath import sincos

__all__ = ["OBS_BOUND", "N_BASE_OBS", "N_PRIVILEGED", "N_PAR", "N_OUT", "MAX_ACT_DIM",
           "KERNEL_INDEX", "load_actions", "observe"]

_jit = njit(cache=True, error_model="numpy")

# Bound of the scaled observations (other than sin/cos and the last action):
# states past it are clipped; a healthy drive stays well inside.
OBS_BOUND = 10.0

# Observation entries (float32 row): what a drive senses, scaled.
OBS_POSITION_ERROR = 0   # (theta_cmd - encoder angle) / full step
OBS_VELOCITY_ERROR = 1   # (omega_cmd - filtered encoder velocity) / held command speed
OBS_SIN_X = 2            # sin, cos of the electrical (Park) angle x, of 2x and of 4x
OBS_COS_X = 3
OBS_SIN_2X = 4
OBS_COS_2X = 5
OBS_SIN_4X = 6
OBS_COS_4X = 7
OBS_SPEED_COMMAND = 8    # omega_cmd / speed normaliser
OBS_ID = 9               # measured id / holding current
OBS_IQ = 10              # measured iq / holding current
N_BASE_OBS = 11          # then the last action (k entries), then the privileged block
# Privileged entries, counted from the end of the last action.
PRIV_POSITION_ERROR = 0  # true (theta_cmd - theta) / full step
PRIV_VELOCITY_ERROR = 1  # true (omega_cmd - omega) / held command speed
PRIV_IA = 2              # true ia / holding current
PRIV_IB = 3              # true ib / holding current
N_PRIVILEGED = 4

# Per-drive episode constants (float64 row).
P_FULL_STEP = 0     # one full step (rad)
P_W_REF = 1         # |held command speed| (rad/s): normaliser of velocity errors
P_HOLD = 2          # holding current (A): normaliser of currents
P_SPEED_SCALE = 3   # normaliser of the speed command (rad/s)
P_I_LIMIT = 4       # unsafe phase current (A)
P_CUR_PEN = 5       # weight of the injected-current penalty
P_TERM_PEN = 6      # penalty on termination
P_ACT_SCALE = 7     # first of MAX_ACT_DIM columns: physical size of action entry j = 1.0 (N*m or A)
MAX_ACT_DIM = 7
N_PAR = P_ACT_SCALE + MAX_ACT_DIM

# Per-step physical outputs (float64 row).
O_REWARD = 0
O_VEL_RMS = 1       # rms of w_cmd - w over the step's PWM samples (rad/s)
O_LAG = 2           # max |theta_cmd - theta| over the step (rad)
O_IINJ_RMS = 3      # rms injected q current (feedforward + residual) (A)
O_PEAK_I = 4        # max |phase current| (A)
O_STEP_LOSS = 5
O_OVERCURRENT = 6
O_NONFINITE = 7
O_TERMINATED = 8
N_OUT = 9

# Positions in KERNEL_INDEX of the kernel's state and accumulator entries.
IX_THETA_FB = 0
IX_OMEGA_FB = 1
IX_THETA_CMD = 2
IX_OMEGA_CMD = 3
IX_ID_MEAS = 4
IX_IQ_MEAS = 5
IX_PARK_ANGLE = 6
IX_THETA = 7
IX_OMEGA = 8
IX_IA = 9
IX_IB = 10
IX_SUM_E2_ALL = 11
IX_COUNT_ALL = 12
IX_SUM_IFF2_ALL = 13
IX_MAX_LAG = 14
IX_MAX_CURRENT = 15
KERNEL_INDEX = np.array([K.STATE.THETA_FB, K.STATE.OMEGA_FB, K.STATE.THETA_CMD, K.STATE.OMEGA_CMD,
                         K.STATE.ID_MEAS, K.STATE.IQ_MEAS, K.STATE.PARK_ANGLE, K.STATE.THETA, K.STATE.OMEGA,
                         K.STATE.IA, K.STATE.IB, K.ACC.SUM_E2_ALL, K.ACC.COUNT_ALL, K.ACC.SUM_IFF2_ALL,
                         K.ACC.MAX_LAG, K.ACC.MAX_CURRENT], dtype=np.int64)


@_jit
def _clip(x, bound):
    if x > bound:
        return bound
    if x < -bound:
        return -bound
    return x


@_jit
def _store(obs, i, j, value, bound):
    """Write ``value`` clipped to +-bound into obs[i, j]; a non-finite one as 0.
    Returns whether it was non-finite."""
    if not math.isfinite(value):
        obs[i, j] = 0.0
        return True
    obs[i, j] = _clip(value, bound)
    return False


@_jit
def load_actions(a, u, acc, par, offset):
    """Scale the action rows ``a`` into the input rows ``u`` and zero ``acc``.

    Returns the first row that is not finite or has an entry outside [-1, 1]
    (nothing is changed then), or -1. Rows are indexed in place: per-row views
    would cost more than the arithmetic.
    """
    n, k = a.shape
    for i in range(n):
        for j in range(k):
            x = a[i, j]
            if not (-1.0 <= x <= 1.0):      # also catches NaN
                return i
    for i in range(n):
        for j in range(k):
            u[i, offset + j] = a[i, j] * par[i, P_ACT_SCALE + j]
        for j in range(acc.shape[1]):
            acc[i, j] = 0.0
    return -1


@_jit
def observe(s, acc, a, par, ix, privileged, obs, out):
    """Scaled observation of each drive (row) into ``obs``, its step's physics into ``out``."""
    bound = OBS_BOUND
    for i in range(s.shape[0]):
        full_step, w_ref, hold = par[i, P_FULL_STEP], par[i, P_W_REF], par[i, P_HOLD]
        theta_fb, omega_fb = s[i, ix[IX_THETA_FB]], s[i, ix[IX_OMEGA_FB]]
        theta_cmd, omega_cmd = s[i, ix[IX_THETA_CMD]], s[i, ix[IX_OMEGA_CMD]]
        angle = s[i, ix[IX_PARK_ANGLE]]
        s1, c1 = sincos(angle)
        s2, c2 = 2.0 * s1 * c1, c1 * c1 - s1 * s1
        s4, c4 = 2.0 * s2 * c2, c2 * c2 - s2 * s2
        # In the order of the OBS_* positions 0 .. N_BASE_OBS - 1.
        vals = (
            (theta_cmd - theta_fb) / full_step,
            (omega_cmd - omega_fb) / w_ref,
            s1, c1, s2, c2, s4, c4,
            omega_cmd / par[i, P_SPEED_SCALE],
            s[i, ix[IX_ID_MEAS]] / hold,
            s[i, ix[IX_IQ_MEAS]] / hold,
        )
        nonfinite = False
        for j in range(N_BASE_OBS):
            nonfinite |= _store(obs, i, j, vals[j], bound)
        k = N_BASE_OBS
        for j in range(a.shape[1]):
            obs[i, k] = a[i, j]
            k += 1
        if privileged:
            pv = ((theta_cmd - s[i, ix[IX_THETA]]) / full_step,
                  (omega_cmd - s[i, ix[IX_OMEGA]]) / w_ref,
                  s[i, ix[IX_IA]] / hold, s[i, ix[IX_IB]] / hold)
            for j in range(N_PRIVILEGED):
                nonfinite |= _store(obs, i, k + j, pv[j], bound)

        n = max(acc[i, ix[IX_COUNT_ALL]], 1.0)
        e2 = acc[i, ix[IX_SUM_E2_ALL]] / n
        i2 = acc[i, ix[IX_SUM_IFF2_ALL]] / n
        lag = acc[i, ix[IX_MAX_LAG]]
        peak = acc[i, ix[IX_MAX_CURRENT]]
        step_loss = lag > full_step
        overcurrent = peak > par[i, P_I_LIMIT]
        # A non-finite plant ends the episode; the reward stays finite.
        if not (math.isfinite(e2) and math.isfinite(i2) and math.isfinite(lag)
                and math.isfinite(peak)):
            nonfinite = True
        terminated = step_loss or overcurrent or nonfinite
        reward = -(e2 / (w_ref * w_ref)) - par[i, P_CUR_PEN] * i2 / (hold * hold)
        if not math.isfinite(reward):
            reward = -1.0
        if terminated:
            reward -= par[i, P_TERM_PEN]
        out[i, O_REWARD] = reward
        out[i, O_VEL_RMS] = math.sqrt(e2) if math.isfinite(e2) else math.inf
        out[i, O_LAG] = lag
        out[i, O_IINJ_RMS] = math.sqrt(i2) if math.isfinite(i2) else math.inf
        out[i, O_PEAK_I] = peak
        out[i, O_STEP_LOSS] = 1.0 if step_loss else 0.0
        out[i, O_OVERCURRENT] = 1.0 if overcurrent else 0.0
        out[i, O_NONFINITE] = 1.0 if nonfinite else 0.0
        out[i, O_TERMINATED] = 1.0 if terminated else 0.0
