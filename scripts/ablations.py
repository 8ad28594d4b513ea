"""The per-step agents' ablations as one table: validation during training and a
stepdamp-bench v3 board on the dev split (never a scored split).

Each variant is a directory of ``stepdamp train --seeds`` runs (``seed<K>/``);
the leaderboard runs each directory as one entry pooling its seeds::

    stepdamp train --algo ars --seeds 1-3 --out runs/abl/history0 --hyperparam "env_kwargs={history: 0}"
    ...
    stepdamp leaderboard --split dev --suite open-loop \\
        --entries ff-delay-comp tuned-constant-gain --policy runs/abl/* --out results/ablations
    python scripts/ablations.py results/ablations runs/abl/*

Prints a Markdown table: per variant its task change, training seconds per
seed, the best validation IQM per seed (training's own validation motors, drawn
from the training distribution), then on each split of the board the
attenuation (dB, IQM over motors [95 % CI]), the gap closed, the probability of
improvement over each comparison entry with the effect (median difference of
per-motor dB [95 % CI]), and the share of runs that held their steps.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from stepdamp_agents.task import REFERENCE_TASK

COMPARED = ("ff-delay-comp", "tuned-constant-gain")


def _task_change(log: dict) -> str:
    given = log["args"]["extra"].get("env_kwargs") or {}
    change = {k: v for k, v in given.items() if REFERENCE_TASK.get(k) != v}
    return ", ".join(f"{k}={v}" for k, v in change.items()) or "reference task"


def _interval(x: dict, fmt: str) -> str:
    lo, hi = x["ci"]
    return f"{x['iqm'] if 'iqm' in x else x['median']:{fmt}} [{lo:{fmt}}, {hi:{fmt}}]"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("board", help="the leaderboard's --out directory (a v3 board)")
    p.add_argument("runs", nargs="+", help="variant directories (seed<K>/ inside)")
    a = p.parse_args(argv)
    with open(os.path.join(a.board, "leaderboard.json"), encoding="utf-8") as fh:
        board = json.load(fh)
    if board["protocol"].get("version") != "v3":
        print(f"ablations: {a.board!r} is a {board['protocol'].get('version')} board; "
              "ablations are scored on v3's dev split", file=sys.stderr)
        return 2
    entries = {(e["name"], e["split"]): e for e in board["entries"]
               if e["suite"] == "open-loop"}
    splits = list(board["protocol"]["splits"])
    head = ["variant", "task change", "train s / seed", "best validation IQM per seed"]
    for s in splits:
        head += [f"{s} dB", f"{s} gap closed"]
        head += [f"{s} P over {c} (effect dB)" for c in COMPARED]
        head += [f"{s} success"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for run in a.runs:
        seeds = sorted(d for d in os.listdir(run) if d.startswith("seed"))
        logs = []
        for d in seeds:
            with open(os.path.join(run, d, "train_log.json"), encoding="utf-8") as fh:
                logs.append(json.load(fh))
        name = f"{logs[0]['config']['name']}@{os.path.basename(os.path.normpath(run))}"
        row = [os.path.basename(os.path.normpath(run)), _task_change(logs[0]),
               ", ".join(f"{log['train_wall_s']:.0f}" for log in logs),
               ", ".join(f"{log['best']['headline_iqm']:.4f}" for log in logs)]
        for s in splits:
            e = entries.get((name, s))
            if e is None:
                print(f"ablations: {name!r} is not on the board {a.board!r}", file=sys.stderr)
                return 2
            row += [_interval(e["attenuation_db"], ".1f"), _interval(e["gap_closed"], ".3f")]
            for c in COMPARED:
                pi = e["probability_of_improvement"].get(c)
                eff = e["effect_db"].get(c)
                row.append("-" if pi is None or eff is None else
                           f"{pi:.2f} ({_interval(eff, '+.1f')})")
            row.append(f"{e['success_rate']:.2f}")
        print("| " + " | ".join(row) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
