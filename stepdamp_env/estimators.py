"""Design of the servo's Kalman velocity estimator.

The drive runs the steady-state filter: a constant-velocity model
x = (theta, omega), driven by white acceleration noise of standard deviation
``accel_std`` (rad/s^2) per control period, measuring the centre of the encoder
count with the quantisation's variance q^2/12. The covariance recursion of
filterpy's ``KalmanFilter`` (predict, then update in Joseph form) is iterated
until its gain stops changing, written out for 2 x 2 in a fixed order (filterpy
multiplies through BLAS, whose last bits depend on the CPU); the kernel then
applies that fixed gain at 20 kHz (a steady-state Kalman filter is an
alpha-beta filter). :func:`kalman_velocity_filter` is the filterpy filter of
the same model, the reference of the tests.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numba import njit

__all__ = ["kalman_velocity_gains", "kalman_velocity_filter", "min_kalman_accel_std",
           "MIN_TRACKING_INDEX"]


def kalman_velocity_filter(dt: float, count_rad: float, accel_std: float):
    """A filterpy ``KalmanFilter`` of the model above (state theta, omega)."""
    from filterpy.common import Q_discrete_white_noise
    from filterpy.kalman import KalmanFilter

    kf = KalmanFilter(dim_x=2, dim_z=1)
    kf.F = np.array([[1.0, dt], [0.0, 1.0]])
    kf.H = np.array([[1.0, 0.0]])
    kf.R = np.array([[count_rad ** 2 / 12.0]])
    kf.Q = Q_discrete_white_noise(dim=2, dt=dt, var=accel_std ** 2)
    kf.P = np.diag([count_rad ** 2, 1e4])
    return kf


# Below this tracking index (accel_std*dt^2 over the measurement's standard
# deviation) the filter averages over seconds and its Riccati recursion needs
# more than ~20,000 steps to settle: refused before iterating.
MIN_TRACKING_INDEX = 1e-6


def min_kalman_accel_std(dt: float, count_rad: float) -> float:
    """The smallest ``kalman_accel_std`` (rad/s^2) allowed for this period and encoder."""
    return MIN_TRACKING_INDEX * (count_rad / math.sqrt(12.0)) / (dt * dt)


@njit(cache=True, error_model="numpy")
def _riccati_gains(dt, r, q_var, p00, p11, steps):
    """(k_theta, k_omega, converged) of the recursion above, from P = diag(p00, p11)."""
    q00 = q_var * dt * dt * dt * dt / 4.0
    q01 = q_var * dt * dt * dt / 2.0
    q11 = q_var * dt * dt
    p01 = 0.0
    p10 = 0.0
    k0_old = math.inf
    k1_old = math.inf
    for _ in range(steps):
        # Predict: P = F P F' + Q, F = [[1, dt], [0, 1]].
        a00 = p00 + dt * p10
        a01 = p01 + dt * p11
        p00 = (a00 + a01 * dt) + q00
        p01 = a01 + q01
        p10 = (p10 + p11 * dt) + q01
        p11 = p11 + q11
        # Update (Joseph form): K = P H' / (H P H' + R), P = (I - K H) P (I - K H)' + K R K'.
        s = p00 + r
        k0 = p00 / s
        k1 = p10 / s
        m00 = 1.0 - k0
        b00 = m00 * p00
        b01 = m00 * p01
        b10 = -k1 * p00 + p10
        b11 = -k1 * p01 + p11
        n00 = b00 * m00 + k0 * r * k0
        n01 = -b00 * k1 + b01 + k0 * r * k1
        n10 = b10 * m00 + k1 * r * k0
        n11 = -b10 * k1 + b11 + k1 * r * k1
        p00, p01, p10, p11 = n00, n01, n10, n11
        if abs(k0 - k0_old) <= 1e-13 * max(abs(k0), 1e-300) and \
                abs(k1 - k1_old) <= 1e-13 * max(abs(k1), 1e-300):
            return k0, k1, True
        k0_old, k1_old = k0, k1
    return k0, k1, False


@lru_cache(maxsize=256)
def kalman_velocity_gains(dt: float, count_rad: float, accel_std: float) -> tuple[float, float]:
    """Steady-state gains (k_theta, k_omega) on the innovation: (-, 1/s)."""
    from .params import ParameterError

    low = min_kalman_accel_std(dt, count_rad)
    if not accel_std >= low:
        raise ParameterError(
            f"kalman_accel_std={accel_std!r} is outside its allowed range [{low:.3g}, 1e9] "
            f"rad/s^2 for this encoder and pwm_hz: a slower Kalman velocity filter would "
            "average over seconds")
    k0, k1, converged = _riccati_gains(dt, count_rad * count_rad / 12.0, accel_std * accel_std,
                                       count_rad * count_rad, 1e4, 200_000)
    if not converged:  # pragma: no cover - the tracking-index bound keeps this out of reach
        raise ParameterError(f"kalman_accel_std={accel_std!r}: the Kalman gain did not "
                             "converge")
    return float(k0), float(k1)
