"""Training of the per-step agents: ``StepperDamp-v1``, a policy acting every
agent step on top of ff-delay-comp (:data:`stepdamp_agents.per_step.REFERENCE_TASK`).

The family's part of :mod:`stepdamp_agents.train` (:class:`~.family.TrainingFamily`):
the env is native ``StepperDamp-v1`` vector envs, one block per preset
(:func:`~.per_step.make_training_env`), the residual is the env's own (a zero
action is ff-delay-comp); ARS meets the same episodes with every candidate of an
update (:class:`~.per_step.SameEpisodes`). Saved models are read back as
:class:`~.per_step.StepAgent`; validation settles as stepdamp-bench v1 does.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

from .family import TrainingFamily
from .task import ENV_ID_V1, INTERFACE_OPTIONS, task_options

__all__ = ["FAMILY", "PerStepTraining"]


class PerStepTraining(TrainingFamily):
    env_id = ENV_ID_V1
    algos = ("ars", "ppo", "ppo_lstm", "sac", "td3")
    kind = "per-step"

    def task_kwargs(self, env_kwargs: dict[str, Any] | None
                    ) -> tuple[dict[str, Any], dict[str, Any]]:
        return task_options(env_kwargs), {}

    def make_env(self, motors: Sequence[Any], per_motor: int, seed: int,
                 env_kwargs: dict[str, Any], wrapper_kwargs: dict[str, Any],
                 algo: str, algo_kwargs: dict[str, Any], num_threads: int = 1) -> Any:
        from .per_step import SameEpisodes, make_training_env

        env = make_training_env(motors, per_motor, seed, env_kwargs, num_threads)
        if algo == "ars":
            # Every candidate of an update on the same episodes, one per drive,
            # the blocks cycling through this seed's 1000 training seeds.
            env = SameEpisodes(env, seed, span=1000)
            algo_kwargs.setdefault("n_eval_episodes", env.num_envs)
        return env

    def seconds_per_step(self, env: Any) -> float:
        while not hasattr(env, "parts"):        # SameEpisodes around the presets' envs
            env = env.venv
        return float(env.parts[0].venv.task.seconds_per_step)

    def after_build(self, env: Any, seed: int) -> None:
        env.seed(seed)          # SB3 seeded the env with the run's seed: the run's own seeds

    def agent_config(self, name: str, algo: str, env_kwargs: dict[str, Any],
                     wrapper_kwargs: dict[str, Any], training: dict[str, Any]
                     ) -> dict[str, Any]:
        return {"name": name, "algo": algo, "env_id": ENV_ID_V1, "base": "ff-delay-comp",
                "estimate": "identified",
                "env_options": {k: v for k, v in env_kwargs.items() if k in INTERFACE_OPTIONS},
                "training": training}

    def load_agent(self, path: str) -> Any:
        from .per_step import StepAgent

        return StepAgent(path)

    def validation_settle(self) -> Callable[[Any], float | None]:
        from stepdamp_env.bench import full_protocol_v1

        v1 = full_protocol_v1()
        return lambda system: v1.settle_times(system)["open-loop"]


FAMILY = PerStepTraining()
