"""Resonance sweeps: ripple against command speed, run on every core."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from .analysis import bridge_limit_rps
from .parallel import default_workers, pool_map
from .params import DETENT_HARMONICS, ParameterError, SystemParams
from .simulation import DEFAULT_ACCEL_RPS2, RunSettings, SpeedProfile, simulate

__all__ = ["SweepResult", "parse_speed_range", "default_speed_range", "run_sweep", "find_resonance_peaks",
           "resolving_spacing", "prominent_peaks", "PEAK_PROMINENCE", "PEAK_MIN_FRACTION"]


#: Command speeds a sweep or a simulation accepts (rev/s, magnitude).
MIN_SPEED_RPS = 1e-3
MAX_SPEED_RPS = 1e3


def parse_speed_range(text: str) -> np.ndarray:
    """``START:STOP:STEP`` in rev/s (STOP included when it falls on the grid)."""
    parts = text.split(":")
    if len(parts) != 3:
        raise ParameterError(f"--speeds expects START:STOP:STEP in rev/s, got {text!r}")
    try:
        start, stop, step = (float(p) for p in parts)
    except ValueError:
        raise ParameterError(f"--speeds expects numbers, got {text!r}") from None
    if not all(math.isfinite(v) for v in (start, stop, step)):
        raise ParameterError(f"--speeds must be finite, got {text!r}")
    for name, value in (("START", start), ("STOP", stop)):
        if not MIN_SPEED_RPS <= value <= MAX_SPEED_RPS:
            sign = (" (a sweep runs forward; the direction does not change the ripple)"
                    if value < 0 else "")
            raise ParameterError(f"--speeds {name}={value:g} is outside its allowed range "
                                 f"[{MIN_SPEED_RPS:g}, {MAX_SPEED_RPS:g}] rev/s{sign}")
    if stop < start:
        raise ParameterError(f"--speeds STOP={stop:g} must be >= START={start:g} rev/s")
    if step <= 0:
        raise ParameterError(f"--speeds STEP={step:g} must be > 0 rev/s")
    count = (stop - start) / step
    if count > 100_000:
        raise ParameterError(f"--speeds {text!r} gives over 100000 points; allowed at most "
                             "100000")
    n = int(math.floor(count + 1e-9)) + 1
    if n > 100_000:
        raise ParameterError(f"--speeds {text!r} gives {n} points; allowed at most 100000")
    # Rounded to 1e-9 rev/s so the grid prints and compares cleanly.
    return np.round(start + step * np.arange(n), 9)


@dataclass
class SweepResult:
    """Metrics of one run per speed, in the order of ``speeds_rps``."""

    system: SystemParams
    settings: RunSettings
    accel_rps2: float
    speeds_rps: np.ndarray
    metrics: list[dict[str, Any]]

    def column(self, key: str) -> np.ndarray:
        return np.array([m[key] for m in self.metrics])

    def peaks(self) -> dict[int, dict[str, float]]:
        return find_resonance_peaks(self.speeds_rps, self.column("rms_velocity_error_rad_s"),
                                    self.system.predicted_resonances_rps(),
                                    resolving_spacing=resolving_spacing(self.system))

    def to_dict(self) -> dict[str, Any]:
        from .version import __version__

        predicted = self.system.predicted_resonances_rps()
        est = self.settings.estimate
        return {
            "package": "stepdamp-env",
            "version": __version__,
            "motor": self.system.name,
            "mode": self.settings.mode,
            "base_controller": self.settings.base_controller,
            "estimate": None if est is None else est.__dict__,
            "accel_rps2": self.accel_rps2,
            "substeps": self.settings.substeps,
            "velocity_estimator": self.settings.velocity_estimator,
            "noise_seed": self.settings.noise_seed,
            "speeds_rps": self.speeds_rps.tolist(),
            "rms_velocity_error_rad_s": self.column("rms_velocity_error_rad_s").tolist(),
            "p2p_velocity_error_rad_s": self.column("p2p_velocity_error_rad_s").tolist(),
            "rms_velocity_error_norm": self.column("rms_velocity_error_norm").tolist(),
            "max_position_lag_rad": self.column("max_position_lag_rad").tolist(),
            "step_loss": [bool(v) for v in self.column("step_loss")],
            "rms_injected_current_a": self.column("rms_injected_current_a").tolist(),
            "harmonic_amplitude_rad_s": {
                str(h): [m["harmonic_amplitude_rad_s"][str(h)] for m in self.metrics]
                for h in DETENT_HARMONICS},
            "predicted_resonances_rps": {str(h): v for h, v in predicted.items()},
            "measured_resonances_rps": {str(h): v for h, v in self.peaks().items()},
            "parameters": self.system.to_dict(),
            "derived": self.system.derived_dict(),
            "runs": self.metrics,
        }


#: A point more than this factor above both neighbours is a lone spike, not a resonance.
SPIKE_RATIO = 1.2
#: A resonance's 3-point mean stands this factor above the median of its search band.
PROMINENCE = 1.2
#: The total damping ratio of the open-loop rotor is at least this multiple of the
#: mechanical one: the back-EMF currents the sampled current loop cannot cancel add
#: from 0.9x (the presets) to 22x (a light, low-D rotor) the mechanical damping,
#: measured on this model (docs/model.md).
TOTAL_OVER_MECHANICAL_DAMPING = 1.9


def default_speed_range(system: SystemParams) -> str:
    """``sweep``'s default ``--speeds`` for a motor (START:STOP:STEP, rev/s): from
    half its h = 4 resonance to 1.25 times its h = 1 resonance, so that all three
    lie inside, capped at its top speed on its bus (:func:`.analysis.bridge_limit_rps`;
    from half that where it lies below the h = 4 resonance), in
    166 steps (the old fixed grid's count) rounded to 3 significant digits."""
    res = system.predicted_resonances_rps()
    low, high = 0.5 * min(res.values()), 1.25 * max(res.values())
    top = bridge_limit_rps(system)
    if not top > 2.0 * MIN_SPEED_RPS:
        raise ParameterError(f"motor {system.name!r}: its bus (Vdc={system.drive.Vdc:g} V) "
                             "cannot drive its holding current at any speed, so there is no "
                             "default --speeds; give --speeds START:STOP:STEP (rev/s)")
    if math.isfinite(top) and top < high:
        high = top
        low = min(low, 0.5 * top)       # a bus too weak for its resonances: up to its top
    low = max(low, MIN_SPEED_RPS)
    step = float(f"{(high - low) / 166:.3g}")
    return f"{float(f'{low:.3g}'):g}:{float(f'{high:.3g}'):g}:{step:g}"


def resolving_spacing(system: SystemParams) -> float:
    """Relative speed spacing of a grid that resolves the open-loop resonances.

    Near its peak a resonance of damping ratio zeta falls as
    1/sqrt(1 + (delta/zeta)^2) at relative offset delta, i.e. by ``SPIKE_RATIO`` at
    delta = zeta*sqrt(SPIKE_RATIO^2 - 1). On a finer grid a real resonance never
    stands ``SPIKE_RATIO`` above both neighbours, so such a point is an aliasing
    spike; on a coarser grid it may be the resonance, sampled once. zeta is the
    smallest expected total damping ratio (``TOTAL_OVER_MECHANICAL_DAMPING`` times
    D / (2*sqrt(Km*holding_current*Nr*J))). 0 (no grid resolves) without D, or
    without a holding-current spring.
    """
    m = system.motor
    stiffness = m.Km * system.drive.holding_current * m.Nr
    if not stiffness > 0.0 or not m.J > 0.0:
        return 0.0
    zeta = TOTAL_OVER_MECHANICAL_DAMPING * m.D / (2.0 * math.sqrt(stiffness * m.J))
    return zeta * math.sqrt(SPIKE_RATIO ** 2 - 1.0)


def find_resonance_peaks(speeds: np.ndarray, ripple: np.ndarray,
                         predicted: dict[int, float], search: float = 0.15,
                         resolving_spacing: float = math.inf) -> dict[int, dict[str, float]]:
    """The ripple maximum within +-``search`` (relative) of each predicted speed.

    Returns per harmonic h: the speed of the maximum, its ripple, its relative
    distance from the prediction, whether it is a local maximum of the sweep
    (not an edge of the searched band) and whether it is a resonance peak
    (``is_resonance``): a local maximum that is not a lone spike (more than
    ``SPIKE_RATIO`` above both neighbours: the ripple aliasing with the PWM or
    encoder rate gives such one-speed spikes) and whose 3-point mean stands
    ``PROMINENCE`` above the median over twice the band. A damped or servo sweep
    may have none. The spike test applies only where the grid's relative spacing
    is at most ``resolving_spacing`` (:func:`resolving_spacing`; ``resolved`` in
    the result): on a coarser grid a resonance sampled at one speed looks like a
    spike, and a prominent maximum counts as a resonance.
    """
    out: dict[int, dict[str, float]] = {}
    for h, pred in predicted.items():
        band = np.nonzero((speeds >= pred * (1 - search)) & (speeds <= pred * (1 + search)))[0]
        if band.size == 0:
            continue
        i = band[np.argmax(ripple[band])]
        interior = 0 < i < len(speeds) - 1 and ripple[i] >= ripple[i - 1] \
            and ripple[i] >= ripple[i + 1] and i not in (band[0], band[-1])
        near = speeds[max(i - 1, 0):i + 2]
        spacing = (near[-1] - near[0]) / max(len(near) - 1, 1) / abs(speeds[i])
        resolved = bool(len(near) > 1 and spacing <= resolving_spacing)
        resonance = False
        if interior:
            spike = resolved and ripple[i] > SPIKE_RATIO * max(ripple[i - 1], ripple[i + 1])
            wide = (speeds >= pred * (1 - 2 * search)) & (speeds <= pred * (1 + 2 * search))
            prominent = np.mean(ripple[i - 1:i + 2]) >= PROMINENCE * np.median(ripple[wide])
            resonance = bool(prominent and not spike)
        out[h] = {"speed_rps": float(speeds[i]), "ripple_rad_s": float(ripple[i]),
                  "relative_offset": float(speeds[i] / pred - 1.0),
                  "is_local_max": bool(interior), "is_resonance": resonance,
                  "resolved": resolved}
    return out


#: A peak stands this factor (in ripple, 1.5 = 3.5 dB) above the higher of the
#: lowest points between it and the nearest higher ripple on either side.
PEAK_PROMINENCE = 1.5
#: Peaks lower than this share of the highest one are not reported.
PEAK_MIN_FRACTION = 0.1


def prominent_peaks(speeds_rps: Sequence[float], ripple: Sequence[float],
                    prominence: float = PEAK_PROMINENCE,
                    min_fraction: float = PEAK_MIN_FRACTION) -> list[dict[str, float]]:
    """Local maxima of ``ripple`` against speed whose topographic prominence, as a
    ratio, is at least ``prominence``: the peak over the higher of the two
    minima that separate it from higher ground (or from the sweep's ends), and
    that reach ``min_fraction`` of the highest such peak (a well-damped curve's
    small aliasing spikes are not humps). Flat tops count once (their first
    point). Non-finite points (lost runs) separate peaks. Returns
    ``speed_rps``, ``ripple``, ``prominence`` (ratio) and ``lone`` (more than
    ``SPIKE_RATIO`` x 2 above both neighbours: one speed, likely aliasing with
    the PWM or encoder rate, not a resonance), highest first."""
    v = np.asarray(speeds_rps, dtype=float)
    y = np.asarray(ripple, dtype=float)
    n = len(y)
    out = []
    for i in range(n):
        if not (math.isfinite(y[i]) and y[i] > 0):
            continue
        left_higher = i > 0 and math.isfinite(y[i - 1]) and y[i - 1] >= y[i]
        right_higher = i + 1 < n and math.isfinite(y[i + 1]) and y[i + 1] > y[i]
        if left_higher or right_higher:
            continue
        bases = []
        for step in (-1, 1):
            low, j = y[i], i + step
            while 0 <= j < n and math.isfinite(y[j]) and y[j] <= y[i]:
                low = min(low, y[j])
                j += step
            bases.append(low)
        base = max(bases)
        ratio = y[i] / base if base > 0 else math.inf
        if ratio >= prominence:
            near = [y[j] for j in (i - 1, i + 1) if 0 <= j < n and math.isfinite(y[j])]
            lone = bool(near) and bool(y[i] > 2.0 * SPIKE_RATIO * max(near))
            out.append({"speed_rps": float(v[i]), "ripple": float(y[i]),
                        "prominence": float(ratio), "lone": lone})
    out.sort(key=lambda p: -p["ripple"])
    return [p for p in out if p["ripple"] >= min_fraction * out[0]["ripple"]] if out else []


def _run_point(args: tuple[SystemParams, RunSettings, float, float]) -> dict[str, Any]:
    system, settings, speed, accel = args
    result = simulate(system, profile=SpeedProfile(speed_rps=speed, accel_rps2=accel),
                      settings=settings)
    return result.metrics.to_dict()


def run_sweep(system: SystemParams, speeds_rps: Sequence[float],
              settings: RunSettings | None = None, accel_rps2: float = DEFAULT_ACCEL_RPS2,
              workers: int | None = None, progress: bool = True,
              backend: Callable[..., list[Any]] | None = None) -> SweepResult:
    """Simulate each speed (constant-speed profile) and collect its metrics.

    Runs are independent and deterministic, so the result does not depend on
    ``workers`` (default: every core this process may use) nor on ``backend``
    (default: this machine's process pool; :func:`stepdamp_env.ray_backend.ray_map`
    for Ray).
    """
    settings = settings or RunSettings()
    speeds = np.asarray(speeds_rps, dtype=float)
    jobs = [(system, settings, float(v), float(accel_rps2)) for v in speeds]
    workers = default_workers() if workers is None else workers
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(jobs), desc=f"sweep {settings.mode}/{settings.base_controller}",
                   unit="run")
    metrics = (pool_map if backend is None else backend)(_run_point, jobs, workers,
                                                         min_jobs=4, bar=bar)
    if bar:
        bar.close()
    return SweepResult(system=system, settings=settings, accel_rps2=float(accel_rps2),
                       speeds_rps=speeds, metrics=metrics)
