"""Learning curves of the committed reference agents, from their training logs.

Run: ``python scripts/learning_curves.py [--out docs/figures/learning_curves.png]
[--out-dev docs/figures/learning_curves_dev.png]
[--experiments DIR ... --names NAME ... --out-experiments PNG --line DB]``.

Two figures, one panel per entry and one line per seed, and a table printed:

* ``--out``: agents selected on validation motors (drawn around the presets
  with the training-side validation seed, never the protocol's): the
  validation headline IQM (ripple over undamped) against agent steps;
* ``--out-dev``: agents selected on stepdamp-bench v3's dev split
  (``stepdamp train --select-on dev``): the dev attenuation (dB, IQM over the
  suite's dev motors) against env steps;
* ``--out-experiments``: the same for the entries ``--names`` found in the
  ``--experiments`` directories (variants tried on dev, committed as entries or
  not), with a comparison entry's dev attenuation drawn at ``--line`` (named
  ``--line-name``), and with ``--out-experiments-wall`` against the training's
  wall time (``learn_s`` of the logs: without the dev checks). The open-loop
  variants of 0.17.0::

      python scripts/learning_curves.py --experiments agents/reference \
          docs/results/ablations/open-loop --names ppo-open-loop ppo-open-loop-long \
          ppo-lstm-open-loop --line 37.32 --out-experiments \
          docs/figures/learning_curves_open_loop_dev.png
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
Curves = dict[str, dict[int, list[tuple[int, float]]]]


def curves(directory: str = REFERENCE) -> tuple[Curves, Curves]:
    """(validation headline IQM, dev attenuation dB) curves per entry and seed of
    the ``<name>.seed<K>.train_log.json`` files in ``directory``."""
    validation: Curves = {}
    dev: Curves = {}
    for fname in sorted(os.listdir(directory)):
        m = LOG.match(fname)
        if not m:
            continue
        with open(os.path.join(directory, fname), encoding="utf-8") as fh:
            log = json.load(fh)
        evals = log["evaluations"]
        on_dev = bool(evals) and "attenuation_db" in evals[0]
        key = "attenuation_db" if on_dev else "headline_iqm"
        # (env steps, value, training wall s without the checks: learn_s where logged)
        points = sorted((int(e["step"]), float(e[key]), float(e.get("learn_s", "nan")))
                        for e in evals)
        (dev if on_dev else validation).setdefault(m["name"], {})[int(m["seed"])] = points
    return validation, dev


def plot(data: Curves, out: str, on_dev: bool, line: tuple[str, float] | None = None,
         shared: bool = False, wall: bool = False) -> None:
    if not data:
        return
    # Validation: log axis (a run that blows up, TD3 at 200x its start, and one that
    # halves share a panel row); dev: dB, already logarithmic.
    cols = min(3, len(data))
    rows = -(-len(data) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.4 * rows), squeeze=False,
                             sharex=shared, sharey=shared)
    for ax in axes.ravel()[len(data):]:
        ax.set_visible(False)
    for ax, (name, seeds) in zip(axes.ravel(), sorted(data.items())):
        for seed, pts in sorted(seeds.items()):
            draw = ax.plot if on_dev else ax.semilogy
            draw([p[2] if wall else p[0] for p in pts], [p[1] for p in pts], marker="o",
                 ms=3, label=f"seed {seed}")
            best = (max if on_dev else min)(p[1] for p in pts)
            fmt = ".2f" if on_dev else ".4f"
            print(f"{name:20s} seed {seed}: " + " ".join(f"{p[1]:{fmt}}" for p in pts)
                  + f"  (best {best:{fmt}})")
        base = next(iter(seeds.values()))[0][1]
        ax.axhline(base, color="k", ls="--", lw=1, label="step 0 (base)")
        if line is not None:
            ax.axhline(line[1], color="tab:red", ls=":", lw=1.2, label=line[0])
        ax.set_title(name)
        ax.set_xlabel("training wall time, s (2 cores, without the dev checks)" if wall
                      else "env steps (decisions)" if on_dev else "agent steps")
        ax.set_ylabel("dev attenuation IQM (dB)" if on_dev else
                      "validation headline IQM (ripple / undamped)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    os.makedirs(os.path.dirname(out) or ".", exist_ok=True)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    print(f"wrote {out}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/figures/learning_curves.png")
    ap.add_argument("--out-dev", default="docs/figures/learning_curves_dev.png")
    ap.add_argument("--experiments", nargs="*", default=(),
                    help="directories of <name>.seed<K>.train_log.json of dev runs")
    ap.add_argument("--names", nargs="*", default=None,
                    help="the entries of --experiments to draw (default: all)")
    ap.add_argument("--out-experiments", default="docs/figures/learning_curves_open_loop_dev.png")
    ap.add_argument("--out-experiments-wall", default=None,
                    help="the --experiments figure against training wall time, too")
    ap.add_argument("--line", type=float, default=None,
                    help="a comparison entry's dev attenuation (dB), drawn in each panel")
    ap.add_argument("--line-name", default="tuned-constant-gain",
                    help="the entry --line is (default tuned-constant-gain)")
    a = ap.parse_args()
    validation, dev = curves()
    plot(validation, a.out, on_dev=False)
    plot(dev, a.out_dev, on_dev=True)
    if a.experiments:
        line = None if a.line is None else (f"{a.line_name} {a.line:.1f} dB", a.line)
        found: Curves = {}
        for directory in a.experiments:
            found.update(curves(directory)[1])
        names = a.names if a.names is not None else sorted(found)
        missing = [n for n in names if n not in found]
        if missing:
            ap.error(f"--names {missing}: no dev training log in {list(a.experiments)}")
        plot({n: found[n] for n in names}, a.out_experiments, on_dev=True, line=line,
             shared=True)
        if a.out_experiments_wall:
            plot({n: found[n] for n in names}, a.out_experiments_wall, on_dev=True, line=line,
                 shared=True, wall=True)


if __name__ == "__main__":
    main()
