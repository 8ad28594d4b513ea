"""The per-step agents' ablations as one table: validation during training and the
stepdamp-bench v1 open-loop splits.

Each variant is a directory of ``stepdamp train --seeds`` runs (``seed<K>/``);
the leaderboard runs each directory as one entry pooling its seeds::

    stepdamp train --algo ars --seeds 1-3 --out runs/abl/history0 --set "env_kwargs={history: 0}"
    ...
    stepdamp leaderboard --suite open-loop --entries ff-delay-comp --policy runs/abl/* \\
        --out results/ablations
    python scripts/ablations.py results/ablations runs/abl/*

Prints a Markdown table: per variant its task change, training seconds per
seed, best validation IQM per seed, then per split the headline IQM [95 % CI],
the probability of improvement over ``ff-delay-comp`` [95 % CI] and the runs
that lost steps.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from stepdamp_agents.task import REFERENCE_TASK


def _task_change(log: dict) -> str:
    given = log["args"]["extra"].get("env_kwargs") or {}
    change = {k: v for k, v in given.items() if REFERENCE_TASK.get(k) != v}
    return ", ".join(f"{k}={v}" for k, v in change.items()) or "reference task"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("board", help="the leaderboard's --out directory")
    p.add_argument("runs", nargs="+", help="variant directories (seed<K>/ inside)")
    a = p.parse_args(argv)
    with open(os.path.join(a.board, "leaderboard.json"), encoding="utf-8") as fh:
        board = json.load(fh)
    entries = {(e["name"], e["split"]): e for e in board["entries"]
               if e["suite"] == "open-loop"}
    splits = list(board["protocol"]["splits"])
    head = ["variant", "task change", "train s / seed", "best validation IQM per seed"]
    for s in splits:
        head += [f"{s} IQM", f"{s} P over ff-delay-comp", f"{s} lost runs"]
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
            h, ci = e["headline"], e["headline"]["ci95"]
            pi, pci = (e["probability_of_improvement"]["ff-delay-comp"],
                       e["probability_of_improvement_ci95"]["ff-delay-comp"])
            lost = e["step_losses"]
            row += [f"{h['iqm']:.4f} [{ci[0]:.4f}, {ci[1]:.4f}]",
                    f"{pi:.2f} [{pci[0]:.2f}, {pci[1]:.2f}]",
                    f"{lost['runs_lost']} / {lost['runs']}"]
        print("| " + " | ".join(row) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
