"""Residual reinforcement-learning agents for StepperDamp (SAC, TD3, PPO; stable-baselines3).

* :mod:`agents.residual`: zero-residual policies, zero-residual warm-up, the
  residual training envs and the action scaling;
* :mod:`agents.train`: the training script (``stepdamp train``);
* :mod:`agents.policy`: a trained agent as a leaderboard policy;
* ``agents/hyperparams/{sac,td3,ppo}.yml``: rl-baselines3-zoo hyperparameters;
* ``agents/reference/``: the reference model ``ppo-residual.zip`` (with its
  ``.agent.json`` config and ``ppo-residual.train_log.json``), which
  ``stepdamp leaderboard`` lists by default.

Importing :mod:`agents.residual` registers ``"ResidualMlpPolicy"`` in SB3's policy
aliases (so the zoo resolves it with ``--gym-packages stepdamp_env agents.residual``).
This package itself imports neither torch nor SB3 (``stepdamp --help`` stays fast),
nor does ``import stepdamp_env``.

``stepdamp leaderboard`` evaluates every committed reference model by its name
(``ppo-residual``); another trained model is given with ``--policy`` (see
:mod:`agents.policy`).
"""

from __future__ import annotations

import os

REFERENCE_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "reference")
ALGO_NAMES = ("ppo", "sac", "td3")

__all__ = ["REFERENCE_DIR", "reference_names", "reference_agent", "ppo_residual",
           "sac_residual", "td3_residual"]


def reference_names() -> tuple[str, ...]:
    """Names (``<algo>-residual``) of the reference models committed in ``agents/reference``."""
    return tuple(f"{a}-residual" for a in ALGO_NAMES
                 if os.path.isfile(os.path.join(REFERENCE_DIR, f"{a}-residual.zip")))


def reference_agent(algo: str = "ppo"):
    """The committed reference model of ``algo`` as a leaderboard policy."""
    from .policy import ResidualAgent

    path = os.path.join(REFERENCE_DIR, f"{algo}-residual.zip")
    if not os.path.isfile(path):
        raise FileNotFoundError(
            f"no reference model {path}: committed ones are {list(reference_names())}; "
            f"train one with `stepdamp train --algo {algo}`")
    return ResidualAgent(path)


def ppo_residual():
    """``agents:ppo_residual``: the reference PPO residual agent (``ppo-residual``)."""
    return reference_agent("ppo")


def sac_residual():
    """``agents:sac_residual``: the SAC reference agent, if one is committed."""
    return reference_agent("sac")


def td3_residual():
    """``agents:td3_residual``: the TD3 reference agent, if one is committed."""
    return reference_agent("td3")
