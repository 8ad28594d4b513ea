"""Residual reinforcement-learning agents for StepperDamp (installed as ``stepdamp_agents``).

SAC, TD3 and PPO from stable-baselines3, as residuals on the model-based baselines.

* :mod:`stepdamp_agents.residual`: zero-residual policies, zero-residual warm-up,
  the residual training envs and the action scaling;
* :mod:`stepdamp_agents.task`: the residual task's id and reference configuration;
* :mod:`stepdamp_agents.train`: the training script (``stepdamp train``);
* :mod:`stepdamp_agents.policy`: a trained agent as a leaderboard policy;
* ``hyperparams/{sac,td3,ppo}.yml``: rl-baselines3-zoo hyperparameters;
* ``reference/``: the reference model ``ppo-residual.zip`` (training seed 1,
  with its ``.agent.json`` config and ``ppo-residual.train_log.json``), which
  ``stepdamp leaderboard`` lists by default, and the same configuration
  trained with seeds 2-5 (``ppo-residual.seed<K>.*``): stepdamp-bench v1
  pools all five in the ``ppo-residual`` entry, v0 runs seed 1 alone.

:func:`register_policies` (the ``stepdamp.policies`` entry point
``reference-agents``) registers every committed reference model by its name
(``ppo-residual``) and a loader for models ``stepdamp train`` writes, so
``stepdamp leaderboard --policy runs/ppo/best.zip`` runs one with its own
options. Importing :mod:`stepdamp_agents.residual` registers
``"ResidualMlpPolicy"`` in SB3's policy aliases and the residual task
``StepperDampResidual-v0`` with Gymnasium (:mod:`stepdamp_agents.task`; the
zoo: ``--env StepperDampResidual-v0 --gym-packages stepdamp_agents.residual``).
This package itself imports neither torch nor SB3 (``stepdamp --help`` stays fast), nor does ``import stepdamp_env``.
"""

from __future__ import annotations

import os

from stepdamp_env.bench.registry import PolicySource, register_loader, register_policy

REFERENCE_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "reference")
ALGO_NAMES = ("ppo", "sac", "td3")

__all__ = ["REFERENCE_DIR", "reference_names", "reference_agent", "reference_seeds",
           "register_policies"]


def reference_names() -> tuple[str, ...]:
    """Names (``<algo>-residual``) of the reference models committed in ``reference/``."""
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


def reference_seeds(algo: str = "ppo") -> dict[int, str]:
    """Training seed -> model path of the committed reference models of ``algo``:
    ``<algo>-residual.zip`` (the one v0 runs) and ``<algo>-residual.seed<K>.zip``
    (the other seeds stepdamp-bench v1 pools), each by the seed in its config."""
    from .policy import load_agent_config

    out: dict[int, str] = {}
    stem = f"{algo}-residual"
    for fname in sorted(os.listdir(REFERENCE_DIR)):
        if fname == f"{stem}.zip" or (fname.startswith(f"{stem}.seed") and fname.endswith(".zip")):
            path = os.path.join(REFERENCE_DIR, fname)
            out[int(load_agent_config(path)["training"]["seed"])] = path
    return dict(sorted(out.items()))


def _reference_factory(algo: str):
    def make():
        return reference_agent(algo)
    make.__qualname__ = f"reference_agent[{algo}]"
    return make


def _seed_factory(path: str):
    def make():
        from .policy import ResidualAgent

        return ResidualAgent(path)
    make.__qualname__ = f"ResidualAgent[{os.path.basename(path)}]"
    return make


_FACTORIES = {algo: _reference_factory(algo) for algo in ALGO_NAMES}


def _is_trained_model(path: str) -> bool:
    from .policy import agent_config_path

    return path.endswith(".zip") and os.path.isfile(agent_config_path(path))


def _load_trained_model(path: str) -> PolicySource:
    """A model ``stepdamp train`` wrote, named ``<config name>@<file stem>`` so that
    it never takes the name of the committed reference it may have been trained as."""
    from .policy import ResidualAgent, load_agent_config

    config = load_agent_config(path)
    stem = os.path.splitext(os.path.basename(path))[0]
    name = f"{config.get('name', 'agent')}@{stem}"

    def make():
        return ResidualAgent(path, name=name)
    seed = config.get("training", {}).get("seed")
    return PolicySource(path, name, make, {int(seed): make} if seed is not None else None)


def register_policies() -> None:
    """Register the committed reference agents and the trained-model loader (idempotent)."""
    for name in reference_names():
        algo = name.split("-")[0]
        register_policy(name, _FACTORIES[algo], kind="agent",
                        description=f"committed reference {algo.upper()} residual agent",
                        training_seeds={k: _seed_factory(p)
                                        for k, p in reference_seeds(algo).items()})
    register_loader("stepdamp-train", _is_trained_model, _load_trained_model)
