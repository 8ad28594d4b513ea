"""One PWM period of a drive, defined once for every loop that runs it.

:func:`law_input` is the damping law of one period, :func:`control_period`
the sample, the controller and the metrics; :func:`.plant.plant_step_in` its
plant steps. The drive's own loop (:mod:`.loop`, a row per drive) and the
SIMD lanes (:mod:`stepdamp_env.lanes`, a structure of arrays) call the same
functions: a row's field j is ``a[at + j*step]`` (``at`` the row's start and
``step`` 1 for a row of its own; in the lanes' workspace ``at`` is the
block's first row times LANES plus the lane, and ``step`` LANES), and
``lanes`` None compiles the drive's loop (with branches) while the lane count
compiles the lanes' (every variant's branches computed and the drive's
selected, the branch-free sine, cosine and logarithm). The arithmetic is the same, in the same order, so both give the
same bits."""

from __future__ import annotations

from numba import njit

from ..fixedmath import sincos_in
from .control import control_step
from .layout import CTRL, INPUT, STATE, ControllerState, LawState, Metrics, Sample
from .plant import harmonics

__all__ = ["resonant_phasor", "law_current", "law_input", "accumulate", "control_period",
           "load_controller", "store_controller", "load_plant", "store_plant", "load_metrics",
           "store_metrics", "load_law", "store_law"]

# No Python error checks on division, no fastmath (see .plant).
_jit_inline = njit(cache=True, error_model="numpy", inline="always")


# ---------------------------------------------------------------------------
# The damping law
# ---------------------------------------------------------------------------
@_jit_inline
def resonant_phasor(kr, ki, a, b, e_w, sin_h, cos_h, dt, limit):
    """A resonant term's coefficients (a, b) (A) after one period: the phasor
    integrates (kr + j ki) times the velocity error ``e_w`` demodulated at the
    harmonic's angle (sin + j cos), each clamped to +-limit (A)."""
    es, ec = e_w * sin_h, e_w * cos_h
    a = a + dt * (kr * es - ki * ec)
    b = b + dt * (ki * es + kr * ec)
    return min(max(a, -limit), limit), min(max(b, -limit), limit)


@_jit_inline
def law_current(lw, e_w, e_theta, s1, c1, dt, lanes=None):
    """One period of the damping law (see ``LAW``): the velocity and high-passed
    position terms, and while ``lw.resonant`` the resonant terms at the Park
    angle whose sine and cosine are given, the sum clamped to +-limit.
    ``lw`` is a :class:`.layout.LawState`; returns (the new state, the law's
    current (A)). ``lanes`` as in :func:`control_period`."""
    e_lp = lw.e_lp + lw.hp_alpha * (e_theta - lw.e_lp)
    i = lw.kv * e_w + lw.kp * (e_theta - e_lp)
    limit = lw.limit
    on = lw.resonant != 0.0
    a1, b1, a2, b2, a4, b4 = lw.a1, lw.b1, lw.a2, lw.b2, lw.a4, lw.b4
    # The resonant terms cost a third of the law: a drive's loop runs them only
    # while on; lanes compute them and select.
    if lanes is not None or on:
        s2, c2, s4, c4 = harmonics(s1, c1)
        n1 = resonant_phasor(lw.kr1, lw.ki1, a1, b1, e_w, s1, c1, dt, limit)
        n2 = resonant_phasor(lw.kr2, lw.ki2, a2, b2, e_w, s2, c2, dt, limit)
        n4 = resonant_phasor(lw.kr4, lw.ki4, a4, b4, e_w, s4, c4, dt, limit)
        with_resonant = (((i + (n1[0] * s1 + n1[1] * c1)) + (n2[0] * s2 + n2[1] * c2))
                         + (n4[0] * s4 + n4[1] * c4))
        a1, b1 = (n1[0] if on else a1), (n1[1] if on else b1)
        a2, b2 = (n2[0] if on else a2), (n2[1] if on else b2)
        a4, b4 = (n4[0] if on else a4), (n4[1] if on else b4)
        i = with_resonant if on else i
    i = min(max(i, -limit), limit)
    return LawState(lw.kv, lw.kp, lw.kr1, lw.ki1, lw.kr2, lw.ki2, lw.kr4, lw.ki4, lw.hp_alpha,
                    limit, e_lp, a1, b1, a2, b2, a4, b4, lw.sum_i2 + i * i, lw.resonant), i


# ---------------------------------------------------------------------------
# The period
# ---------------------------------------------------------------------------
@_jit_inline
def accumulate(m, t, x, obs, win_start, win_end, ref_rate, lanes):
    """The metrics ``m`` (:class:`.layout.Metrics`) with the sample at time ``t``
    (s) of the period's start: plant state ``x``, :class:`.layout.Sample` ``obs``.
    Over all samples the largest lag and current, the velocity error's and the
    position error's squares. In the window (``win_start <= t < win_end``) the velocity error's moments, the
    position error's first two moments, and the velocity error's lock-in
    sums on the detent harmonics h*Nr*w_ref*t (``ref_rate`` = Nr*w_ref,
    timed from the window start, the angle evaluated afresh each sample, so no
    rounding accumulates). Returns (metrics, whether the lock-in angle left
    the lanes' range)."""
    err = obs.omega_cmd - x[1]
    iq_inj = obs.iq_ff
    in_win = (t >= win_start) & (t < win_end)
    ref = ref_rate * (t - win_start)
    (count, sum_e, sum_e2, min_e, max_e, sum_iff2, h1s, h1c, h2s, h2c, h4s, h4c,
     max_lag, max_i, sum_e2_all, n_all, sum_iff2_all, sum_p, sum_p2, sum_p2_all) = m
    perr = obs.theta_cmd - x[0]
    sum_p2_all += perr * perr
    max_lag = max(max_lag, abs(perr))
    max_i = max(max_i, abs(x[2]), abs(x[3]))
    sum_e2_all += err * err
    sum_iff2_all += iq_inj * iq_inj
    n_all += 1.0
    if lanes is not None or in_win:
        lo = err if count == 0.0 else min_e
        hi = err if count == 0.0 else max_e
        s1, c1 = sincos_in(ref, lanes)
        s2, c2, s4, c4 = harmonics(s1, c1)
        min_e = min(lo, err) if in_win else min_e
        max_e = max(hi, err) if in_win else max_e
        count = count + 1.0 if in_win else count
        sum_e = sum_e + err if in_win else sum_e
        sum_e2 = sum_e2 + err * err if in_win else sum_e2
        sum_iff2 = sum_iff2 + iq_inj * iq_inj if in_win else sum_iff2
        h1s = h1s + err * s1 if in_win else h1s
        h1c = h1c + err * c1 if in_win else h1c
        h2s = h2s + err * s2 if in_win else h2s
        h2c = h2c + err * c2 if in_win else h2c
        h4s = h4s + err * s4 if in_win else h4s
        h4c = h4c + err * c4 if in_win else h4c
        sum_p = sum_p + perr if in_win else sum_p
        sum_p2 = sum_p2 + perr * perr if in_win else sum_p2
    return (Metrics(count, sum_e, sum_e2, min_e, max_e, sum_iff2, h1s, h1c, h2s, h2c, h4s, h4c,
                    max_lag, max_i, sum_e2_all, n_all, sum_iff2_all, sum_p, sum_p2, sum_p2_all),
            in_win & ((abs(ref) >= 1e6) | (ref != ref)))


@_jit_inline
def law_input(lw, u, cs, obs, dt, lanes):
    """The damping law of one period on top of the inputs ``u``: its current,
    from the previous period's :class:`.layout.ControllerState` ``cs`` and
    :class:`.layout.Sample` ``obs`` (one period of computation), added to the
    q residual and held for the period. Returns (the law's new
    :class:`.layout.LawState`, the inputs)."""
    lw, i_law = law_current(lw, obs.omega_cmd - cs.omega_fb, obs.theta_cmd - cs.theta_fb_prev,
                            obs.sin_angle, obs.cos_angle, dt, lanes)
    return lw, (u[INPUT.DS1], u[INPUT.DC1], u[INPUT.DS2], u[INPUT.DC2], u[INPUT.DS4],
                u[INPUT.DC4], u[INPUT.IQ] + i_law)


@_jit_inline
def control_period(period, x, cs, v_next, obs, m, q, u, win_start, win_end, ref_rate, lanes,
                   given=None, current_only=None):
    """The sample, control and metrics of PWM period ``period`` (the damping
    law, if any, is in ``u``: :func:`law_input`).

    ``x`` the plant state at the period's start (see :func:`.plant.rk4_step`),
    ``cs`` the :class:`.layout.ControllerState`, ``v_next`` the voltages the
    previous period computed, ``obs`` its :class:`.layout.Sample`, ``m`` the
    :class:`.layout.Metrics`; ``q`` :func:`.control.controller_params`, ``u``
    the external inputs. ``lanes`` None for a drive's own loop; for SIMD lanes
    their count (an int: an array passed into the inlined branches would be
    reference-counted there, and the loop would stay scalar). ``given`` and
    ``current_only``: see :func:`.control.control_step`.

    Returns (cs, the voltages applied during this period (V), the voltages to
    apply next period, the period's sample, the metrics, whether the period
    left the lanes' branch-free path: a Park or lock-in angle beyond 1e6 rad
    or NaN).
    """
    t = period * q[CTRL.DT]
    # Computation delay: this period applies what the previous one computed.
    va, vb = v_next
    cs, v_next, obs, far = control_step(period, x[0], x[2], x[3], cs, q, u, lanes, given,
                                        current_only)
    # What this period applies is, at the next sample, the period that just ended.
    cs = ControllerState(cs.int_d, cs.int_q, cs.theta_fb_prev, cs.omega_fb, cs.pos_int,
                         cs.theta_est, cs.ia_prev, cs.ib_prev, va, vb)
    m, ref_off = accumulate(m, t, x, obs, win_start, win_end, ref_rate, lanes)
    off_path = (abs(obs.angle) >= 1e6) | (obs.angle != obs.angle) | ref_off | far
    return cs, (va, vb), v_next, obs, m, off_path


# ---------------------------------------------------------------------------
# The rows: a drive's STATE and ACC fields, ``a[at + FIELD*step]``
# ---------------------------------------------------------------------------
@_jit_inline
def load_plant(s, at, step):
    """The plant state x (see :func:`.plant.rk4_step`) of a STATE row."""
    return (s[at + STATE.THETA * step], s[at + STATE.OMEGA * step], s[at + STATE.IA * step],
            s[at + STATE.IB * step], s[at + STATE.E_IN * step], s[at + STATE.E_CU * step],
            s[at + STATE.E_DAMP * step], s[at + STATE.E_FRIC * step],
            s[at + STATE.E_LOAD * step])


@_jit_inline
def store_plant(s, at, step, x):
    """:func:`load_plant`'s fields of a STATE row set to ``x``."""
    s[at + STATE.THETA * step] = x[0]
    s[at + STATE.OMEGA * step] = x[1]
    s[at + STATE.IA * step] = x[2]
    s[at + STATE.IB * step] = x[3]
    s[at + STATE.E_IN * step] = x[4]
    s[at + STATE.E_CU * step] = x[5]
    s[at + STATE.E_DAMP * step] = x[6]
    s[at + STATE.E_FRIC * step] = x[7]
    s[at + STATE.E_LOAD * step] = x[8]


@_jit_inline
def load_controller(s, at, step, sin_angle, cos_angle):
    """(period, :class:`.layout.ControllerState`, the voltages to apply next, the
    last :class:`.layout.Sample`) of a STATE row; the sine and cosine of its Park
    angle are given (the q current command is not kept: 0)."""
    cs = ControllerState(s[at + STATE.INT_D * step], s[at + STATE.INT_Q * step],
                         s[at + STATE.THETA_FB_PREV * step], s[at + STATE.OMEGA_FB * step],
                         s[at + STATE.POS_INT * step], s[at + STATE.THETA_EST * step],
                         s[at + STATE.IA_PREV * step], s[at + STATE.IB_PREV * step],
                         s[at + STATE.VA_OLD * step], s[at + STATE.VB_OLD * step])
    obs = Sample(s[at + STATE.THETA_FB * step], s[at + STATE.THETA_CMD * step],
                 s[at + STATE.OMEGA_CMD * step], s[at + STATE.ID_MEAS * step],
                 s[at + STATE.IQ_MEAS * step], 0.0, s[at + STATE.IQ_FF * step],
                 s[at + STATE.PARK_ANGLE * step], sin_angle, cos_angle)
    return (s[at + STATE.PERIOD * step], cs,
            (s[at + STATE.VA_NEXT * step], s[at + STATE.VB_NEXT * step]), obs)


@_jit_inline
def store_controller(s, at, step, period, cs, v_next, obs):
    """:func:`load_controller`'s fields of a STATE row set."""
    s[at + STATE.PERIOD * step] = period
    s[at + STATE.INT_D * step] = cs.int_d
    s[at + STATE.INT_Q * step] = cs.int_q
    s[at + STATE.THETA_FB_PREV * step] = cs.theta_fb_prev
    s[at + STATE.OMEGA_FB * step] = cs.omega_fb
    s[at + STATE.POS_INT * step] = cs.pos_int
    s[at + STATE.THETA_EST * step] = cs.theta_est
    s[at + STATE.IA_PREV * step] = cs.ia_prev
    s[at + STATE.IB_PREV * step] = cs.ib_prev
    s[at + STATE.VA_OLD * step] = cs.va_old
    s[at + STATE.VB_OLD * step] = cs.vb_old
    s[at + STATE.VA_NEXT * step] = v_next[0]
    s[at + STATE.VB_NEXT * step] = v_next[1]
    s[at + STATE.THETA_FB * step] = obs.theta_fb
    s[at + STATE.THETA_CMD * step] = obs.theta_cmd
    s[at + STATE.OMEGA_CMD * step] = obs.omega_cmd
    s[at + STATE.ID_MEAS * step] = obs.id
    s[at + STATE.IQ_MEAS * step] = obs.iq
    s[at + STATE.IQ_FF * step] = obs.iq_ff
    s[at + STATE.PARK_ANGLE * step] = obs.angle


def _row_io(kind, cls):
    """The inlined reader and writer of a row as the namedtuple ``cls`` of its
    fields in order (written out from them, so the two cannot drift apart)."""
    fields = range(len(cls._fields))
    read = ", ".join(f"a[at + {j} * step]" for j in fields)
    write = "".join(f"    a[at + {j} * step] = v[{j}]\n" for j in fields)
    namespace: dict = {"cls": cls}
    exec(f"def load(a, at, step):\n    return cls({read})\n"
         f"def store(a, at, step, v):\n{write}", namespace)
    inline = njit(error_model="numpy", inline="always")
    load, store = inline(namespace["load"]), inline(namespace["store"])
    load.__doc__ = f"The :class:`.layout.{cls.__name__}` of an {kind} row."
    store.__doc__ = f"An {kind} row set to the :class:`.layout.{cls.__name__}` ``v``."
    return load, store


load_metrics, store_metrics = _row_io("ACC", Metrics)
load_law, store_law = _row_io("LAW", LawState)
