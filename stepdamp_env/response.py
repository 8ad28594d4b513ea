"""Frequency responses of the drive model, as the drive itself can compute them.

All take a :class:`~stepdamp_env.params.SystemParams` (what the drive believes:
datasheet motor, its own gains) and an angular frequency w (rad/s) of a signal
in time, and return a complex gain. They serve the model-based baselines
(delay compensation, adaptive feedforward) and identification.
"""

from __future__ import annotations

import math

import numpy as np

from . import fixedmath as fm
from .params import DETENT_HARMONICS, FeedforwardModel, SystemParams

__all__ = ["current_path", "velocity_filter", "servo_loop", "torque_to_velocity", "phasors",
           "torque_paths"]


def _z(system: SystemParams, w: float) -> tuple[complex, float]:
    dt = 1.0 / system.drive.pwm_hz
    return complex(fm.cos(w * dt), fm.sin(w * dt)), dt


def current_path(system: SystemParams, w: float) -> complex:
    """From the q current the controller computes at a sample to the torque.

    The sampled current loop with its period of computation delay,
    g/(z^2 - z + g), times the half-period lag of the held voltage. A
    voltage-mode drive (``drive_mode="voltage"``) has no current loop: the
    model's voltage R*i_q one period later, held, drives the winding's
    R + j*w*L, R/(R + j*w*L)/z with the same half-period lag (the back-EMF and
    the frame's cross-coupling left out, as the current loop's are).
    """
    z, dt = _z(system, w)
    if system.drive.drive_mode == "voltage":
        m = system.motor
        delay = w * dt / 2.0
        return (m.R / complex(m.R, w * m.L) / z
                * complex(fm.cos(delay), -fm.sin(delay)))
    kp, _ = system.current_gains()
    pole = fm.exp(-system.motor.R * dt / system.motor.L)
    g = kp * (1.0 - pole) / system.motor.R
    delay = w * dt / 2.0
    return g / (z * z - z + g) * complex(fm.cos(delay), -fm.sin(delay))


def velocity_filter(system: SystemParams, w: float) -> complex:
    """Differenced encoder angle through the first-order low-pass, per rad/s of speed."""
    z, dt = _z(system, w)
    zi = 1.0 / z
    alpha = 1.0 - fm.exp(-2.0 * math.pi * system.servo.velocity_cutoff_hz * dt)
    # The backward difference (1 - z^-1)/dt of the angle, over j*w: the
    # difference's own half-sample lag, relative to the true speed.
    diff = (1.0 - zi) / dt / complex(0.0, w) if w != 0 else 1.0
    return alpha / (1.0 - (1.0 - alpha) * zi) * diff


def servo_loop(system: SystemParams, w: float) -> complex:
    """Loop gain L of the servo: C(z) * current path / (J*(j*w)^2)."""
    z, dt = _z(system, w)
    zi = 1.0 / z
    kv, kp, ki = system.servo_gains()
    controller = kv * velocity_filter(system, w) * complex(0.0, w) + kp + ki * dt / (1.0 - zi)
    return controller * current_path(system, w) / (system.motor.J * complex(0.0, w) ** 2)


def torque_to_velocity(system: SystemParams, w: float, mode: str) -> complex:
    """Shaft speed (rad/s) per N*m of torque disturbance at w.

    Open loop: the rotor on the spring of its holding current,
    j*w/(k - J*w^2 + j*w*D), k = Km*holding_current*Nr. Servo: the rigid
    rotor inside the servo loop, (1/(J*j*w))/(1 + L).
    """
    m = system.motor
    jw = complex(0.0, w)
    if mode == "open-loop":
        k = m.Km * system.drive.holding_current * m.Nr
        return jw / (k + m.J * jw * jw + m.D * jw)
    return 1.0 / (m.J * jw) / (1.0 + servo_loop(system, w))


def phasors(model: FeedforwardModel) -> np.ndarray:
    """The model's harmonics 1, 2, 4 as complex phasors (N*m)."""
    c = model.coefficients()
    return np.array([complex(c[0], c[1]), complex(c[2], c[3]), complex(c[4], c[5])])


def torque_paths(system: SystemParams, mode: str, speed_rps: float,
                 friction: FeedforwardModel | None = None) -> np.ndarray:
    """G for h = 1, 2, 4 at the held speed, from the drive model.

    The current path (sampled current loop, computation delay, held voltage).
    In open loop the rotor also trails its command by the static lag
    (Fs + D*w)/(Km*holding_current*Nr), so the detent it feels runs h*Nr*lag
    behind the feedforward's angle: G carries that as a phase lead (with Fs
    from ``friction``, the drive's friction estimate, if given).
    """
    w = 2.0 * math.pi * abs(speed_rps)
    m = system.motor
    lag = 0.0
    if mode == "open-loop":
        fs = friction.Fs if friction is not None else m.Fs
        lag = (fs + m.D * w) / (m.Km * system.drive.holding_current * m.Nr)
    out = np.zeros(3, dtype=complex)
    for i, h in enumerate(DETENT_HARMONICS):
        out[i] = current_path(system, h * m.Nr * w) * fm.cexp(1j * h * m.Nr * lag)
    return out
