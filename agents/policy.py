"""A trained residual agent as a leaderboard policy (:class:`stepdamp_env.bench.policy.Policy`).

The agent's network sees the env's observation plus the episode constants the
drive knows (:func:`stepdamp_agents.residual.context_features`, computed in ``reset``
from the leaderboard's identified model and the nominal drive), so a model that
``stepdamp train`` wrote is put on the leaderboard by its path, its
``.agent.json`` beside it (:func:`stepdamp_agents.register_policies` registers
the loader)::

    stepdamp leaderboard --policy runs/ppo/best.zip --out results/leaderboard

A model is a ``NAME.zip`` (SB3) beside ``NAME.agent.json`` (algorithm, base,
residual scale, env options, training arguments), as ``stepdamp train`` writes.
"""

from __future__ import annotations

import json
import math
import os
from typing import Any, Sequence

import numpy as np

from stepdamp_env.bench.policy import MotorKnowledge, PolicyCard, PolicyContext, resolve_estimate

__all__ = ["ResidualAgent", "load_agent_config", "load_model", "forget_model", "agent_config_path",
           "predict_rows"]

_MODELS: dict[str, Any] = {}


def agent_config_path(path: str) -> str:
    """The ``NAME.agent.json`` beside a ``NAME.zip``."""
    return os.path.splitext(path)[0] + ".agent.json"


def load_agent_config(path: str) -> dict[str, Any]:
    with open(agent_config_path(path), encoding="utf-8") as fh:
        return json.load(fh)


def load_model(path: str) -> Any:
    """The SB3 model at ``path`` (cached per process: forked workers share it)."""
    path = os.path.abspath(path)
    if path not in _MODELS:
        import torch

        from .per_step import ALGOS, POLICIES

        torch.set_num_threads(1)
        algo = load_agent_config(path)["algo"]
        # The policy class by this package's name (models saved before 0.2 name
        # the module ``agents.residual``).
        custom = {"policy_class": POLICIES[algo]} if algo in POLICIES else {}
        _MODELS[path] = ALGOS[algo].load(path, device="cpu", custom_objects=custom)
    return _MODELS[path]


def _deterministic_action(policy: Any) -> Any:
    """The network part of the policy's deterministic ``predict`` (the body of
    SB3's ``_predict`` for each policy family, through public methods)."""
    from stable_baselines3.common.distributions import DiagGaussianDistribution
    from stable_baselines3.common.policies import ActorCriticPolicy, BaseModel
    from stable_baselines3.sac.policies import SACPolicy
    from stable_baselines3.td3.policies import TD3Policy

    if isinstance(policy, ActorCriticPolicy):
        if isinstance(policy.action_dist, DiagGaussianDistribution) and \
                type(policy).get_distribution is ActorCriticPolicy.get_distribution:
            # The Gaussian's mode is its mean: the action net on the actor's latent
            # (get_distribution's steps without building the distribution object).
            return lambda obs: policy.action_net(policy.mlp_extractor.forward_actor(
                BaseModel.extract_features(policy, obs, policy.pi_features_extractor)))
        return lambda obs: policy.get_distribution(obs).get_actions(deterministic=True)
    if isinstance(policy, SACPolicy):
        return lambda obs: policy.actor(obs, deterministic=True)
    if isinstance(policy, TD3Policy):
        return policy.actor
    return policy            # ARS: forward is the deterministic action


def predict_rows(model: Any, observations: np.ndarray, *, eval_mode: bool = True
                 ) -> np.ndarray:
    """``model.predict(x[None], deterministic=True)[0][0]`` of each row x, stacked.

    Each row goes through the network as a batch of its own: a batch of many
    rows would change the matrix kernels' summation order and with it the
    last bits of the actions, and the leaderboard's batched runs must equal
    the scalar ones bit for bit. ``predict``'s bookkeeping (mode switch, input
    checks, clipping) is done once for all rows; the per-row steps are its own
    (``tests/test_scale.py`` checks the equality on every reference model).
    ``eval_mode=False`` skips the switch to evaluation mode (the caller made it).
    """
    import torch
    from gymnasium import spaces

    policy = model.policy
    if eval_mode:
        policy.set_training_mode(False)
    act = _deterministic_action(policy)
    x = torch.as_tensor(np.asarray(observations, dtype=np.float32))
    with torch.no_grad():
        out = [act(x[k:k + 1]) for k in range(len(x))]
    actions = torch.cat(out).cpu().numpy().reshape((-1, *policy.action_space.shape))
    if isinstance(policy.action_space, spaces.Box):
        if policy.squash_output:
            actions = policy.unscale_action(actions)
        else:
            actions = np.clip(actions, policy.action_space.low, policy.action_space.high)
    return actions


def forget_model(path: str) -> None:
    """Drop the cached model of ``path`` (after the file was rewritten)."""
    _MODELS.pop(os.path.abspath(path), None)


class ResidualAgent:
    """Policy: base controller (patent-ff, optionally ff-delay-comp's lead) plus
    the network's residual, deterministic."""

    def __init__(self, path: str, name: str | None = None) -> None:
        from .residual import EpisodeConstants, RESIDUAL_ACTIONS

        self.path = os.path.abspath(path)
        self.config = load_agent_config(self.path)
        self.name = name or self.config["name"]
        self.model = load_model(self.path)
        self.base = self.config["base"]
        self.residual_scale = float(self.config["residual_scale"])
        self.residual_action = self.config.get("residual_action", "harmonic")
        self.action_mode = RESIDUAL_ACTIONS[self.residual_action]
        # Env options the agent was trained with (agent rate, velocity estimator).
        self.env_extra = {k: v for k, v in self.config.get("env_options", {}).items()
                          if k in ("agent_hz", "velocity_estimator")}
        self.hold_steps = int(self.config.get("hold_steps", 1))
        self.feedback_gain = float(self.config.get("feedback_gain", 0.0))
        which = self.config.get("estimate", self.config.get("eval_estimate", "identified"))
        self.card = PolicyCard(sensors="encoder, currents (observation)", model=which,
                               learned=True, oracle=which == "exact")
        self._constants = EpisodeConstants(1)
        self._step = 0
        self._gain = np.zeros(1)
        self._sq = 0.0

    def env_options(self, knowledge: MotorKnowledge) -> dict[str, Any]:
        # "eval_estimate": the key of configs written before 0.2.
        which = self.config.get("estimate", self.config.get("eval_estimate", "identified"))
        return {"base_controller": "patent-ff", "action_mode": self.action_mode,
                **self.env_extra, "estimate": resolve_estimate(which, knowledge)}

    def reset(self, context: PolicyContext) -> None:
        est = context.estimate if context.estimate is not None else context.knowledge.exact
        self._constants.set(0, context.knowledge.nominal, est, context.mode, context.speed_rps,
                            context.action_scale, self.base)
        self._step, self._gain, self._sq = 0, np.zeros(1), 0.0

    # The batched runner's interface (stepdamp_env.bench.policy.BatchPolicy): the
    # same arithmetic as reset/act, row by row (all rows step together, so they
    # share the step count).
    def reset_batch(self, contexts: Sequence[PolicyContext]) -> None:
        from .residual import EpisodeConstants

        n = len(contexts)
        self._rows = EpisodeConstants(n)
        for i, context in enumerate(contexts):
            est = context.estimate if context.estimate is not None else context.knowledge.exact
            self._rows.set(i, context.knowledge.nominal, est, context.mode, context.speed_rps,
                           context.action_scale, self.base)
        self._rows_step, self._rows_gain, self._rows_sq = 0, np.zeros(n), np.zeros(n)
        self.model.policy.set_training_mode(False)

    def act_batch(self, observations: np.ndarray, rows: np.ndarray) -> np.ndarray:
        obs = np.asarray(observations, dtype=np.float32)
        x = self._rows.augment(obs, rows)
        if self.residual_action != "feedback":
            r = np.asarray(predict_rows(self.model, x, eval_mode=False), dtype=np.float64)
            return self._rows.env_action(r, self.residual_scale, self.residual_action,
                                         rows).astype(np.float32)
        from .residual import feedback_current

        vel = x[:, obs.shape[1]].astype(np.float64)
        if self._rows_step > 0:
            self._rows_sq[rows] += vel * vel
        if self._rows_step % self.hold_steps == 0:
            rms = (np.sqrt(self._rows_sq[rows] / self.hold_steps) if self._rows_step > 0
                   else np.zeros(len(rows)))
            x_in = np.concatenate([x, rms.astype(np.float32)[:, None]], axis=1)
            self._rows_gain[rows] = np.asarray(predict_rows(self.model, x_in, eval_mode=False),
                                               dtype=np.float64).reshape(-1)
            self._rows_sq[rows] = 0.0
        self._rows_step += 1
        current = feedback_current(self._rows_gain[rows], vel, self.feedback_gain)
        return self._rows.env_action(current[:, None], self.residual_scale, "current",
                                     rows).astype(np.float32)

    def residual(self, observation: np.ndarray) -> np.ndarray:
        x = self._constants.augment(np.asarray(observation, dtype=np.float32)[None])
        r, _ = self.model.predict(x, deterministic=True)
        return np.asarray(r, dtype=np.float64)

    def act(self, observation: np.ndarray) -> np.ndarray:
        if self.residual_action != "feedback":
            a = self._constants.env_action(self.residual(observation), self.residual_scale,
                                           self.residual_action)
            return a[0].astype(np.float32)
        from .residual import feedback_current

        # The gain is chosen every hold_steps steps from the observation and the RMS
        # velocity feature of the observations since the last choice (as in training).
        x = self._constants.augment(np.asarray(observation, dtype=np.float32)[None])
        vel = float(x[0, len(observation)])
        if self._step > 0:
            self._sq += vel * vel
        if self._step % self.hold_steps == 0:
            rms = math.sqrt(self._sq / self.hold_steps) if self._step > 0 else 0.0
            r, _ = self.model.predict(np.append(x[0], np.float32(rms)).astype(np.float32),
                                      deterministic=True)
            self._gain = np.asarray(r, dtype=np.float64).reshape(1)
            self._sq = 0.0
        self._step += 1
        current = feedback_current(self._gain, np.array([vel]), self.feedback_gain)
        a = self._constants.env_action(current[:, None], self.residual_scale, "current")
        return a[0].astype(np.float32)
