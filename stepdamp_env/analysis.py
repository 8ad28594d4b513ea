"""Small-signal analysis of the open-loop drive at constant speed: the mid-band.

The rotor on its field spring, the two windings and the drive law, written in
the frame of the command's electrical angle x_c = Nr*theta_cmd, which turns at
w_e = Nr*w_c (w_c the command speed, rad/s). State z = (eps, nu, i_d, i_q) plus
the current loops' integrators (I_d, I_q) in current mode:

    eps' = Nr*nu                         eps = Nr*theta - x_c (rad), nu = w - w_c
    J*nu' = Km*(-i_d*sin(eps) + i_q*cos(eps)) - D*w - Fs*sign(w_c) - load_torque
    L*i_d' = v_d - R*i_d + w_e*L*i_q + Km*w*sin(eps)
    L*i_q' = v_q - R*i_q - w_e*L*i_d - Km*w*cos(eps)

(the plant of docs/model.md turned into that frame; the back-EMF Km*w along the
rotor's q axis). The drive sets (v_d, v_q):

* ``drive_mode="current"``: a PI per axis on i_d* = holding_current, i_q* = 0,
  with the drive's gains (``SystemParams.current_gains``), in continuous time;
* ``drive_mode="voltage"``: the winding model's steady-state voltages,
  v_d = R*i_d* - w_e*L*i_q*, v_q = R*i_q* + w_e*L*i_d* + Km*w_c, which the
  state does not change; past the bridge's circle Vdc/sqrt(2) (the radius
  the three-leg bridge reaches at every angle) they pass the bridge's
  describing function (:func:`bridge_gain`).

The detent torque is left out: at constant speed it is the forcing (its
stiffness averages to zero over an electrical turn), not part of the loop.
The equilibrium (nu = 0) is solved by Newton's method and the Jacobian taken by
central differences; its eigenvalues give the damping of the rotor mode at
each speed. With a voltage-fed winding the currents lag the back-EMF that an
oscillation induces, and over a band of speeds the torque they make pushes
the oscillation instead of damping it: the mid-band instability.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from . import fixedmath as fm
from .params import ParameterError, SystemParams

__all__ = ["OperatingPoint", "MidBand", "RotorMode", "operating_point", "jacobian",
           "rotor_damping", "bridge_limit_rps", "bridge_gain", "midband", "MIDBAND_SCAN_RPS",
           "HIGH_RIPPLE", "BAND_SETTLE_S", "undamped_ripple", "MeasuredBand", "measured_band"]

TWO_PI = 2.0 * math.pi
#: Speeds (rev/s) :func:`midband` scans: (lowest, highest, step).
MIDBAND_SCAN_RPS = (0.25, 30.0, 0.05)


@dataclass(frozen=True)
class OperatingPoint:
    """Steady state at a constant command speed: load angle ``eps_rad``
    (electrical, negative when the rotor trails), currents ``i_d_a``, ``i_q_a`` (A)
    in the command's frame, applied voltages ``v_d_v``, ``v_q_v`` (V) and whether
    the bridge limits them (``saturated``)."""

    speed_rps: float
    eps_rad: float
    i_d_a: float
    i_q_a: float
    v_d_v: float
    v_q_v: float
    saturated: bool


@functools.lru_cache(maxsize=1)
def _turn_table() -> tuple[np.ndarray, np.ndarray]:
    """(sin, cos) of 720 angles over a turn, at first use: fm.sincos_array is
    compiled code, and importing this module must compile nothing."""
    sin, cos = fm.sincos_array(np.linspace(0.0, TWO_PI, 720, endpoint=False))
    sin.flags.writeable = cos.flags.writeable = False      # shared by every call
    return sin, cos


@functools.lru_cache(maxsize=4096)
def bridge_gain(amplitude_v: float, vdc: float) -> complex:
    """Fundamental of what the three-leg bridge applies, per volt asked, for a
    winding-voltage vector of ``amplitude_v`` turning a full circle: the SVPWM
    legs of the kernel (common-mode centred, each clamped to [0, Vdc]), averaged
    over the turn (a describing function; 1 up to Vdc/sqrt(2))."""
    sin, cos = _turn_table()
    va, vb = amplitude_v * cos, amplitude_v * sin
    vmax = np.maximum(np.maximum(va, vb), 0.0)
    vmin = np.minimum(np.minimum(va, vb), 0.0)
    v0 = 0.5 * vdc - 0.5 * (vmax + vmin)
    gamma = np.clip(v0, 0.0, vdc)
    a = np.clip(va + v0, 0.0, vdc) - gamma
    b = np.clip(vb + v0, 0.0, vdc) - gamma
    # (a + jb) e^{-j angle} in real arithmetic (numpy's complex loops may fuse).
    return complex(float(np.mean(a * cos + b * sin)),
                   float(np.mean(b * cos - a * sin))) / amplitude_v


def _voltage_mode_voltages(system: SystemParams, w_c: float) -> tuple[float, float, bool]:
    """(v_d, v_q, saturated) of the voltage-mode law at command speed ``w_c`` (rad/s),
    through the bridge (:func:`bridge_gain`) past its circle Vdc/sqrt(2)."""
    m, d = system.motor, system.drive
    w_e = m.Nr * w_c
    vd = m.R * d.holding_current
    vq = w_e * m.L * d.holding_current + m.Km * w_c
    mag = fm.hypot(vd, vq)
    if mag > d.Vdc / math.sqrt(2.0):
        g = complex(vd, vq) * bridge_gain(mag, d.Vdc)
        return g.real, g.imag, True
    return vd, vq, False


def _rhs(system: SystemParams, w_c: float, z: np.ndarray) -> np.ndarray:
    """Time derivative of the state ``z`` at command speed ``w_c`` (rad/s)."""
    m, d = system.motor, system.drive
    eps, nu, i_d, i_q = z[0], z[1], z[2], z[3]
    w = w_c + nu
    w_e = m.Nr * w_c
    s, c = fm.sin(eps), fm.cos(eps)
    if d.drive_mode == "voltage":
        vd, vq, _ = _voltage_mode_voltages(system, w_c)
        extra: list[float] = []
    else:
        kp, ki = system.current_gains()
        e_d, e_q = d.holding_current - i_d, 0.0 - i_q
        vd, vq = kp * e_d + z[4], kp * e_q + z[5]
        extra = [ki * e_d, ki * e_q]
    fric = m.Fs * (1.0 if w_c > 0 else -1.0 if w_c < 0 else 0.0)
    torque = m.Km * (-i_d * s + i_q * c) - m.D * w - fric - m.load_torque
    out = [m.Nr * nu, torque / m.J,
           (vd - m.R * i_d + w_e * m.L * i_q + m.Km * w * s) / m.L,
           (vq - m.R * i_q - w_e * m.L * i_d - m.Km * w * c) / m.L]
    return np.array(out + extra)


def _state_size(system: SystemParams) -> int:
    return 4 if system.drive.drive_mode == "voltage" else 6


def operating_point(system: SystemParams, speed_rps: float) -> OperatingPoint:
    """The steady state at ``speed_rps`` (rev/s); ``ParameterError`` if the motor
    cannot hold that speed (no equilibrium: it stalls)."""
    m, d = system.motor, system.drive
    w_c = TWO_PI * speed_rps
    n = _state_size(system)
    # Unknowns: eps, i_d, i_q (nu = 0); current mode also the integrators.
    z = np.zeros(n)
    z[2] = d.holding_current
    if n == 6:
        z[4] = m.R * d.holding_current
        z[5] = m.Nr * w_c * m.L * d.holding_current + m.Km * w_c
    free = [0, 2, 3] + ([4, 5] if n == 6 else [])
    rows = [1, 2, 3] + ([4, 5] if n == 6 else [])

    def residual(x: np.ndarray) -> np.ndarray:
        zz = z.copy()
        zz[free] = x
        return _rhs(system, w_c, zz)[rows]

    x = z[free].copy()
    scale = np.array([1.0, d.holding_current, d.holding_current] + [d.Vdc] * (n - 4))
    for _ in range(60):
        f = residual(x)
        jac = _central_differences(residual, x, 1e-7 * scale)
        step = fm.solve(jac, -f)
        if not np.all(np.isfinite(step)):        # singular
            break
        # Damped: the load angle must stay on the stable branch (|eps| < pi/2).
        step *= min(1.0, 0.3 / max(abs(step[0]), 1e-300))
        x = x + step
        if np.all(np.abs(step) <= 1e-13 * scale):
            break
    z[free] = x
    # The residual in N*m over the holding torque, and in V over the bus voltage
    # (integrator rows: in A over the holding current).
    ki = system.current_gains().ki if n == 6 else 0.0
    weights = np.array([m.J / (m.Km * d.holding_current), m.L / d.Vdc, m.L / d.Vdc]
                       + [1.0 / (ki * d.holding_current) if ki > 0 else 0.0] * (n - 4))
    scaled = residual(x) * weights
    if not (np.all(np.isfinite(scaled)) and np.all(np.abs(scaled) <= 1e-9)
            and abs(x[0]) < math.pi / 2):
        raise ParameterError(f"motor {system.name!r} at {speed_rps:g} rev/s: no steady state "
                             "(the drive cannot hold that speed)")
    if n == 6:
        kp, _ = system.current_gains()
        vd = kp * (d.holding_current - z[2]) + z[4]
        vq = kp * (0.0 - z[3]) + z[5]
        sat = fm.hypot(vd, vq) > d.Vdc / math.sqrt(2.0)
    else:
        vd, vq, sat = _voltage_mode_voltages(system, w_c)
    return OperatingPoint(speed_rps, float(z[0]), float(z[2]), float(z[3]), vd, vq, sat)


def jacobian(system: SystemParams, speed_rps: float) -> np.ndarray:
    """d(z')/dz at the steady state of ``speed_rps`` (rev/s), central differences."""
    op = operating_point(system, speed_rps)
    w_c = TWO_PI * speed_rps
    d = system.drive
    z0 = np.zeros(_state_size(system))
    z0[0], z0[2], z0[3] = op.eps_rad, op.i_d_a, op.i_q_a
    if len(z0) == 6:
        kp, _ = system.current_gains()
        z0[4] = op.v_d_v - kp * (d.holding_current - op.i_d_a)
        z0[5] = op.v_q_v - kp * (0.0 - op.i_q_a)
    scale = np.array([1.0, max(abs(w_c), 1.0), d.holding_current, d.holding_current]
                     + [d.Vdc] * (len(z0) - 4))
    return _central_differences(lambda z: _rhs(system, w_c, z), z0, 1e-6 * scale)


def _central_differences(f: Any, x: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """The Jacobian of ``f`` at ``x``, column k from steps of +-``steps[k]``."""
    cols = []
    for k in range(len(x)):
        xp, xm = x.copy(), x.copy()
        xp[k] += steps[k]
        xm[k] -= steps[k]
        cols.append((f(xp) - f(xm)) / (2 * steps[k]))
    return np.column_stack(cols)


class RotorMode(NamedTuple):
    """The rotor's oscillatory mode: its damping ratio (negative: it grows) and
    eigenvalue (1/s)."""

    damping_ratio: float
    eigenvalue: complex


def rotor_damping(system: SystemParams, speed_rps: float) -> RotorMode:
    """(damping ratio, eigenvalue in 1/s) of the rotor's oscillatory mode at
    ``speed_rps``: the least damped complex pair. Negative: the oscillation grows."""
    lam = np.linalg.eigvals(jacobian(system, speed_rps))
    wn = system.natural_frequency()
    osc = [x for x in lam if x.imag > 1e-9 * wn]
    if not osc:                                   # overdamped: the slowest real pole
        x = max(lam, key=lambda v: v.real)
        return RotorMode(1.0 if x.real < 0 else -1.0, complex(x))
    # The least damped oscillatory pair: the rotor's (the windings' and the current
    # loops' pairs are damped by R and the PI); nearest-to-wn would miss it where
    # the voltage-fed winding stiffens the rotor well above wn.
    x = min(osc, key=lambda v: -v.real / abs(v))
    return RotorMode(float(-x.real / abs(x)), complex(x))


def bridge_limit_rps(system: SystemParams) -> float:
    """Speed (rev/s) above which the voltage-mode law asks for more than the
    bridge's circle Vdc/sqrt(2): |(R*I, (Nr*L*I + Km)*w)| = Vdc/sqrt(2), I the
    holding current (the current-mode drive needs about the same)."""
    m, d = system.motor, system.drive
    vmax = d.Vdc / math.sqrt(2.0)
    vr = m.R * d.holding_current
    if vr >= vmax:
        return 0.0
    return math.sqrt(vmax * vmax - vr * vr) / (m.Nr * m.L * d.holding_current + m.Km) / TWO_PI


@dataclass(frozen=True)
class MidBand:
    """The predicted mid-band of one motor and drive mode.

    ``unstable_rps``: (low, high) edges in rev/s of the speeds where the rotor
    mode's damping ratio is negative, or None (a high edge equal to the scan's
    end: the band reaches past it); ``min_damping_ratio``, ``at_rps``: the
    least damping ratio over the scan and its speed; ``bridge_limit_rps``: see
    :func:`bridge_limit_rps`; ``stall_rps``: the lowest scanned speed without a
    steady state (None: every speed has one)."""

    motor: str
    drive_mode: str
    unstable_rps: tuple[float, float] | None
    min_damping_ratio: float
    at_rps: float
    bridge_limit_rps: float
    stall_rps: float | None

    def to_dict(self) -> dict[str, Any]:
        return {"motor": self.motor, "drive_mode": self.drive_mode,
                "unstable_rps": list(self.unstable_rps) if self.unstable_rps else None,
                "min_damping_ratio": self.min_damping_ratio, "at_rps": self.at_rps,
                "bridge_limit_rps": self.bridge_limit_rps, "stall_rps": self.stall_rps}


def _zeta(system: SystemParams, v: float) -> float | None:
    try:
        return rotor_damping(system, v).damping_ratio
    except ParameterError:
        return None


def _edge(system: SystemParams, lo: float, hi: float) -> float:
    """The speed between ``lo`` and ``hi`` (rev/s) where the damping ratio
    changes sign, by bisection to 1e-4 rev/s."""
    z_lo = _zeta(system, lo)
    for _ in range(40):
        if hi - lo < 1e-4:
            break
        mid = 0.5 * (lo + hi)
        z = _zeta(system, mid)
        if z is not None and z_lo is not None and (z < 0) == (z_lo < 0):
            lo, z_lo = mid, z
        else:
            hi = mid
    return 0.5 * (lo + hi)


def midband(system: SystemParams, scan: tuple[float, float, float] = MIDBAND_SCAN_RPS,
            first_band_only: bool = False) -> MidBand:
    """The unstable speed band of ``system`` with its own ``drive_mode``: the
    damping ratio on the grid ``scan`` = (low, high, step) in rev/s, the band's
    edges refined by bisection. Only the first band is reported; with
    ``first_band_only`` the scan stops where that band has closed (the least
    damped speed is then the least damped one scanned; the speeds above, where
    the drive stalls, cost the most)."""
    lo_s, hi_s, step = scan
    speeds = np.arange(lo_s, hi_s + 0.5 * step, step)
    zetas: list[float | None] = []
    for v in speeds:
        zetas.append(_zeta(system, float(v)))
        if first_band_only and len(zetas) > 1 and zetas[-1] is not None \
                and zetas[-1] >= 0 and any(z is not None and z < 0 for z in zetas):
            break
    speeds = speeds[:len(zetas)]
    stall = next((float(v) for v, z in zip(speeds, zetas) if z is None), None)
    known = [(float(v), z) for v, z in zip(speeds, zetas) if z is not None]
    if not known:
        raise ParameterError(f"motor {system.name!r}: no steady state at any speed in "
                             f"[{lo_s:g}, {hi_s:g}] rev/s")
    at, zmin = min(known, key=lambda p: p[1])
    band = None
    neg = [k for k, (_, z) in enumerate(known) if z < 0]
    if neg:
        k0 = neg[0]
        k1 = k0
        while k1 + 1 < len(known) and known[k1 + 1][1] < 0:
            k1 += 1
        low = _edge(system, known[k0 - 1][0], known[k0][0]) if k0 > 0 else known[k0][0]
        high = _edge(system, known[k1][0], known[k1 + 1][0]) if k1 + 1 < len(known) \
            else known[k1][0]
        band = (low, high)
    return MidBand(system.name, system.drive.drive_mode, band, zmin, at,
                   bridge_limit_rps(system), stall)


# ---------------------------------------------------------------------------
# The band measured on the simulation, for comparison with the prediction.
# ---------------------------------------------------------------------------
#: RMS velocity ripple over the command speed above which a run "rips" (or it lost steps).
HIGH_RIPPLE = 0.05


#: Settling (s) before :func:`measured_band` measures: near the band's edges an
#: oscillation grows at only -zeta*wn (a few 1/s), so it needs seconds to show.
BAND_SETTLE_S = 3.0


def undamped_ripple(system: SystemParams, speed_rps: float, drive_mode: str,
                    settle_s: float = BAND_SETTLE_S, noise_seed: int = 0
                    ) -> tuple[float, bool]:
    """(RMS velocity ripple / command speed, lost steps) of the undamped open-loop
    drive of ``system`` with ``drive_mode`` at ``speed_rps`` after ``settle_s``
    (s) at speed, over :func:`stepdamp_env.simulation.simulate`'s default window."""
    from .simulation import RunSettings, simulate     # this floor's own core

    res = simulate(system.replace(drive_mode=drive_mode), speed_rps=speed_rps,
                   settings=RunSettings(mode="open-loop", base_controller="none", settle_s=settle_s,
                                        noise_seed=noise_seed))
    m = res.metrics
    return float(m.rms_velocity_error_norm), bool(m.step_loss)


def _rips(system: SystemParams, v: float, drive_mode: str) -> bool:
    ripple, lost = undamped_ripple(system, v, drive_mode)
    return lost or not ripple < HIGH_RIPPLE


@dataclass(frozen=True)
class MeasuredBand:
    """The voltage-mode band measured on the simulation: ``band_rps`` (low, high)
    edges in rev/s of the first run of speeds where the undamped voltage-mode
    drive rips (ripple >= HIGH_RIPPLE or lost steps) while the current-mode
    drive does not, each edge bisected to ``resolution_rps``; None if there is
    none. ``current_mode_limit_rps``: the lowest grid speed above the band's
    low edge where the current-mode drive rips (None: none up to the grid's end)."""

    band_rps: tuple[float, float] | None
    current_mode_limit_rps: float | None
    resolution_rps: float


def measured_band(system: SystemParams, grid_rps: np.ndarray,
                  resolution_rps: float = 0.02) -> MeasuredBand:
    """Measure :class:`MeasuredBand` on ``grid_rps`` (ascending, rev/s)."""
    grid = [float(v) for v in grid_rps]
    volt = [_rips(system, v, "voltage") for v in grid]
    curr = [_rips(system, v, "current") for v in grid]
    inside = [a and not b for a, b in zip(volt, curr)]
    if not any(inside):
        return MeasuredBand(None, None, resolution_rps)
    k0 = inside.index(True)
    k1 = k0
    while k1 + 1 < len(grid) and inside[k1 + 1]:
        k1 += 1

    def bisect(lo: float, hi: float, rising: bool) -> float:
        while hi - lo > resolution_rps:
            mid = 0.5 * (lo + hi)
            if _rips(system, mid, "voltage") == rising:
                hi = mid
            else:
                lo = mid
        return 0.5 * (lo + hi)

    low = bisect(grid[k0 - 1], grid[k0], True) if k0 > 0 else grid[k0]
    high = bisect(grid[k1], grid[k1 + 1], False) if k1 + 1 < len(grid) else grid[k1]
    limit = next((v for v, c in zip(grid[k0:], curr[k0:]) if c), None)
    return MeasuredBand((low, high), limit, resolution_rps)
