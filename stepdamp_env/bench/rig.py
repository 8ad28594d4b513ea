"""A calibration rig: the motor under test on a test bench, before the measured run.

Entries that calibrate (US 5,659,234's correction tables, Prusa's phase stepping)
measure the speed ripple of the very motor they will drive, at constant speeds,
with trial feedforward corrections. :class:`CalibrationRig` runs those trials on
the true plant (the drive, its current loop, its current sensors' noise) without
handing out the plant's parameters: a trial returns only what a reference speed
sensor on the rig reads (noise-free: the simulation core's lock-in on the shaft
speed), the amplitude of each detent harmonic of the velocity error over whole
periods (a single DFT bin, as Prusa takes it), and the trial's simulated
seconds, which the leaderboard reports beside (never inside) the score.
"""

from __future__ import annotations

import math

import numpy as np

from .. import kernel as K
from ..params import DETENT_HARMONICS, FeedforwardModel, ParameterError, SystemParams
from ..simulation import (RunSettings, SpeedProfile, build_config, initial_state,
                          measuring_window, metrics_from_accumulators, new_accumulators)

__all__ = ["CalibrationRig"]


class CalibrationRig:
    """Constant-speed trials on one motor (see the module docstring).

    Args:
        system: the true plant with its sensors (kept private).
        noise_seed: seed of the current-sensor noise of the trials.
        accel_rps2: the ramp to each trial's speed (rev/s^2).
    """

    def __init__(self, system: SystemParams, noise_seed: int, accel_rps2: float) -> None:
        self.__system = system
        self.noise_seed = int(noise_seed)
        self.accel_rps2 = float(accel_rps2)

    @property
    def key(self) -> tuple:
        """Identifies the motor and the noise for caches of calibrations."""
        return (repr(self.__system), self.noise_seed, self.accel_rps2)

    def harmonic_ripple(self, mode: str, speed_rps: float, estimate: FeedforwardModel,
                        corrections_nm: np.ndarray, window_s: float = 0.05
                        ) -> tuple[np.ndarray, float]:
        """(amplitudes in rad/s of the velocity error at h*Nr*speed, h = 1, 2, 4;
        the trial's simulated seconds).

        One trial in drive ``mode``: the drive's patent feedforward with model ``estimate`` plus
        the sin/cos coefficient corrections ``corrections_nm`` (N*m, order s1,
        c1, s2, c2, s4, c4), ramped to ``speed_rps``, settled as the simulation
        core settles, then measured over ``window_s`` (rounded up to whole
        periods of the first harmonic).
        """
        corr = np.asarray(corrections_nm, dtype=float)
        if corr.shape != (6,) or not np.all(np.isfinite(corr)):
            raise ParameterError("corrections_nm must hold 6 finite numbers (N*m)")
        system = self.__system
        profile = SpeedProfile(speed_rps=float(speed_rps), accel_rps2=self.accel_rps2)
        settings = RunSettings(mode=mode, base_controller="patent-ff", estimate=estimate,
                               window_s=window_s, noise_seed=self.noise_seed)
        start, length = measuring_window(system, profile, settings)
        config = build_config(system, profile, settings, window_start_s=start)
        state = initial_state(config)
        acc = new_accumulators()
        inputs = np.zeros(len(K.INPUT))
        inputs[K.INPUT.DS1:K.INPUT.DC4 + 1] = corr
        n = int(math.ceil((start + length) * system.drive.pwm_hz))
        K.run_periods(config, state, acc, inputs, n, np.zeros((0, len(K.TRACE))), 1)
        amps = metrics_from_accumulators(acc, system, speed_rps).harmonic_amplitude_rad_s
        return np.array([amps[h] for h in DETENT_HARMONICS]), n / system.drive.pwm_hz
