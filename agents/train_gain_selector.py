"""Training of the v0 gain selector: ``StepperDampResidual-v0``, a policy that
picks the residual's gains on top of the patent's feedforward
(:mod:`stepdamp_agents.task`).

The family's part of :mod:`stepdamp_agents.train` (:class:`~.family.TrainingFamily`):
the env is v0's native vector envs wrapped as residuals on top of the base
controller (:func:`~.residual.make_residual_vec_env`); saved models are read
back as :class:`~.policy.ResidualAgent`; validation settles as the core does.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

from stepdamp_env.env import DEFAULT_EPISODE_STEPS

from .family import TrainingFamily
from .task import RESIDUAL_ENV_ID, task_kwargs

__all__ = ["FAMILY", "GainSelectorTraining"]


class GainSelectorTraining(TrainingFamily):
    env_id = RESIDUAL_ENV_ID
    algos = ("ppo", "sac", "td3")
    kind = "gain-selector"

    def task_kwargs(self, env_kwargs: dict[str, Any] | None
                    ) -> tuple[dict[str, Any], dict[str, Any]]:
        return task_kwargs(env_kwargs)

    def make_env(self, motors: Sequence[Any], per_motor: int, seed: int,
                 env_kwargs: dict[str, Any], wrapper_kwargs: dict[str, Any],
                 algo: str, algo_kwargs: dict[str, Any], num_threads: int = 1) -> Any:
        from .residual import make_residual_vec_env

        options = dict(env_kwargs)
        max_steps = int(options.pop("max_episode_steps", DEFAULT_EPISODE_STEPS))
        return make_residual_vec_env(motors, per_motor, seed, max_episode_steps=max_steps,
                                     num_threads=num_threads, **wrapper_kwargs, **options)

    def seconds_per_step(self, env: Any) -> float:
        hold = getattr(env, "hold_steps", 1)     # HeldFeedbackVecEnv: one action, hold steps
        inner = getattr(env, "inner", env)
        return float(hold * inner.parts[0].venv.task.seconds_per_step)

    def agent_config(self, name: str, algo: str, env_kwargs: dict[str, Any],
                     wrapper_kwargs: dict[str, Any], training: dict[str, Any]
                     ) -> dict[str, Any]:
        wk = wrapper_kwargs
        return {"name": name, "algo": algo,
                "base": wk.get("base", "patent-ff"),
                "residual_scale": float(wk.get("residual_scale", 0.25)),
                "residual_action": wk.get("residual_action", "harmonic"),
                "hold_steps": int(wk.get("hold_steps", 1)),
                "feedback_gain": float(wk.get("feedback_gain", 0.1)),
                "estimate": "identified",
                "env_options": {k: env_kwargs[k] for k in ("agent_hz", "velocity_estimator")
                                if k in env_kwargs},
                "training": _with_wrapper_kwargs(training, wk)}

    def load_agent(self, path: str) -> Any:
        from .policy import ResidualAgent

        return ResidualAgent(path)

    def validation_settle(self) -> Callable[[Any], float | None]:
        return lambda system: None


def _with_wrapper_kwargs(training: dict[str, Any], wk: dict[str, Any]) -> dict[str, Any]:
    out = {k: v for k, v in training.items() if k != "hyperparams"}
    out["wrapper_kwargs"] = wk
    out["hyperparams"] = training["hyperparams"]
    return out


FAMILY = GainSelectorTraining()
