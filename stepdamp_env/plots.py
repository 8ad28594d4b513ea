"""Figures: ripple against speed, and velocity error against time (patent Figs. 4-7)."""

from __future__ import annotations

import os
from typing import Sequence

import numpy as np

from .io import atomic_path
from .params import SystemParams
from .simulation import DEFAULT_ACCEL_RPS2, RunSettings, SpeedProfile, simulate
from .sweep import SweepResult

__all__ = ["plot_sweep", "plot_velocity_error_traces", "pyplot", "save_figure", "trace_speeds"]


def pyplot():
    """matplotlib.pyplot on the Agg backend (files only, no screen)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str | os.PathLike[str]) -> None:
    """Save ``fig`` as a PNG, atomically."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")


def plot_sweep(sweeps: Sequence[SweepResult], path: str | os.PathLike[str],
               title: str | None = None) -> None:
    """RMS velocity error against command speed, predicted resonances marked."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for sw in sweeps:
        ax.semilogy(sw.speeds_rps, sw.column("rms_velocity_error_rad_s"), marker=".",
                    label=f"{sw.settings.mode}, {sw.settings.damping}")
        lost = sw.column("step_loss").astype(bool)
        if lost.any():
            ax.semilogy(sw.speeds_rps[lost], sw.column("rms_velocity_error_rad_s")[lost], "x",
                        color="red", label="step loss")
    system = sweeps[0].system
    for h, v in system.predicted_resonances_rps().items():
        ax.axvline(v, color="grey", ls="--", lw=0.8)
        ax.text(v, 1.0, f" h={h}", transform=ax.get_xaxis_transform(), va="top",
                fontsize=8, color="grey")
    ax.set_xlabel("command speed (rev/s)")
    ax.set_ylabel("RMS velocity error (rad/s)")
    ax.set_title(title or f"Resonance sweep: {system.name}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def plot_velocity_error_traces(system: SystemParams, settings: RunSettings,
                               speeds_rps: Sequence[float], path: str | os.PathLike[str],
                               accel_rps2: float = DEFAULT_ACCEL_RPS2, span_s: float = 0.1,
                               title: str | None = None) -> None:
    """Velocity error against time at several speeds, stacked (patent Figs. 4-7).

    Each panel shows ``span_s`` seconds of the measuring window of one run.
    """
    plt = pyplot()
    speeds = list(speeds_rps)
    fig, axes = plt.subplots(len(speeds), 1, figsize=(8, 1.5 + 1.3 * len(speeds)),
                             sharex=True, squeeze=False)
    for ax, v in zip(axes[:, 0], speeds):
        res = simulate(system, profile=SpeedProfile(speed_rps=float(v), accel_rps2=accel_rps2),
                       settings=settings, trace=True, trace_every=4)
        tr = res.trace
        sel = tr["t"] >= res.window_start_s
        t = tr["t"][sel] - res.window_start_s
        err = tr["omega_cmd"][sel] - tr["omega"][sel]
        keep = t <= span_s
        ax.plot(t[keep] * 1e3, err[keep], lw=0.8)
        ax.set_ylabel("rad/s", fontsize=8)
        ax.text(0.99, 0.9, f"{v:.3g} rev/s  rms {res.metrics.rms_velocity_error_rad_s:.3g}",
                transform=ax.transAxes, ha="right", va="top", fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel("time in the measuring window (ms)")
    fig.suptitle(title or f"Velocity error w_cmd - w: {system.name}, {settings.mode}, "
                 f"{settings.damping}", fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def trace_speeds(system: SystemParams, speeds: np.ndarray) -> list[float]:
    """Speeds for the time figure: the grid points nearest the three predictions,
    plus the lowest and highest speed of the sweep."""
    chosen = {float(speeds[0]), float(speeds[-1])}
    for v in system.predicted_resonances_rps().values():
        chosen.add(float(speeds[np.argmin(np.abs(speeds - v))]))
    return sorted(chosen)
