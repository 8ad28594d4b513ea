"""Compiled per-step helpers of StepperDamp-v0, and the layouts they write.

The layouts are declared once here (:func:`stepdamp_env.fields.layout`); the
kernel's state and accumulator entries the step reads come in as the array
``KERNEL_INDEX`` (named by ``KERNEL_FIELDS``, shared with v1).
:mod:`stepdamp_env.env.layout` gives the observation positions lower-case names
for baselines and agents.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import kernel as K
from ..fields import layout
from ..fixedmath import sincos

__all__ = ["OBS_BOUND", "OBS", "PRIVILEGED", "PARAM", "OUT", "OUT_FIELDS", "KERNEL_FIELDS",
           "KERNEL_INDEX", "load_actions", "observe", "physics_info",
           # The pieces v1's step shares (env/v1_compiled.py).
           "scale_actions", "store_clipped", "harmonics", "rms", "store_privileged",
           "step_physics", "write_out"]

_jit = njit(cache=True, error_model="numpy")

# Bound of the scaled observations (other than sin/cos and the last action):
# states past it are clipped; a healthy drive stays well inside.
OBS_BOUND = 10.0

# Observation entries (float32 row): what a drive senses, scaled; then the last
# action (k entries), then, with ``privileged``, the PRIVILEGED block.
OBS = layout("Observation", """
    POSITION_ERROR  (theta_cmd - encoder angle) / full step
    VELOCITY_ERROR  (omega_cmd - filtered encoder velocity) / held command speed
    SIN_X           sin, cos of the electrical (Park) angle x, of 2x and of 4x
    COS_X
    SIN_2X
    COS_2X
    SIN_4X
    COS_4X
    SPEED_COMMAND   omega_cmd / speed normaliser
    ID              measured id / holding current
    IQ              measured iq / holding current
""")
PRIVILEGED = layout("Privileged", """
    POSITION_ERROR  true (theta_cmd - theta) / full step
    VELOCITY_ERROR  true (omega_cmd - omega) / held command speed
    IA              true ia / holding current
    IB              true ib / holding current
""")

# Per-drive episode constants (float64 row).
PARAM = layout("EpisodeRow", """
    FULL_STEP    one full step (rad)
    W_REF        |held command speed| (rad/s): normaliser of velocity errors
    HOLD         holding current (A): normaliser of currents
    SPEED_SCALE  normaliser of the speed command (rad/s)
    I_LIMIT      unsafe phase current (A)
    CUR_PEN      weight of the injected-current penalty
    TERM_PEN     penalty on termination
    ACT_SCALE[7] physical size of action entry j = 1.0 (N*m or A)
    LAG_LIMIT    lag past which the episode ends with a step loss (rad)
""")

# Per-step physical outputs (float64 row); v1's begin with these.
OUT_FIELDS = """
    REWARD
    VEL_RMS      rms of w_cmd - w over the step's PWM samples (rad/s)
    LAG          max |theta_cmd - theta| over the step (rad)
    IINJ_RMS     rms injected q current (the base controller's and the agent's;
                   v1: and the damping law's) (A)
    PEAK_I       max |phase current| (A)
    STEP_LOSS    1.0 if the lag passed a full step
    OVERCURRENT  1.0 if a phase current passed the limit
    NONFINITE    1.0 if the plant or the observation went non-finite
    TERMINATED   1.0 if any of the three
"""
OUT = layout("StepOutput", OUT_FIELDS)


def physics_info(out_row: np.ndarray) -> dict:
    """The info entries of one drive's step from its ``out`` row (OUT's entries)."""
    return {"velocity_error_rms_rad_s": float(out_row[OUT.VEL_RMS]),
            "lag_rad": float(out_row[OUT.LAG]),
            "injected_current_rms_a": float(out_row[OUT.IINJ_RMS]),
            "peak_current_a": float(out_row[OUT.PEAK_I]),
            "step_loss": bool(out_row[OUT.STEP_LOSS]),
            "overcurrent": bool(out_row[OUT.OVERCURRENT])}


# The kernel state and accumulator entries the step reads (positions in
# KERNEL_INDEX), shared by both tasks.
KERNEL_FIELDS = layout("KernelFields", """
    THETA_FB
    OMEGA_FB
    THETA_CMD
    OMEGA_CMD
    ID_MEAS
    IQ_MEAS
    PARK_ANGLE
    THETA
    OMEGA
    IA
    IB
    SUM_E2_ALL
    COUNT_ALL
    SUM_IFF2_ALL
    MAX_LAG
    MAX_CURRENT
""")
KERNEL_INDEX = np.array([getattr(K.STATE, f) if f in K.STATE._fields else getattr(K.ACC, f)
                         for f in KERNEL_FIELDS._fields], dtype=np.int64)


@_jit
def _clip(x, bound):
    if x > bound:
        return bound
    if x < -bound:
        return -bound
    return x


@_jit
def store_clipped(obs, i, j, value, bound):
    """Write ``value`` clipped to +-bound into obs[i, j]; a non-finite one as 0.
    Returns whether it was non-finite."""
    if not math.isfinite(value):
        obs[i, j] = 0.0
        return True
    obs[i, j] = _clip(value, bound)
    return False


@_jit
def harmonics(angle):
    """sin and cos of ``angle`` (rad), of twice and of four times it."""
    s1, c1 = sincos(angle)
    s2, c2 = 2.0 * s1 * c1, c1 * c1 - s1 * s1
    s4, c4 = 2.0 * s2 * c2, c2 * c2 - s2 * s2
    return s1, c1, s2, c2, s4, c4


@_jit
def rms(mean_square):
    """sqrt of a mean square; inf when it is not finite."""
    return math.sqrt(mean_square) if math.isfinite(mean_square) else math.inf


@_jit
def _first_bad_row(a):
    """The first row of ``a`` with an entry outside [-1, 1] or not finite, or -1."""
    n, k = a.shape
    for i in range(n):
        for j in range(k):
            x = a[i, j]
            if not (-1.0 <= x <= 1.0):      # also catches NaN
                return i
    return -1


@_jit
def store_privileged(obs, i, k, s, ix, theta_cmd, omega_cmd, pos_unit, vel_unit, hold, bound):
    """The PRIVILEGED block of drive i from obs[i, k]; returns whether one was non-finite."""
    pv = ((theta_cmd - s[i, ix[KERNEL_FIELDS.THETA]]) / pos_unit,
          (omega_cmd - s[i, ix[KERNEL_FIELDS.OMEGA]]) / vel_unit,
          s[i, ix[KERNEL_FIELDS.IA]] / hold, s[i, ix[KERNEL_FIELDS.IB]] / hold)
    nonfinite = False
    for j in range(len(PRIVILEGED)):
        nonfinite |= store_clipped(obs, i, k + j, pv[j], bound)
    return nonfinite


@_jit
def step_physics(acc, i, ix, lag_limit, current_limit):
    """Drive i's step from its accumulators: (samples, mean square velocity error,
    mean square injected current, max lag, peak current, step loss, overcurrent)."""
    n = max(acc[i, ix[KERNEL_FIELDS.COUNT_ALL]], 1.0)
    lag = acc[i, ix[KERNEL_FIELDS.MAX_LAG]]
    peak = acc[i, ix[KERNEL_FIELDS.MAX_CURRENT]]
    return (n, acc[i, ix[KERNEL_FIELDS.SUM_E2_ALL]] / n, acc[i, ix[KERNEL_FIELDS.SUM_IFF2_ALL]] / n,
            lag, peak, lag > lag_limit, peak > current_limit)


@_jit
def write_out(out, i, reward, vel_rms, lag, cur_rms, peak, step_loss, overcurrent, nonfinite,
              terminated):
    """Row i of ``out`` (OUT's entries; v1's OUT begins with them)."""
    out[i, OUT.REWARD] = reward
    out[i, OUT.VEL_RMS] = vel_rms
    out[i, OUT.LAG] = lag
    out[i, OUT.IINJ_RMS] = cur_rms
    out[i, OUT.PEAK_I] = peak
    out[i, OUT.STEP_LOSS] = 1.0 if step_loss else 0.0
    out[i, OUT.OVERCURRENT] = 1.0 if overcurrent else 0.0
    out[i, OUT.NONFINITE] = 1.0 if nonfinite else 0.0
    out[i, OUT.TERMINATED] = 1.0 if terminated else 0.0


@_jit
def scale_actions(a, dest, offset, par, scale_at, acc):
    """dest[i, offset + j] = a[i, j] * par[i, scale_at + j] and acc zeroed, for each row;
    or, if a row is not finite or has an entry outside [-1, 1], nothing changed
    and that row returned (else -1). Rows are indexed in place: per-row views
    would cost more than the arithmetic."""
    bad = _first_bad_row(a)
    if bad >= 0:
        return bad
    n, k = a.shape
    for i in range(n):
        for j in range(k):
            dest[i, offset + j] = a[i, j] * par[i, scale_at + j]
        for j in range(acc.shape[1]):
            acc[i, j] = 0.0
    return -1


@_jit
def load_actions(a, u, acc, par, offset):
    """Scale the action rows ``a`` into the input rows ``u`` and zero ``acc``
    (:func:`scale_actions`); returns the first bad row or -1."""
    return scale_actions(a, u, offset, par, PARAM.ACT_SCALE, acc)


@_jit
def observe(s, acc, a, par, ix, privileged, obs, out):
    """Scaled observation of each drive (row) into ``obs``, its step's physics into ``out``."""
    bound = OBS_BOUND
    for i in range(s.shape[0]):
        full_step, w_ref, hold = par[i, PARAM.FULL_STEP], par[i, PARAM.W_REF], par[i, PARAM.HOLD]
        theta_fb, omega_fb = s[i, ix[KERNEL_FIELDS.THETA_FB]], s[i, ix[KERNEL_FIELDS.OMEGA_FB]]
        theta_cmd, omega_cmd = s[i, ix[KERNEL_FIELDS.THETA_CMD]], s[i, ix[KERNEL_FIELDS.OMEGA_CMD]]
        s1, c1, s2, c2, s4, c4 = harmonics(s[i, ix[KERNEL_FIELDS.PARK_ANGLE]])
        # In the order of OBS.
        vals = (
            (theta_cmd - theta_fb) / full_step,
            (omega_cmd - omega_fb) / w_ref,
            s1, c1, s2, c2, s4, c4,
            omega_cmd / par[i, PARAM.SPEED_SCALE],
            s[i, ix[KERNEL_FIELDS.ID_MEAS]] / hold,
            s[i, ix[KERNEL_FIELDS.IQ_MEAS]] / hold,
        )
        nonfinite = False
        for j in range(len(OBS)):
            nonfinite |= store_clipped(obs, i, j, vals[j], bound)
        k = len(OBS)
        for j in range(a.shape[1]):
            obs[i, k] = a[i, j]
            k += 1
        if privileged:
            nonfinite |= store_privileged(obs, i, k, s, ix, theta_cmd, omega_cmd, full_step,
                                          w_ref, hold, bound)

        _, e2, i2, lag, peak, step_loss, overcurrent = step_physics(
            acc, i, ix, par[i, PARAM.LAG_LIMIT], par[i, PARAM.I_LIMIT])
        # A non-finite plant ends the episode; the reward stays finite.
        if not (math.isfinite(e2) and math.isfinite(i2) and math.isfinite(lag)
                and math.isfinite(peak)):
            nonfinite = True
        terminated = step_loss or overcurrent or nonfinite
        reward = -(e2 / (w_ref * w_ref)) - par[i, PARAM.CUR_PEN] * i2 / (hold * hold)
        if not math.isfinite(reward):
            reward = -1.0
        if terminated:
            reward -= par[i, PARAM.TERM_PEN]
        write_out(out, i, reward, rms(e2), lag, rms(i2), peak, step_loss, overcurrent,
                  nonfinite, terminated)
