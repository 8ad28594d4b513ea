"""Model selection on a dev split (``stepdamp train --select-on dev``): stepdamp-bench
v3's for the suites v3 has, v4's for the moves suite; with ``--motor-pool
datasheets``, v4's board on motors drawn from the datasheet pool's dev part.

The dev split (``stepdamp leaderboard --split dev``) is drawn from the training
distribution with its own seed and is never scored: it is the split for
tuning, ablations and model selection. :class:`DevValidator` scores a saved
model as the protocol's board does on the dev motors of one suite (identified
models, the protocol's evaluation seeds: v3's one, v4's three; the attenuation
counts the headline speeds) and returns the attenuation in dB (IQM over
motors; higher is better).

A training run records what it used in its config (``training.splits``):
``{"motors": "train", "selection": "dev"}`` here (``"pool-train"`` and
``"pool-dev"`` for the datasheet pool's parts), ``"validation"`` for the
training-distribution motors of :class:`stepdamp_agents.train.Validator`,
``"none"`` when training ran no checks (the final model). None is a scored
split (:data:`SCORED_SPLITS`).
"""

from __future__ import annotations

import math
from types import MappingProxyType
from typing import Any

from stepdamp_env.params import ParameterError

__all__ = ["DevValidator", "SELECTION_SPLITS", "SCORED_SPLITS", "POOL_DEV_DRAW", "POOL_DEV_SENSORS",
           "training_splits"]

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


#: A datasheet pool's dev motors for selection (``--motor-pool datasheets...``):
#: how many, and the seed of their draw from the pool's dev part.
POOL_DEV_DRAW = MappingProxyType({"count": 12, "seed": 950_000})
#: The sensors of those dev motors (``--pool-dev-sensors``): the protocol's, as
#: ``--motors`` and the scored catalogue give them (the default), or the motor
#: file's defaults (no current noise), with which ``ppo-mid-band-datasheets`` and
#: ``ppo-mid-band-unrelated`` were selected (their configs' ``pool_dev`` has no
#: ``sensors``).
POOL_DEV_SENSORS = ("protocol", "motor-file")


class DevValidator:
    """Scores a saved model on the dev motors of ``suite`` (dB, higher is better):
    v3's, or v4's for a suite v3 does not have (moves); with a datasheet
    ``motor_pool``, v4's board on the motors :data:`POOL_DEV_DRAW` draws from
    that pool's dev part (:mod:`stepdamp_env.motorpool`), each the drive's own
    model as a catalogue motor is."""

    metric = "attenuation_db"
    higher_is_better = True

    def __init__(self, suite: str, motor_pool: str = "presets",
                 pool_dev_sensors: str = "protocol") -> None:
        from stepdamp_env.bench.protocols import protocol_for
        from stepdamp_env.bench.suites import SUITES_THROUGH_V3

        from stepdamp_env.motorpool import MOTOR_POOLS

        if motor_pool != "presets" and motor_pool not in MOTOR_POOLS:
            raise ParameterError(f"motor_pool={motor_pool!r} is not one of "
                                 f"{['presets', *MOTOR_POOLS]}")
        if pool_dev_sensors not in POOL_DEV_SENSORS:
            raise ParameterError(f"pool_dev_sensors={pool_dev_sensors!r} is not one of "
                                 f"{list(POOL_DEV_SENSORS)}")
        self.suite = suite
        pool = motor_pool != "presets"
        # v3's dev split where v3 has the suite (the committed models); v4's otherwise.
        self.version = "v3" if suite in SUITES_THROUGH_V3 and not pool else "v4"
        protocol = protocol_for(self.version).with_suites([suite])
        if pool:
            from stepdamp_env.motorpool import draw_datasheets, pool_systems

            from stepdamp_env.bench.protocols.drawn import with_protocol_sensors

            dev = pool_systems(draw_datasheets(POOL_DEV_DRAW["seed"], POOL_DEV_DRAW["count"],
                                               "dev", motor_pool=motor_pool))
            if pool_dev_sensors == "protocol":
                dev = tuple(with_protocol_sensors(s, protocol) for s in dev)
            self.protocol = protocol.with_custom_motors(dev)
        else:
            self.protocol = protocol.with_splits(["dev"])

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
