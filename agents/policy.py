"""A trained residual agent as a leaderboard policy (:class:`baselines.base.Policy`).

The agent's network sees the env's observation plus the episode constants the
drive knows (:func:`agents.residual.context_features`, computed in ``reset``
from the leaderboard's identified model and the nominal drive), so it is loaded
as a ``package.module:attr`` policy rather than a bare ``.zip``::

    stepdamp leaderboard --policy agents:sac_residual --out results/leaderboard

A model is a ``NAME.zip`` (SB3) beside ``NAME.agent.json`` (algorithm, base,
residual scale, env options, training arguments), as ``stepdamp train`` writes.
"""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from baselines.base import MotorKnowledge, PolicyContext, resolve_estimate

__all__ = ["ResidualAgent", "load_agent_config", "load_model"]

_MODELS: dict[str, Any] = {}


def load_agent_config(path: str) -> dict[str, Any]:
    side = os.path.splitext(path)[0] + ".agent.json"
    with open(side, encoding="utf-8") as fh:
        return json.load(fh)


def load_model(path: str) -> Any:
    """The SB3 model at ``path`` (cached per process: forked workers share it)."""
    path = os.path.abspath(path)
    if path not in _MODELS:
        import torch

        from .residual import ALGOS

        torch.set_num_threads(1)
        algo = load_agent_config(path)["algo"]
        _MODELS[path] = ALGOS[algo].load(path, device="cpu")
    return _MODELS[path]


class ResidualAgent:
    """Policy: base controller (patent-ff, optionally ff-delay-comp's lead) plus
    the network's residual, deterministic."""

    def __init__(self, path: str, name: str | None = None) -> None:
        from .residual import context_features  # noqa: F401  (fail early if unavailable)

        self.path = os.path.abspath(path)
        self.config = load_agent_config(self.path)
        self.name = name or self.config["name"]
        self.model = load_model(self.path)
        self.base = self.config["base"]
        self.residual_scale = float(self.config["residual_scale"])
        self._features = np.zeros(12, dtype=np.float32)
        self._base_action = np.zeros(6)

    def env_options(self, knowledge: MotorKnowledge) -> dict[str, Any]:
        return {"base_controller": "patent-ff", "action_mode": "harmonic",
                "estimate": resolve_estimate(self.config.get("eval_estimate", "identified"),
                                             knowledge)}

    def reset(self, context: PolicyContext) -> None:
        from .residual import context_features

        est = context.estimate if context.estimate is not None else context.knowledge.exact
        self._features, dc = context_features(context.knowledge.nominal, est, context.mode,
                                              context.speed_rps, context.action_scale)
        self._base_action = dc.astype(np.float64) if self.base == "ff-delay-comp" \
            else np.zeros(6)

    def residual(self, observation: np.ndarray) -> np.ndarray:
        x = np.concatenate([np.asarray(observation, dtype=np.float32), self._features])
        r, _ = self.model.predict(x, deterministic=True)
        return np.asarray(r, dtype=np.float64)

    def act(self, observation: np.ndarray) -> np.ndarray:
        a = self._base_action + self.residual_scale * self.residual(observation)
        return np.clip(a, -1.0, 1.0).astype(np.float32)
