"""Compiled per-step helpers of ``StepperDamp-v1``, and the layouts they write.

The layouts are declared once here (:func:`stepdamp_env.fields.layout`); the
kernel's state and accumulator positions come in as the array ``ix``
(:data:`stepdamp_env.env.compiled.KERNEL_INDEX`, named by ``KERNEL_FIELDS``),
the law's as ``lx`` (:data:`LAW_INDEX`), bounds as arguments.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .. import kernel as K
from ..fields import layout
from .. import fixedmath as fm
from . import compiled as C

__all__ = ["OBS", "HISTORY", "PARAM", "OUT", "LAW_FIELDS", "LAW_INDEX", "load_actions",
           "load_gain_phase", "observe"]

_jit = njit(cache=True, error_model="numpy")

# Observation entries (float32 row), in units the motor sets (see the env
# docstring); then the last action (k), the history (HISTORY per sample, h
# samples), the context, the privileged block (compiled.PRIVILEGED).
OBS = layout("ObservationV1", """
    POSITION_ERROR  (theta_cmd - encoder angle) / ripple position unit
    VELOCITY_ERROR  (omega_cmd - velocity estimate) / ripple velocity unit
    SIN_X           sin, cos of the electrical (Park) angle x, 2x, 4x
    COS_X
    SIN_2X
    COS_2X
    SIN_4X
    COS_4X
    SPEED_COMMAND   omega_cmd / (2*pi * predicted h = 1 resonance of the nominal motor)
    ID_ERROR        (measured id - its command) / ripple current unit
    IQ              measured iq / ripple current unit
""")
HISTORY = layout("HistorySample", """
    POSITION_ERROR  the observation's, of an earlier call
    VELOCITY_ERROR
""")

# Per-drive episode constants (float64 row).
PARAM = layout("EpisodeRowV1", """
    POS_UNIT     ripple position unit (rad)
    VEL_UNIT     ripple velocity unit (rad/s)
    CUR_UNIT     ripple current unit (A)
    SPEED_UNIT   normaliser of the speed command (rad/s)
    ID_CMD       the drive's d current command (A)
    FULL_STEP    one full step (rad)
    HOLD         holding current (A)
    I_LIMIT      unsafe phase current (A)
    CUR_PEN      weight of the current penalty
    ACT_SCALE[8] physical size of action entry j at 1.0
    LAG_LIMIT    lag past which the episode ends with a step loss (rad)
""")

# Per-step physical outputs (float64 row): v0's, then the damping law's current.
OUT = layout("StepOutputV1", C.OUT_FIELDS + """
    LAW_RMS      rms current of the damping law (A)
""")
assert OUT._fields[:len(C.OUT)] == C.OUT._fields

LAW_FIELDS = layout("LawFields", """
    SUM_I2
""")
LAW_INDEX = np.array([getattr(K.LAW, f) for f in LAW_FIELDS._fields], dtype=np.int64)
KERNEL_FIELDS = C.KERNEL_FIELDS
PRIVILEGED = C.PRIVILEGED


@_jit
def load_actions(a, dest, offset, par, acc, law, lx):
    """Scale the action rows ``a`` into ``dest[:, offset:]`` (kernel inputs or law gains),
    zero the step's accumulators. Returns the first row that is not finite or has
    an entry outside [-1, 1] (nothing changed then), or -1."""
    bad = C.scale_actions(a, dest, offset, par, PARAM.ACT_SCALE, acc)
    if bad < 0:
        for i in range(a.shape[0]):
            law[i, lx[LAW_FIELDS.SUM_I2]] = 0.0
    return bad


@_jit
def load_gain_phase(a, law, offset, par, acc, lx, phase_limit_rad):
    """The "gain-phase" action rows ``a`` (gain, phase) into the law's (kv, kp) at
    ``law[:, offset:]``: kv = g*cos(phi), kp = -g*sin(phi) with g = max(gain, 0)
    and phi = phase * ``phase_limit_rad``, each times its scale; the step's
    accumulators zeroed. Returns the first row that is not finite or has an entry
    outside [-1, 1] (nothing changed then), or -1."""
    n, k = a.shape
    for i in range(n):
        for j in range(k):
            if not (-1.0 <= a[i, j] <= 1.0):       # also catches NaN
                return i
    for i in range(n):
        g = max(float(a[i, 0]), 0.0)
        s, c = fm.sincos(float(a[i, 1]) * phase_limit_rad)
        law[i, offset] = g * c * par[i, PARAM.ACT_SCALE]
        law[i, offset + 1] = -g * s * par[i, PARAM.ACT_SCALE + 1]
        for j in range(acc.shape[1]):
            acc[i, j] = 0.0
        law[i, lx[LAW_FIELDS.SUM_I2]] = 0.0
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
        p_unit, v_unit, c_unit = par[i, PARAM.POS_UNIT], par[i, PARAM.VEL_UNIT], par[i, PARAM.CUR_UNIT]
        theta_fb, omega_fb = s[i, ix[KERNEL_FIELDS.THETA_FB]], s[i, ix[KERNEL_FIELDS.OMEGA_FB]]
        theta_cmd, omega_cmd = s[i, ix[KERNEL_FIELDS.THETA_CMD]], s[i, ix[KERNEL_FIELDS.OMEGA_CMD]]
        s1, c1, s2, c2, s4, c4 = C.harmonics(s[i, ix[KERNEL_FIELDS.PARK_ANGLE]])
        vals = (
            (theta_cmd - theta_fb) / p_unit,
            (omega_cmd - omega_fb) / v_unit,
            s1, c1, s2, c2, s4, c4,
            omega_cmd / par[i, PARAM.SPEED_UNIT],
            (s[i, ix[KERNEL_FIELDS.ID_MEAS]] - par[i, PARAM.ID_CMD]) / c_unit,
            s[i, ix[KERNEL_FIELDS.IQ_MEAS]] / c_unit,
        )
        nonfinite = False
        for j in range(len(OBS)):
            nonfinite |= C.store_clipped(obs, i, j, vals[j], bound)
        k = len(OBS)
        for j in range(a.shape[1]):
            obs[i, k] = a[i, j]
            k += 1
        for j in range(n_hist):
            obs[i, k + j] = history[i, j]
        for j in range(n_hist - 1, len(HISTORY) - 1, -1):
            history[i, j] = history[i, j - len(HISTORY)]
        if n_hist > 0:
            history[i, HISTORY.POSITION_ERROR] = obs[i, OBS.POSITION_ERROR]
            history[i, HISTORY.VELOCITY_ERROR] = obs[i, OBS.VELOCITY_ERROR]
        k += n_hist
        for j in range(context.shape[1]):
            C.store_clipped(obs, i, k + j, context[i, j], bound)
        k += context.shape[1]
        if privileged:
            nonfinite |= C.store_privileged(obs, i, k, s, ix, theta_cmd, omega_cmd, p_unit,
                                            v_unit, par[i, PARAM.HOLD], bound)

        n, e2, i2, lag, peak, step_loss, overcurrent = C.step_physics(
            acc, i, ix, par[i, PARAM.LAG_LIMIT], par[i, PARAM.I_LIMIT])
        l2 = law[i, lx[LAW_FIELDS.SUM_I2]] / n
        if not (math.isfinite(e2) and math.isfinite(i2) and math.isfinite(lag)
                and math.isfinite(peak) and math.isfinite(l2)):
            nonfinite = True
        terminated = step_loss or overcurrent or nonfinite
        vel_rms, cur_rms = C.rms(e2), C.rms(i2)
        reward = -min(vel_rms / v_unit, reward_bound) - par[i, PARAM.CUR_PEN] * min(
            cur_rms / c_unit, reward_bound)
        if not math.isfinite(reward):
            reward = -reward_bound * (1.0 + par[i, PARAM.CUR_PEN])
        C.write_out(out, i, reward, vel_rms, lag, cur_rms, peak, step_loss, overcurrent,
                    nonfinite, terminated)
        out[i, OUT.LAW_RMS] = C.rms(l2)
