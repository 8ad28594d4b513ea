"""The mid-band of the voltage-mode drive: simulation against the eigenvalue analysis.

For every preset: the undamped open-loop ripple from 1 to 15 rev/s with the
current-mode drive (the default) and the voltage-mode drive
(``drive_mode="voltage"``), overlaid, with the unstable band that
:func:`stepdamp_env.analysis.midband` predicts shaded and the band measured on
the simulation (:func:`stepdamp_env.analysis.measured_band`) marked. Writes
``docs/results/midband/midband_sweep.png`` and ``midband.json``::

    python scripts/midband_sweep.py [--out DIR] [--step 0.25]

``tests/test_midband.py`` checks the measured edges against the predicted ones.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from stepdamp_env.analysis import (BAND_SETTLE_S, HIGH_RIPPLE, measured_band, midband,
                                   undamped_ripple)
from stepdamp_env.io import write_json
from stepdamp_env.plots import pyplot, save_figure
from stepdamp_env.presets import get_preset, preset_names

GRID_RPS = (1.0, 15.0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=os.path.join("docs", "results", "midband"))
    ap.add_argument("--step", type=float, default=0.25, help="speed step of the curves (rev/s)")
    args = ap.parse_args(argv)
    if not 0.01 <= args.step <= 14.0:
        ap.error(f"--step {args.step:g} is outside its allowed range [0.01, 14] rev/s")
    speeds = np.arange(GRID_RPS[0], GRID_RPS[1] + 1e-9, args.step)
    plt = pyplot()
    names = preset_names()
    fig, axes = plt.subplots(len(names), 1, figsize=(9, 2.6 * len(names)), sharex=True)
    record = {"grid_rps": [float(v) for v in speeds], "settle_s": BAND_SETTLE_S,
              "high_ripple": HIGH_RIPPLE, "motors": []}
    for ax, name in zip(axes, names):
        system = get_preset(name)
        predicted = midband(system.replace(drive_mode="voltage"))
        measured = measured_band(system, np.arange(GRID_RPS[0], GRID_RPS[1] + 1e-9, 0.5))
        curves = {}
        for mode in ("current", "voltage"):
            vals = [undamped_ripple(system, float(v), mode) for v in speeds]
            curves[mode] = vals
            ripple = [r for r, _ in vals]
            lost = [v for v, (_, f) in zip(speeds, vals) if f]
            line, = ax.semilogy(speeds, ripple, lw=1.2, marker="o" if mode == "current" else "s",
                                ms=3, mfc="none", label=f"{mode} mode, undamped")
            if lost:
                ax.plot(lost, [1.0] * len(lost), "x", color=line.get_color(), ms=6,
                        label=f"{mode} mode: lost steps")
        if predicted.unstable_rps:
            ax.axvspan(*predicted.unstable_rps, color="tab:red", alpha=0.12,
                       label="predicted unstable band (eigenvalues)")
        if measured.band_rps:
            for edge in measured.band_rps:
                ax.axvline(edge, color="tab:red", ls="--", lw=0.8)
        ax.axvline(predicted.bridge_limit_rps, color="0.4", ls=":", lw=1.0,
                   label="bridge circle Vdc/sqrt(2) reached")
        ax.axhline(HIGH_RIPPLE, color="0.6", lw=0.6)
        ax.set_ylim(1e-4, 3.0)
        ax.set_ylabel("RMS ripple / speed", fontsize=8)
        ax.set_title(f"{name} ({system.drive.Vdc:g} V): predicted "
                     f"{_band(predicted.unstable_rps)}, measured {_band(measured.band_rps)} "
                     "rev/s (dashed)", fontsize=9, loc="left")
        ax.grid(True, alpha=0.3, which="both")
        record["motors"].append({
            "motor": name, "predicted": predicted.to_dict(),
            "measured_band_rps": list(measured.band_rps) if measured.band_rps else None,
            "current_mode_limit_rps": measured.current_mode_limit_rps,
            "ripple": {m: [r for r, _ in c] for m, c in curves.items()},
            "lost_steps": {m: [f for _, f in c] for m, c in curves.items()}})
        print(f"{name:20s} predicted {_band(predicted.unstable_rps):>13s}  measured "
              f"{_band(measured.band_rps):>13s}  current mode rips from "
              f"{measured.current_mode_limit_rps} rev/s  bridge circle at "
              f"{predicted.bridge_limit_rps:.2f} rev/s")
    axes[0].legend(fontsize=7, loc="upper right", ncol=2)
    axes[-1].set_xlabel("command speed (rev/s)")
    fig.suptitle("Undamped open-loop ripple: current-mode vs voltage-mode drive "
                 f"(settled {BAND_SETTLE_S:g} s)", fontsize=10)
    os.makedirs(args.out, exist_ok=True)
    save_figure(fig, os.path.join(args.out, "midband_sweep.png"))
    write_json(os.path.join(args.out, "midband.json"), record)
    print(f"wrote {args.out}/midband_sweep.png, midband.json")
    return 0


def _band(band: tuple[float, float] | None) -> str:
    return "none" if band is None else f"{band[0]:.2f}-{band[1]:.2f}"


if __name__ == "__main__":
    sys.exit(main())
