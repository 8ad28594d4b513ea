"""Figures: ripple against speed, and velocity error against time (patent Figs. 4-7)."""

from __future__ import annotations

import os
from typing import Sequence

import numpy as np

from .io import atomic_path
from .params import SystemParams
from .simulation import DEFAULT_ACCEL_RPS2, RunSettings, SpeedProfile, simulate
from .sweep import SweepResult

__all__ = ["POLICY_COLOURS", "POLICY_MARKERS", "BASE_CONTROLLER_STYLES", "finish_ripple_axes",
           "finish_trace_axes",
           "legend_outside", "mark_resonances", "plot_sweep", "plot_velocity_error_traces",
           "pyplot", "save_figure", "trace_speeds"]

#: Colours and markers of policies in every figure (Tableau 10 without grey, which
#: is kept for annotations; black is the undamped reference).
# tab10, then ten more that stay apart from it: a full board has more than ten entries.
POLICY_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple",
                  "tab:brown", "tab:pink", "tab:olive", "tab:cyan", "tab:gray",
                  "navy", "gold", "teal", "magenta", "lime", "maroon", "indigo",
                  "coral", "yellowgreen", "slategray", "sienna", "deepskyblue",
                  "darkorange", "olivedrab", "crimson", "darkviolet", "peru",
                  "steelblue", "hotpink", "chocolate", "darkkhaki", "mediumpurple")
POLICY_MARKERS = ("s", "^", "D", "v", "P", "X", "<", ">", "*")
#: The simulation core's damping settings, styled like the policies of the same name.
BASE_CONTROLLER_STYLES = {"none": ("black", "o"), "patent-ff": (POLICY_COLOURS[0], POLICY_MARKERS[0])}


def pyplot():
    """matplotlib.pyplot on the Agg backend (files only, no screen)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str | os.PathLike[str]) -> None:
    """Lay out ``fig``, save it as a PNG atomically, and close it."""
    fig.tight_layout()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=110, format="png")
    finally:
        pyplot().close(fig)


def legend_outside(ax, fontsize: float = 8) -> None:
    """The legend right of the axes, off the data."""
    ax.legend(fontsize=fontsize, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)


def finish_ripple_axes(ax, title: str) -> None:
    """Labels, title, grid and legend of a ripple-against-speed axis."""
    ax.set_xlabel("command speed (rev/s)")
    ax.set_ylabel("RMS velocity error (rad/s)")
    ax.set_title(title, pad=14)
    ax.grid(True, which="both", alpha=0.3)
    legend_outside(ax)


def finish_trace_axes(ax, ylabel: str, title: str, title_size: float = 8) -> None:
    """Label, title, grid and legend of one speed's velocity-error trace."""
    ax.set_ylabel(ylabel, fontsize=8)
    ax.set_title(title, fontsize=title_size, loc="left")
    ax.grid(True, alpha=0.3)
    legend_outside(ax, fontsize=7)


def mark_resonances(ax, resonances) -> None:
    """Dashed lines at the predicted resonances, labelled above the axes (off the data)."""
    for h, v in resonances.items():
        ax.axvline(v, color="grey", ls="--", lw=0.8, zorder=0)
        ax.annotate(f"h={h}", (v, 1.0), xycoords=("data", "axes fraction"), xytext=(0, 2),
                    textcoords="offset points", ha="center", va="bottom", fontsize=8,
                    color="grey", annotation_clip=False)


def plot_sweep(sweeps: Sequence[SweepResult], path: str | os.PathLike[str],
               title: str | None = None) -> None:
    """RMS velocity error against command speed, every sweep on one axis.

    Predicted resonances are marked for open-loop sweeps (the servo loop has no
    peak there); resonance peaks the sweep really has (:meth:`SweepResult.peaks`,
    ``is_resonance``) are circled; runs that lost steps are crossed.
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    lost_label = "step loss"
    for sw in sweeps:
        colour, marker = BASE_CONTROLLER_STYLES.get(sw.settings.base_controller, (None, "."))
        ripple = sw.column("rms_velocity_error_rad_s")
        ax.semilogy(sw.speeds_rps, ripple, color=colour, marker=marker, ms=3, mfc="none",
                    lw=1.0, label=f"{sw.settings.mode}, {sw.settings.base_controller}")
        lost = sw.column("step_loss").astype(bool)
        if lost.any():
            ax.semilogy(sw.speeds_rps[lost], ripple[lost], "x", color="red", label=lost_label)
            lost_label = None
        for h, peak in sw.peaks().items():
            if peak["is_resonance"]:
                ax.plot(peak["speed_rps"], peak["ripple_rad_s"], "o", ms=10, mfc="none",
                        color="grey", zorder=0)
    system = sweeps[0].system
    if any(sw.settings.mode == "open-loop" for sw in sweeps):
        mark_resonances(ax, system.predicted_resonances_rps())
    finish_ripple_axes(ax, title or f"Resonance sweep: {system.name}")
    save_figure(fig, path)


def plot_velocity_error_traces(system: SystemParams, settings: RunSettings | Sequence[RunSettings],
                               speeds_rps: Sequence[float], path: str | os.PathLike[str],
                               accel_rps2: float = DEFAULT_ACCEL_RPS2,
                               title: str | None = None) -> None:
    """Velocity error against time at several speeds, stacked (patent Figs. 4-7).

    Each panel shows the whole measuring window of one run per setting, one
    sample per PWM period.
    """
    plt = pyplot()
    runs = [settings] if isinstance(settings, RunSettings) else list(settings)
    speeds = list(speeds_rps)
    fig, axes = plt.subplots(len(speeds), 1, figsize=(9, 1.5 + 1.4 * len(speeds)),
                             sharex=True, squeeze=False)
    for ax, v in zip(axes[:, 0], speeds):
        for rs in runs:
            res = simulate(system, profile=SpeedProfile(speed_rps=float(v), accel_rps2=accel_rps2),
                           settings=rs, trace=True)
            tr = res.trace
            sel = tr["t"] >= res.window_start_s - 1e-12
            t = tr["t"][sel] - res.window_start_s
            err = tr["omega_cmd"][sel] - tr["omega"][sel]
            colour = BASE_CONTROLLER_STYLES.get(rs.base_controller, (None, ""))[0]
            ax.plot(t * 1e3, err, lw=0.6, color=colour,
                    label=f"{rs.base_controller}: RMS {res.metrics.rms_velocity_error_rad_s:.3g} rad/s")
        finish_trace_axes(ax, "rad/s", f"{v:.3g} rev/s")
    axes[-1, 0].set_xlabel("time in the measuring window (ms), one sample per PWM period")
    fig.suptitle(title or f"Velocity error w_cmd - w: {system.name}, {runs[0].mode}",
                 fontsize=10)
    save_figure(fig, path)


def trace_speeds(system: SystemParams, speeds: np.ndarray) -> list[float]:
    """Speeds for the time figure: the grid points nearest the three predictions,
    plus the lowest and highest speed of the sweep."""
    chosen = {float(speeds[0]), float(speeds[-1])}
    for v in system.predicted_resonances_rps().values():
        chosen.add(float(speeds[np.argmin(np.abs(speeds - v))]))
    return sorted(chosen)
