"""Residual reinforcement-learning agents for StepperDamp (SAC, TD3, PPO; stable-baselines3).

* :mod:`agents.residual`: zero-residual policies, zero-residual warm-up, the
  residual training envs and the action scaling;
* :mod:`agents.train`: the training script (``stepdamp train``);
* :mod:`agents.policy`: a trained agent as a leaderboard policy;
* ``agents/hyperparams/{sac,td3,ppo}.yml``: rl-baselines3-zoo hyperparameters;
* ``agents/reference/``: where the reference model goes once one beats the
  baselines (none is committed yet: no training run has, see README).

Importing :mod:`agents.residual` registers ``"ResidualMlpPolicy"`` in SB3's policy
aliases (so the zoo resolves it with ``--gym-packages stepdamp_env agents.residual``).
This package itself imports neither torch nor SB3 (``stepdamp --help`` stays fast),
nor does ``import stepdamp_env``.

``stepdamp leaderboard --policy agents:sac_residual`` evaluates the reference model
(once there is one; until then give a trained model with ``agents.policy.ResidualAgent``).
"""

from __future__ import annotations

import os

REFERENCE_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "reference")

__all__ = ["REFERENCE_DIR", "reference_agent", "sac_residual"]


def reference_agent(algo: str = "sac"):
    """The committed reference model of ``algo`` as a leaderboard policy."""
    from .policy import ResidualAgent

    path = os.path.join(REFERENCE_DIR, f"{algo}-residual.zip")
    if not os.path.isfile(path):
        raise FileNotFoundError(
            f"no reference model {path}: none is committed yet (no training run has beaten "
            "the baselines); train one with `stepdamp train --algo {algo}`")
    return ResidualAgent(path)


def sac_residual():
    """``agents:sac_residual``: the reference SAC residual agent (name ``sac-residual``)."""
    return reference_agent("sac")
