"""Residual reinforcement-learning agents for StepperDamp (installed as ``stepdamp_agents``).

ARS and RecurrentPPO (sb3-contrib), PPO, SAC and TD3 (stable-baselines3) as
residuals on the model-based baselines.

* :mod:`stepdamp_agents.per_step`: the per-step agents on ``StepperDamp-v1``
  (a decision every 10 ms on top of ff-delay-comp), their training envs and
  their leaderboard policy :class:`~stepdamp_agents.per_step.StepAgent`;
* :mod:`stepdamp_agents.residual`: zero-residual policies, zero-residual warm-up,
  and the v0 residual envs (the gain selector's);
* :mod:`stepdamp_agents.task`: the v0 residual task's id and reference configuration;
* :mod:`stepdamp_agents.train`: the training script (``stepdamp train``), one loop
  for every family; :mod:`stepdamp_agents.train_per_step` and
  :mod:`stepdamp_agents.train_gain_selector`: what each family brings to it
  (:class:`stepdamp_agents.family.TrainingFamily`); :mod:`stepdamp_agents.arguments`:
  a dataclass's fields as command-line options;
* :mod:`stepdamp_agents.policy`: loading models, the v0 agent as a leaderboard policy;
* ``hyperparams/{ars,ppo,ppo_lstm,sac,td3}.yml``: rl-baselines3-zoo hyperparameters, keyed
  by ``StepperDamp-v1`` (and ``StepperDampResidual-v0`` for the gain selector);
* ``reference/``: the committed models, ``<entry>.seed<K>.zip`` with their
  ``.agent.json`` configs and training logs: ``ars-per-step``,
  ``ars-per-step-25hz``, ``ppo-per-step``, ``td3-per-step`` and
  ``ppo-gain-selector`` (v0's agent, named ``ppo-residual``
  up to 0.5.0: one PPO decision, a damping gain, every 0.1 s); and, one per
  stepdamp-bench v3 suite, selected on its dev split (training seeds 11-15),
  ``ars-open-loop``, ``ars-servo`` and ``ars-mid-band``, and with PPO
  ``ppo-open-loop`` and ``ppo-mid-band`` (0.14.0), and ``ppo-open-loop-long``
  (0.17.0: ``ppo-open-loop`` trained for 1.5M decisions); ``ppo-moves`` (0.19.0:
  trained for stepdamp-bench v4's moves suite, selected on its dev split) and
  ``ppo-mid-band-datasheets`` (0.19.0: the mid-band trained on real catalogue
  motors, the datasheet pool's train part, selected on its dev part) and
  ``ppo-mid-band-unrelated`` and ``ppo-open-loop-unrelated`` (the mid-band
  and open loop on the pool without the scored catalogue motors' relatives);
* :mod:`stepdamp_agents.selection`: model selection on a dev split (v3's; v4's
  for moves), and the splits a training config records.

:func:`register_policies` (the ``stepdamp.policies`` entry point
``reference-agents``) registers every committed entry by its name, with all its
training seeds (stepdamp-bench v1 pools them; v0 runs seed 1 alone), and a
loader for models ``stepdamp train`` writes, so ``stepdamp leaderboard --policy
runs/ars/seed1/best.zip`` runs one with its own options, and ``--policy runs/ars``
(the output of ``stepdamp train --seeds 1-5 --out runs/ars``) runs its seeds'
``best.zip`` as one entry that pools them. This package itself
imports neither torch nor SB3 (``stepdamp --help`` stays fast), nor does
``import stepdamp_env``.
"""

from __future__ import annotations

import functools
import os
import re

from stepdamp_env.bench.registry import PolicySource, register_loader, register_policy

REFERENCE_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "reference")
_SEED_FILE = re.compile(r"^(?P<name>[a-z0-9-]+)\.seed(?P<seed>\d+)\.zip$")

__all__ = ["REFERENCE_DIR", "reference_names", "reference_agent", "reference_seeds",
           "agent_from_path", "register_policies"]


def reference_names() -> tuple[str, ...]:
    """Names of the entries committed in ``reference/`` (``<name>.seed<K>.zip``)."""
    names = {m["name"] for m in map(_SEED_FILE.match, os.listdir(REFERENCE_DIR)) if m}
    return tuple(sorted(names))


def reference_seeds(name: str = "ppo-gain-selector") -> dict[int, str]:
    """Training seed -> model path of the committed entry ``name``."""
    out = {int(m["seed"]): os.path.join(REFERENCE_DIR, m.string)
           for m in map(_SEED_FILE.match, os.listdir(REFERENCE_DIR)) if m and m["name"] == name}
    return dict(sorted(out.items()))


def agent_from_path(path: str, name: str | None = None):
    """The leaderboard policy of a model ``stepdamp train`` wrote: a per-step agent
    (``StepperDamp-v1``) or the v0 gain selector, by its ``.agent.json``."""
    from .policy import ResidualAgent, load_agent_config

    if load_agent_config(path).get("env_id") == "StepperDamp-v1":
        from .per_step import StepAgent

        return StepAgent(path, name=name)
    return ResidualAgent(path, name=name)


def reference_agent(name: str = "ppo-gain-selector", seed: int | None = None):
    """A committed entry as a leaderboard policy (its first training seed by default)."""
    seeds = reference_seeds(name)
    if not seeds or (seed is not None and seed not in seeds):
        raise FileNotFoundError(
            f"no reference model {name!r} seed {seed}: committed entries are "
            f"{list(reference_names())}; train one with `stepdamp train`")
    return agent_from_path(seeds[min(seeds) if seed is None else seed])


@functools.cache           # the same factory on every registration: registering is idempotent
def _seed_factory(path: str):
    def make():
        return agent_from_path(path)
    make.__qualname__ = f"agent_from_path[{os.path.basename(path)}]"
    return make


def _is_trained_model(path: str) -> bool:
    from .policy import agent_config_path

    return path.endswith(".zip") and os.path.isfile(agent_config_path(path))


def _load_trained_model(path: str) -> PolicySource:
    """A model ``stepdamp train`` wrote, named ``<config name>@<file stem>`` so that
    it never takes the name of the committed reference it may have been trained as."""
    from .policy import load_agent_config

    config = load_agent_config(path)
    stem = os.path.splitext(os.path.basename(path))[0]
    name = f"{config.get('name', 'agent')}@{stem}"

    def make():
        return agent_from_path(path, name=name)
    seed = config.get("training", {}).get("seed")
    return PolicySource(path, name, make, {int(seed): make} if seed is not None else None)


_SEED_DIR = re.compile(r"^seed(?P<seed>\d+)$")


def _seed_models(path: str) -> dict[int, str]:
    """Training seed -> ``best.zip`` of the ``seed<K>/`` runs in ``path``
    (``stepdamp train --seeds K-L --out path``)."""
    if not os.path.isdir(path):
        return {}
    out = {}
    for sub in os.listdir(path):
        m = _SEED_DIR.match(sub)
        model = os.path.join(path, sub, "best.zip")
        if m and _is_trained_model(model):
            out[int(m["seed"])] = model
    return dict(sorted(out.items()))


def _load_trained_seeds(path: str) -> PolicySource:
    """The runs of ``stepdamp train --seeds`` as one learned entry pooling its
    seeds' ``best.zip``, named ``<config name>@<directory name>``."""
    from .policy import load_agent_config

    seeds = _seed_models(path)
    names = {load_agent_config(p).get("name", "agent") for p in seeds.values()}
    if len(names) != 1:
        raise ValueError(f"the seeds' models have different names {sorted(names)}")
    name = f"{names.pop()}@{os.path.basename(os.path.normpath(path))}"

    def factory(model: str):
        return lambda: agent_from_path(model, name=name)
    makers = {k: factory(p) for k, p in seeds.items()}
    return PolicySource(path, name, makers[min(makers)], makers)


def register_policies() -> None:
    """Register the committed reference agents and the trained-model loader (idempotent)."""
    for name in reference_names():
        seeds = reference_seeds(name)
        algo = name.split("-")[0].upper()
        what = ("v0 gain selector (a damping gain every 0.1 s)" if "gain-selector" in name
                else "per-step residual on StepperDamp-v1")
        register_policy(name, _seed_factory(seeds[min(seeds)]), kind="agent",
                        description=f"committed {algo} {what}, seeds {sorted(seeds)}",
                        training_seeds={k: _seed_factory(p) for k, p in seeds.items()})
    register_loader("stepdamp-train", _is_trained_model, _load_trained_model)
    register_loader("stepdamp-train-seeds", lambda p: bool(_seed_models(p)), _load_trained_seeds)
