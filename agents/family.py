"""What an agent family brings to the training script (:mod:`stepdamp_agents.train`).

The script is one loop (build the env, the algorithm, validate, checkpoint, save);
a family is what differs: which env it trains on and how it is built, what its
policy file's config says, how a saved model is read back as a policy, and the
settling its validation uses. Each family is one module
(:mod:`stepdamp_agents.train_per_step`, :mod:`stepdamp_agents.train_gain_selector`)
with one object, ``FAMILY``, that implements :class:`TrainingFamily`; the script
picks it by ``--env``. A family module imports torch and SB3 only inside its
methods, so the command line stays quick to parse.
"""

from __future__ import annotations

import abc
from typing import Any, Callable, Sequence

__all__ = ["TrainingFamily"]


class TrainingFamily(abc.ABC):
    """One agent family's part of training. Attributes: ``env_id`` (the zoo
    YAML's key and ``--env``), ``algos`` (the algorithms it trains), ``kind``
    (the default policy name's suffix: ``<algo>-<kind>``)."""

    env_id: str
    algos: tuple[str, ...]
    kind: str

    @abc.abstractmethod
    def task_kwargs(self, env_kwargs: dict[str, Any] | None
                    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """The YAML's ``env_kwargs`` over the family's reference task: (env
        options, wrapper kwargs)."""

    @abc.abstractmethod
    def make_env(self, motors: Sequence[Any], per_motor: int, seed: int,
                 env_kwargs: dict[str, Any], wrapper_kwargs: dict[str, Any],
                 algo: str, algo_kwargs: dict[str, Any], num_threads: int = 1) -> Any:
        """The training ``VecEnv``: ``per_motor`` drives around each motor of
        ``motors`` (preset names or datasheet mappings), drive k seeded ``seed + k``, each step's drives on ``num_threads``
        of numba's threads; may set defaults in ``algo_kwargs``."""

    @abc.abstractmethod
    def seconds_per_step(self, env: Any) -> float:
        """Simulated time (s) of one agent step of the training ``env``."""

    def after_build(self, env: Any, seed: int) -> None:
        """After the algorithm is built (SB3 seeds the env with the run's seed)."""

    @abc.abstractmethod
    def agent_config(self, name: str, algo: str, env_kwargs: dict[str, Any],
                     wrapper_kwargs: dict[str, Any], training: dict[str, Any]
                     ) -> dict[str, Any]:
        """The ``.agent.json`` beside each saved model: what the leaderboard's
        policy needs to act as trained."""

    @abc.abstractmethod
    def load_agent(self, path: str) -> Any:
        """A saved model (``path``: its zip) as a leaderboard policy."""

    @abc.abstractmethod
    def validation_settle(self) -> Callable[[Any], float | None]:
        """Settling (s) of a validation run on a system (None: the core's)."""
