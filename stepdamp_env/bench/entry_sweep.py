"""Sweeps of a leaderboard entry: ripple against command speed on one motor.

``stepdamp sweep --damping ENTRY`` runs any registered entry (or a ``--policy``)
as stepdamp-bench v3 runs it (the drive identifies the motor first, the entry
knows what its card says), at every speed of the sweep, and finds the ripple's
peaks by prominence (:func:`prominent_peaks`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ..params import FeedforwardModel, ParameterError, SystemParams
from ..parallel import default_workers, pool_map
from .leaderboard import identify_cached, protocol_knowledge
from .motors import ProtocolMotor
from .protocols.decibels import FAILURE_DB, attenuation_db
from .protocols.v3 import full_protocol_v3
from .registry import resolve_policy
from .runner import run_episode
from ..plots import finish_ripple_axes, mark_resonances, pyplot, save_figure, POLICY_COLOURS
from ..sweep import prominent_peaks

__all__ = ["EntrySweep", "sweep_entry", "plot_entry_sweeps", "decibel_summary", "HUMP_DB"]

#: A hump: a speed where the entry's ripple is above ``none``'s by more than this (dB).
HUMP_DB = 1.0

@dataclass
class EntrySweep:
    """One entry's runs over the speeds (metrics None where a run lost its steps
    before the window)."""

    entry: str
    mode: str
    system: SystemParams
    speeds_rps: np.ndarray
    ripple_rad_s: np.ndarray          # RMS velocity error; nan where the run was lost
    failed: np.ndarray
    identified: FeedforwardModel | str | None = None
    metrics: list[dict[str, Any] | None] = field(default_factory=list)

    def peaks(self) -> list[dict[str, float]]:
        return prominent_peaks(self.speeds_rps, self.ripple_rad_s)

    def to_dict(self) -> dict[str, Any]:
        ident = self.identified
        return {"entry": self.entry, "mode": self.mode, "motor": self.system.name,
                "parameters": self.system.to_dict(),
                "identified": ident.__dict__ if isinstance(ident, FeedforwardModel) else ident,
                "speeds_rps": self.speeds_rps.tolist(),
                "rms_velocity_error_rad_s": [None if not math.isfinite(x) else float(x)
                                             for x in self.ripple_rad_s],
                "step_loss": [bool(x) for x in self.failed],
                "peaks": self.peaks(), "runs": self.metrics}


def _run(job: tuple[str, str, ProtocolMotor, Any, float, int, float, float, float | None]
         ) -> tuple[bool, dict[str, Any] | None]:
    spec, mode, motor, knowledge, speed, seed, accel, window, lag = job
    r = run_episode(resolve_policy(spec).make(), knowledge, motor.system, mode=mode,
                    speed_rps=speed, seed=seed, accel_rps2=accel, window_s=window,
                    lag_limit_steps=lag)
    return bool(r.failed), r.metrics


def sweep_entry(spec: str, system: SystemParams, speeds_rps: Sequence[float], *,
                mode: str = "open-loop", seed: int = 0, workers: int | None = None,
                progress: bool = True) -> EntrySweep:
    """Run entry ``spec`` at each speed (rev/s) on ``system`` in ``mode``
    ("open-loop" or "servo"; the drive mode is the system's), as stepdamp-bench
    v3 runs it: ramp, settling, 0.3 s window, lag limit; the drive knows the
    motor's values as nominal and the model it identifies with noise ``seed``."""
    protocol = full_protocol_v3()
    if mode not in ("open-loop", "servo"):
        raise ParameterError(f"--mode {mode!r}: a damping sweep runs 'open-loop' or 'servo'")
    motor = ProtocolMotor(name=system.name, system=system, nominal=system,
                          speeds_rps=tuple(float(v) for v in speeds_rps),
                          speed_labels=("sweep",) * len(speeds_rps), split="custom",
                          family="custom")
    ident_system = system if system.drive.drive_mode == "current" else \
        system.replace(drive_mode="current")
    identified = identify_cached(ident_system, protocol.identification_method, seed)
    knowledge = protocol_knowledge(motor, seed, identified if isinstance(
        identified, FeedforwardModel) else None, protocol)
    resolve_policy(spec)            # an unknown entry fails here, in one line
    jobs = [(spec, mode, motor, knowledge, float(v), seed, protocol.accel_rps2,
             protocol.window_s, protocol.lag_limit()) for v in speeds_rps]
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(jobs), desc=f"sweep {mode}/{spec}", unit="run")
    got = pool_map(_run, jobs, default_workers() if workers is None else workers,
                   min_jobs=4, bar=bar)
    if bar:
        bar.close()
    failed = np.array([f for f, _ in got], dtype=bool)
    ripple = np.array([m["rms_velocity_error_rad_s"] if m is not None and not f else math.nan
                       for f, m in got])
    return EntrySweep(spec, mode, system, np.asarray(speeds_rps, dtype=float), ripple, failed,
                      identified, [m for _, m in got])


def decibel_summary(entry: EntrySweep, none: EntrySweep, hump_db: float = HUMP_DB
                    ) -> dict[str, Any]:
    """The entry's attenuation of the RMS velocity ripple against ``none``'s at each
    speed of the same sweep, in dB as stepdamp-bench scores it (a lost run
    :data:`FAILURE_DB`; nan where ``none`` lost its steps), and its summary: mean,
    median and worst over the speeds where it is defined, and the humps, the
    speeds where the entry holds its steps and ripples more than ``none`` by over
    ``hump_db`` (its lost runs are counted apart)."""
    if not np.array_equal(entry.speeds_rps, none.speeds_rps):
        raise ParameterError("decibel_summary: the two sweeps must share their speeds")
    db = np.array([math.nan if nf else FAILURE_DB if ef else attenuation_db(float(n), float(e))
                   for n, e, nf, ef in zip(none.ripple_rad_s, entry.ripple_rad_s, none.failed,
                                           entry.failed)])
    ok = np.isfinite(db)
    worst = int(np.flatnonzero(ok)[np.argmin(db[ok])]) if ok.any() else None
    humps = np.flatnonzero(ok & ~entry.failed & (db < -hump_db))
    return {"attenuation_db": [None if not math.isfinite(x) else float(x) for x in db],
            "mean_db": float(np.mean(db[ok])) if ok.any() else None,
            "median_db": float(np.median(db[ok])) if ok.any() else None,
            "worst_db": None if worst is None else float(db[worst]),
            "worst_speed_rps": None if worst is None else float(entry.speeds_rps[worst]),
            "humps_rps": [float(entry.speeds_rps[k]) for k in humps],
            "hump_db": float(hump_db), "speeds_scored": int(ok.sum())}


def plot_entry_sweeps(sweeps: Sequence[EntrySweep], path: str) -> None:
    """RMS ripple against speed, one line per entry; lost runs crossed at the
    top, prominent peaks circled (one-speed spikes, likely aliasing: a triangle
    above), predicted resonances marked in open loop."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    top = max([float(np.nanmax(sw.ripple_rad_s)) for sw in sweeps
               if np.isfinite(sw.ripple_rad_s).any()] or [1.0])
    lost_label = "lost steps"
    for k, sw in enumerate(sweeps):
        colour = "black" if sw.entry == "none" else POLICY_COLOURS[k % len(POLICY_COLOURS)]
        ax.semilogy(sw.speeds_rps, sw.ripple_rad_s, color=colour, marker=".", ms=3, lw=1.0,
                    label=f"{sw.mode}, {sw.entry}")
        if sw.failed.any():
            ax.semilogy(sw.speeds_rps[sw.failed], np.full(int(sw.failed.sum()), top * 1.3), "x",
                        color="red", label=lost_label)
            lost_label = None
        for peak in sw.peaks():
            ax.plot(peak["speed_rps"], peak["ripple"] * (1.25 if peak["lone"] else 1.0),
                    "v" if peak["lone"] else "o", ms=5 if peak["lone"] else 10,
                    mfc="none", color=colour, alpha=0.7, zorder=0)
    if sweeps[0].mode == "open-loop":
        mark_resonances(ax, sweeps[0].system.predicted_resonances_rps())
    finish_ripple_axes(ax, f"Damping sweep: {sweeps[0].system.name}\n(circles: prominent peaks; "
                       "triangles: one-speed spikes)")
    save_figure(fig, path)
