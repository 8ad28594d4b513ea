"""Learning curves of the committed reference agents, from their training logs.

Run: ``python scripts/learning_curves.py [--out docs/figures/learning_curves.png]``.
Plots the validation headline IQM (motors drawn around the presets with the
training-side validation seed, never the protocol's) against agent steps for
every seed of every entry in ``agents/reference/``, and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import re

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

REFERENCE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "agents", "reference")
LOG = re.compile(r"^(?P<name>[a-z0-9-]+)\.seed(?P<seed>\d+)\.train_log\.json$")


def curves() -> dict[str, dict[int, list[tuple[int, float]]]]:
    out: dict[str, dict[int, list[tuple[int, float]]]] = {}
    for fname in sorted(os.listdir(REFERENCE)):
        m = LOG.match(fname)
        if not m:
            continue
        with open(os.path.join(REFERENCE, fname), encoding="utf-8") as fh:
            log = json.load(fh)
        points = [(int(e["step"]), float(e["headline_iqm"])) for e in log["evaluations"]]
        out.setdefault(m["name"], {})[int(m["seed"])] = sorted(points)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/figures/learning_curves.png")
    a = ap.parse_args()
    data = curves()
    # Log axis: a run that blows up (TD3: 200x its start) and one that halves share a panel row.
    cols = min(3, len(data))
    rows = -(-len(data) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.4 * rows), squeeze=False)
    for ax in axes.ravel()[len(data):]:
        ax.set_visible(False)
    for ax, (name, seeds) in zip(axes.ravel(), sorted(data.items())):
        for seed, pts in sorted(seeds.items()):
            ax.semilogy([p[0] for p in pts], [p[1] for p in pts], marker="o", ms=3,
                        label=f"seed {seed}")
            best = min(p[1] for p in pts)
            print(f"{name:20s} seed {seed}: " + " ".join(f"{p[1]:.4f}" for p in pts)
                  + f"  (best {best:.4f})")
        base = next(iter(seeds.values()))[0][1]
        ax.axhline(base, color="k", ls="--", lw=1, label="step 0 (base)")
        ax.set_title(name)
        ax.set_xlabel("agent steps")
        ax.set_ylabel("validation headline IQM (ripple / undamped)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    os.makedirs(os.path.dirname(a.out) or ".", exist_ok=True)
    fig.savefig(a.out, dpi=90)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
