"""Design of the servo's Kalman velocity estimator (with filterpy).

The drive runs the steady-state filter: a constant-velocity model
x = (theta, omega), driven by white acceleration noise of standard deviation
``accel_std`` (rad/s^2) per control period, measuring the centre of the encoder
count with the quantisation's variance q^2/12. filterpy's covariance recursion
is iterated until its gain stops changing; the kernel then applies that fixed
gain at 20 kHz (a steady-state Kalman filter is an alpha-beta filter).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

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
    return MIN_TRACKING_INDEX * (count_rad / np.sqrt(12.0)) / dt ** 2


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
    kf = kalman_velocity_filter(dt, count_rad, accel_std)
    previous = np.full(2, np.inf)
    for _ in range(200_000):
        kf.predict()
        kf.update(np.array([0.0]))
        gain = kf.K[:, 0].copy()
        if np.all(np.abs(gain - previous) <= 1e-13 * np.maximum(np.abs(gain), 1e-300)):
            break
        previous = gain
    else:  # pragma: no cover - the tracking-index bound keeps this out of reach
        raise ParameterError(f"kalman_accel_std={accel_std!r}: the Kalman gain did not "
                             "converge")
    return float(gain[0]), float(gain[1])
