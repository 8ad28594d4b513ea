"""A run's metrics: the kernel's sums over the measuring window (``kernel.ACC``),
merged across stretches of a run, and turned into :class:`RunMetrics` (SI)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from . import fixedmath as fm
from . import kernel as K
from .params import ParameterError, SystemParams

__all__ = ["RunMetrics", "metrics_from_accumulators", "merge_accumulators",
           "merge_accumulator_rows", "new_accumulators", "METRICS_V0_V3"]

TWO_PI = 2.0 * math.pi


def merge_accumulators(total: np.ndarray, part: np.ndarray) -> None:
    """Fold the sums of a later stretch ``part`` into ``total`` (in place).

    Sums add, extremes combine; the lock-in sums add because their phase is
    timed from the window start, not from the stretch.
    """
    # The compiled loop on one row: one definition of the arithmetic.
    K.merge_rows(total[np.newaxis], part[np.newaxis])


def merge_accumulator_rows(total: np.ndarray, part: np.ndarray) -> None:
    """:func:`merge_accumulators` row by row over (n, N_ACC) arrays
    (:func:`stepdamp_env.kernel.merge_rows`)."""
    K.merge_rows(total, part)


def new_accumulators(n: int | None = None) -> np.ndarray:
    """Zeroed metric sums for one drive, or an (n, N_ACC) batch."""
    return np.zeros(len(K.ACC) if n is None else (n, len(K.ACC)))


@dataclass(frozen=True)
class RunMetrics:
    """Metrics of one run over its measuring window (SI units).

    Velocity error is w_cmd - w (rad/s) and position error theta_cmd - theta
    (rad), sampled once per PWM period. ``rms_position_error_steps``: the RMS
    of the position error over the window, in full steps (the static lag
    included); ``position_ripple_steps``: its RMS about its window mean (the
    ripple a constant lag leaves), in full steps, from the window's sums
    (``E[p^2] - E[p]^2``, which cancels as (lag/ripple)^2 grows: on 20,000
    synthetic samples 2e-9 relative at 0.22 steps of lag and 3e-4 of ripple,
    9e-5 at 10 and 1e-4; a run lost past its lag limit is not scored).
    ``run_position_error_steps``: the RMS of the position error over every
    sample of the run, not only the window (for a point-to-point move: the
    move and its settling), in full steps. ``harmonic_phasor_rad_s``: the
    velocity error's lock-in phasor at each detent harmonic h, (2/n)*(sum
    e*sin, sum e*cos) of h*Nr*w_ref*(t - window start) (its length is
    ``harmonic_amplitude_rad_s``): linear in the error, for a law that
    cancels a harmonic by its measured response (``plant-bound``).
    """

    speed_rps: float
    rms_velocity_error_rad_s: float
    p2p_velocity_error_rad_s: float
    rms_velocity_error_norm: float      # divided by the command speed (rad/s)
    p2p_velocity_error_norm: float
    mean_velocity_error_rad_s: float
    max_position_lag_rad: float         # over the whole run
    max_position_lag_steps: float       # in full steps
    step_loss: bool                     # lag past one full step
    rms_injected_current_a: float       # feedforward plus residual q current
    harmonic_amplitude_rad_s: dict[int, float]  # error amplitude at h*Nr*speed
    peak_phase_current_a: float
    rms_position_error_steps: float
    position_ripple_steps: float
    run_position_error_steps: float
    harmonic_phasor_rad_s: dict[int, tuple[float, float]]

    def to_dict(self, keys: tuple[str, ...] | None = None) -> dict[str, Any]:
        """JSON-ready; ``keys``: only these fields (e.g. :data:`METRICS_V0_V3`)."""
        # Shallow (dataclasses.asdict deep-copies: a fifth of a run's Python):
        # every field is a number but the two dicts, made afresh here.
        out = {name: getattr(self, name) for name in _FIELD_NAMES}
        out["harmonic_amplitude_rad_s"] = {str(h): v for h, v in
                                           self.harmonic_amplitude_rad_s.items()}
        out["harmonic_phasor_rad_s"] = {str(h): list(v) for h, v in
                                        self.harmonic_phasor_rad_s.items()}
        return out if keys is None else {k: out[k] for k in keys}


_FIELD_NAMES = tuple(f.name for f in fields(RunMetrics))

#: The fields a run's metrics held through 0.17 (stepdamp-bench v0-v3 record
#: only these, so that their records stay as published).
METRICS_V0_V3 = ("speed_rps", "rms_velocity_error_rad_s", "p2p_velocity_error_rad_s",
                 "rms_velocity_error_norm", "p2p_velocity_error_norm",
                 "mean_velocity_error_rad_s", "max_position_lag_rad", "max_position_lag_steps",
                 "step_loss", "rms_injected_current_a", "harmonic_amplitude_rad_s",
                 "peak_phase_current_a")


def metrics_from_accumulators(acc: np.ndarray, system: SystemParams,
                              speed_rps: float) -> RunMetrics:
    """Turn the kernel's sums into :class:`RunMetrics` (the ``*_norm`` metrics,
    relative to the command speed, are NaN for a command at rest)."""
    n = acc[K.ACC.COUNT]
    if n <= 0:
        raise ParameterError("the measuring window holds no sample: the run ended before it "
                         "opened (raise duration_s or lower settle_s)")
    rms = math.sqrt(acc[K.ACC.SUM_E2] / n)
    p2p = acc[K.ACC.MAX_E] - acc[K.ACC.MIN_E]
    w_cmd = TWO_PI * abs(speed_rps)
    norm = w_cmd if w_cmd > 0 else math.nan
    amps, phasors = {}, {}
    for h, (i_s, i_c) in ((1, (K.ACC.H1_S, K.ACC.H1_C)), (2, (K.ACC.H2_S, K.ACC.H2_C)),
                          (4, (K.ACC.H4_S, K.ACC.H4_C))):
        amps[h] = 2.0 / n * fm.hypot(acc[i_s], acc[i_c])
        phasors[h] = (float(2.0 / n * acc[i_s]), float(2.0 / n * acc[i_c]))
    step = system.motor.full_step_rad
    lag = float(acc[K.ACC.MAX_LAG])
    p_mean = acc[K.ACC.SUM_P] / n
    p_ms = acc[K.ACC.SUM_P2] / n
    return RunMetrics(
        speed_rps=float(speed_rps),
        rms_velocity_error_rad_s=rms,
        p2p_velocity_error_rad_s=float(p2p),
        rms_velocity_error_norm=rms / norm,
        p2p_velocity_error_norm=float(p2p) / norm,
        mean_velocity_error_rad_s=float(acc[K.ACC.SUM_E] / n),
        max_position_lag_rad=lag,
        max_position_lag_steps=lag / step,
        step_loss=bool(lag > step),
        rms_injected_current_a=math.sqrt(acc[K.ACC.SUM_IFF2] / n),
        harmonic_amplitude_rad_s=amps,
        peak_phase_current_a=float(acc[K.ACC.MAX_CURRENT]),
        rms_position_error_steps=math.sqrt(p_ms) / step,
        # Rounding can leave the variance a hair below 0 for a constant error.
        position_ripple_steps=math.sqrt(max(p_ms - p_mean * p_mean, 0.0)) / step,
        run_position_error_steps=math.sqrt(acc[K.ACC.SUM_P2_ALL] / acc[K.ACC.COUNT_ALL]) / step,
        harmonic_phasor_rad_s=phasors,
    )
