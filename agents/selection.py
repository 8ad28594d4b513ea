"""Model selection on a dev split (``stepdamp train --select-on dev``): stepdamp-bench
v3's for the suites v3 has, v4's for the moves suite.

The dev split (``stepdamp leaderboard --split dev``) is drawn from the training
distribution with its own seed and is never scored: it is the split for
tuning, ablations and model selection. :class:`DevValidator` scores a saved
model as the protocol's board does on the dev motors of one suite (identified
models, the protocol's evaluation seeds: v3's one, v4's three; the attenuation
counts the headline speeds) and returns the attenuation in dB (IQM over
motors; higher is better).

A training run records what it used in its config (``training.splits``):
``{"motors": "train", "selection": "dev"}`` here, ``"validation"`` for the
training-distribution motors of :class:`stepdamp_agents.train.Validator`,
``"none"`` when training ran no checks (the final model). None is a scored
split (:data:`SCORED_SPLITS`).
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["DevValidator", "SELECTION_SPLITS", "SCORED_SPLITS", "training_splits"]

#: Where a model may be selected: the dev split, or validation motors drawn from
#: the training distribution below the training seed limit.
SELECTION_SPLITS = ("dev", "validation")
#: The splits a board scores; no training, tuning or selection may see them.
SCORED_SPLITS = ("interpolation", "extrapolation", "catalogue", "custom")


def training_splits(config: dict[str, Any]) -> dict[str, str]:
    """The splits a model's training used (``training.splits`` of its config);
    models trained before it was recorded drew their motors below the training
    seed limit and were selected on validation motors from the same distribution."""
    recorded = (config.get("training") or {}).get("splits")
    return dict(recorded) if recorded else {"motors": "train", "selection": "validation"}


class DevValidator:
    """Scores a saved model on the dev motors of ``suite`` (dB, higher is better):
    v3's, or v4's for a suite v3 does not have (moves)."""

    metric = "attenuation_db"
    higher_is_better = True

    def __init__(self, suite: str) -> None:
        from stepdamp_env.bench.protocols import protocol_for
        from stepdamp_env.bench.suites import SUITES_THROUGH_V3

        self.suite = suite
        # v3's dev split where v3 has the suite (the committed models); v4's otherwise.
        self.version = "v3" if suite in SUITES_THROUGH_V3 else "v4"
        self.protocol = protocol_for(self.version).with_splits(["dev"]).with_suites([suite])

    def score(self, path: str) -> dict[str, Any]:
        """The dev board's row of the model in ``path`` (a ``stepdamp train`` zip)."""
        from stepdamp_env.bench import run_leaderboard

        board = run_leaderboard(self.protocol, [path], workers=1, progress=False)
        row = next(e for e in board["entries"]
                   if e["spec"] == path and e["suite"] == self.suite)
        db = row["attenuation_db"]
        return {"attenuation_db": db["iqm"], "attenuation_db_ci": db["ci"],
                "gap_closed": row["gap_closed"]["iqm"], "success_rate": row["success_rate"],
                "per_motor_db": row["per_motor_db"],
                "step_losses": row["step_losses"]["runs_lost"]}

    @staticmethod
    def better(new: dict[str, Any], best: dict[str, Any] | None) -> bool:
        value = new["attenuation_db"]
        return math.isfinite(value) and (best is None or value > best["attenuation_db"])
