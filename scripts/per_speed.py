"""Where the learned entries win and lose, per speed: each entry's RMS velocity
error over ``ff-delay-comp``'s on the same run (motor, evaluation seed, speed),
per speed label (``h4``, ``h2``, ``h1``: the resonances; ``off``: the speeds
between them), from a v1 board's runs file.

Run: ``python scripts/per_speed.py [docs/results] [--entries NAME ...]``.
Prints per open-loop split and entry: the median ratio and the fraction of runs
that beat ``ff-delay-comp`` (a learned entry's training seeds pooled; a run that
loses steps counts as a loss).
"""

from __future__ import annotations

import argparse
import json
import os

import numpy as np

from stepdamp_env.bench.report import GZIP_RUNS_FILE, open_runs_file

BASE = "ff-delay-comp"
DEFAULT = ("ars-per-step-25hz", "ars-per-step", "ppo-per-step", "td3-per-step",
           "ppo-gain-selector", "tuned-constant-gain", "velocity-feedback")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("board", nargs="?", default="docs/results")
    p.add_argument("--entries", nargs="+", default=list(DEFAULT))
    a = p.parse_args()
    with open(os.path.join(a.board, "leaderboard.json"), encoding="utf-8") as fh:
        runs_file = json.load(fh).get("runs_file", GZIP_RUNS_FILE)
    with open_runs_file(os.path.join(a.board, runs_file)) as fh:
        raw = json.load(fh)
    for split in ("interpolation", "extrapolation"):
        rms: dict[str, dict[tuple, list[float]]] = {}
        for e in raw["entries"]:
            if e["suite"] == "open-loop" and e.get("split") == split:
                for r in e["runs"]:
                    ok = r["metrics"] is not None and not r["failed"]
                    v = r["metrics"]["rms_velocity_error_rad_s"] if ok else np.inf
                    key = (r["motor"], r["seed"], r["speed_label"])
                    rms.setdefault(e["name"], {}).setdefault(key, []).append(v)
        if BASE not in rms:
            continue
        labels = sorted({k[2] for k in rms[BASE]})
        print(f"## open-loop, {split}: ratio to {BASE} per speed (median; fraction of runs won)")
        print("| entry | " + " | ".join(labels) + " |")
        print("|---|" + "---|" * len(labels))
        for name in a.entries:
            if name not in rms:
                continue
            cells = []
            for lb in labels:
                ratios = np.array([v / rms[BASE][k][0] for k, vals in rms[name].items()
                                   if k[2] == lb for v in vals])
                cells.append(f"{np.median(ratios):.2f}; {np.mean(ratios < 1.0):.2f}")
            print(f"| {name} | " + " | ".join(cells) + " |")
        print()


if __name__ == "__main__":
    main()
