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

import hashlib
import io
import json
import math
import os
import weakref
from collections import OrderedDict
from typing import Any, Sequence

import numpy as np

from stepdamp_env.bench.policy import MotorKnowledge, PolicyCard, PolicyContext, resolve_estimate

__all__ = ["ResidualAgent", "load_agent_config", "load_model", "clear_model_cache",
           "agent_config_path", "predict_rows", "policy_network", "PolicyNetwork"]

# Loaded models by the sha256 of their file's bytes (never by path: a file
# rewritten in place is loaded again), the most recent last.
_MODELS: "OrderedDict[str, Any]" = OrderedDict()
_MODELS_KEPT = 32


def agent_config_path(path: str) -> str:
    """The ``NAME.agent.json`` beside a ``NAME.zip``."""
    return os.path.splitext(path)[0] + ".agent.json"


def load_agent_config(path: str) -> dict[str, Any]:
    with open(agent_config_path(path), encoding="utf-8") as fh:
        return json.load(fh)


def load_model(path: str) -> Any:
    """The SB3 model in the file ``path``, read now and kept per process by the
    sha256 of its bytes (forked workers share it; a changed file is a new key).
    The model is built from the very bytes that were hashed."""
    with open(path, "rb") as fh:
        data = fh.read()
    key = hashlib.sha256(data).hexdigest()
    if key in _MODELS:
        _MODELS.move_to_end(key)
        return _MODELS[key]
    import torch

    from .per_step import ALGOS, POLICIES

    torch.set_num_threads(1)
    algo = load_agent_config(path)["algo"]
    # The policy class by this package's name (models saved before 0.2 name
    # the module ``agents.residual``).
    custom = {"policy_class": POLICIES[algo]} if algo in POLICIES else {}
    _MODELS[key] = ALGOS[algo].load(io.BytesIO(data), device="cpu", custom_objects=custom)
    while len(_MODELS) > _MODELS_KEPT:
        _MODELS.popitem(last=False)
    return _MODELS[key]


def clear_model_cache() -> None:
    """Forget every loaded model (the next :func:`load_model` reads and builds anew)."""
    _MODELS.clear()


class PolicyNetwork:
    """The deterministic action network of an SB3 policy, evaluated by
    :func:`stepdamp_env.fixedmath.mlp_forward`: the same bits on every CPU and for
    any batch size (torch picks its matrix kernels by instruction set and batch
    shape). Read through public modules: ``nn.Linear`` layers with ReLU or tanh
    between them, for PPO/A2C (the Gaussian's mean), TD3, SAC (tanh of the mean)
    and ARS policies on a flat Box observation; :func:`policy_network` says None
    for anything else."""

    def __init__(self, layers: Sequence[Any], final_tanh: bool) -> None:
        import torch.nn as nn

        from stepdamp_env.fixedmath import IDENTITY, RELU, TANH

        weights, biases, sizes, acts = [], [], [], []
        for module in layers:
            if isinstance(module, nn.Linear):
                w = module.weight.detach().cpu().numpy().astype(np.float64)
                b = (module.bias.detach().cpu().numpy().astype(np.float64)
                     if module.bias is not None else np.zeros(w.shape[0]))
                if not sizes:
                    sizes.append(w.shape[1])
                elif sizes[-1] != w.shape[1]:
                    raise ValueError("layer sizes do not chain")
                weights.append(w.ravel())
                biases.append(b)
                sizes.append(w.shape[0])
                acts.append(IDENTITY)
            elif isinstance(module, (nn.ReLU, nn.Tanh)) and acts and acts[-1] == IDENTITY:
                acts[-1] = RELU if isinstance(module, nn.ReLU) else TANH
            elif not isinstance(module, (nn.Identity, nn.Flatten)):
                raise ValueError(f"unsupported layer {type(module).__name__}")
        if not acts:
            raise ValueError("no layer")
        if final_tanh:
            if acts[-1] != IDENTITY:
                raise ValueError("tanh after an activation")
            acts[-1] = TANH
        self.weights = np.concatenate(weights)
        self.biases = np.concatenate(biases)
        self.sizes = np.array(sizes, dtype=np.int64)
        self.activations = np.array(acts, dtype=np.int64)

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        """Raw actions (float32, n x action dim) of float32 observation rows."""
        from stepdamp_env.fixedmath import mlp_forward

        x = np.ascontiguousarray(observations, dtype=np.float32)
        return mlp_forward(x, self.weights, self.biases, self.sizes,
                           self.activations).astype(np.float32)


# Networks by policy object (a model's network is read once).
_NETWORKS: "weakref.WeakKeyDictionary[Any, PolicyNetwork | None]" = weakref.WeakKeyDictionary()


def policy_network(policy: Any) -> PolicyNetwork | None:
    """The :class:`PolicyNetwork` of an SB3 policy, or None where its deterministic
    action is not a plain network of linear layers on a flat observation."""
    if policy in _NETWORKS:
        return _NETWORKS[policy]
    from gymnasium import spaces
    from stable_baselines3.common.distributions import DiagGaussianDistribution
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.common.torch_layers import FlattenExtractor
    from stable_baselines3.sac.policies import SACPolicy
    from stable_baselines3.td3.policies import TD3Policy

    def flat(extractor: Any) -> bool:
        return isinstance(extractor, FlattenExtractor)

    layers, final_tanh = None, False
    if isinstance(policy.observation_space, spaces.Box) and \
            len(policy.observation_space.shape) == 1 and \
            isinstance(policy.action_space, spaces.Box):
        if isinstance(policy, ActorCriticPolicy):
            if isinstance(policy.action_dist, DiagGaussianDistribution) and \
                    type(policy).get_distribution is ActorCriticPolicy.get_distribution and \
                    flat(policy.pi_features_extractor):
                layers = [*policy.mlp_extractor.policy_net, policy.action_net]
        elif isinstance(policy, TD3Policy):
            if flat(policy.actor.features_extractor):
                layers = [*policy.actor.mu]
        elif isinstance(policy, SACPolicy):
            if flat(policy.actor.features_extractor) and not policy.actor.use_sde:
                layers, final_tanh = [*policy.actor.latent_pi, policy.actor.mu], True
        elif type(policy).__name__ in ("ARSPolicy", "ARSLinearPolicy") and \
                flat(policy.features_extractor):
            layers = [*policy.action_net]
    network = None
    if layers is not None:
        try:
            network = PolicyNetwork(layers, final_tanh)
        except ValueError:
            network = None
    _NETWORKS[policy] = network
    return network


def _torch_action(policy: Any) -> Any:
    """The deterministic action through torch (for networks :func:`policy_network`
    cannot read; their last bits may depend on the CPU)."""
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.sac.policies import SACPolicy

    if isinstance(policy, ActorCriticPolicy):
        return lambda obs: policy.get_distribution(obs).get_actions(deterministic=True)
    if isinstance(policy, SACPolicy):
        return lambda obs: policy.actor(obs, deterministic=True)
    return policy.actor if hasattr(policy, "actor") else policy


def predict_rows(model: Any, observations: np.ndarray) -> np.ndarray:
    """``model.predict(x, deterministic=True)`` of float32 observation rows, each
    row alone: through :class:`PolicyNetwork` (fixed summation order, the same
    bits on any CPU and batch size) where the policy is a plain network, else
    row by row through torch with a warning. Then ``predict``'s clipping to
    the action space, or its unscaling of a squashed output."""
    from gymnasium import spaces

    policy = model.policy
    obs = np.asarray(observations, dtype=np.float32).reshape(
        (-1, *policy.observation_space.shape))
    network = policy_network(policy)
    if network is not None:
        actions = network(obs)
    else:
        import warnings

        import torch

        warnings.warn(f"{type(policy).__name__}: not a plain network; its actions go through "
                      "torch and may differ in the last bits between CPUs", RuntimeWarning,
                      stacklevel=2)
        policy.set_training_mode(False)
        act = _torch_action(policy)
        x = torch.as_tensor(obs)
        with torch.no_grad():
            actions = torch.cat([act(x[k:k + 1]) for k in range(len(x))]).cpu().numpy()
    actions = actions.reshape((-1, *policy.action_space.shape))
    if isinstance(policy.action_space, spaces.Box):
        if policy.squash_output:
            actions = policy.unscale_action(actions)
        else:
            actions = np.clip(actions, policy.action_space.low, policy.action_space.high)
    return actions


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

    def act_batch(self, observations: np.ndarray, rows: np.ndarray) -> np.ndarray:
        obs = np.asarray(observations, dtype=np.float32)
        x = self._rows.augment(obs, rows)
        if self.residual_action != "feedback":
            r = np.asarray(predict_rows(self.model, x), dtype=np.float64)
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
            self._rows_gain[rows] = np.asarray(predict_rows(self.model, x_in),
                                               dtype=np.float64).reshape(-1)
            self._rows_sq[rows] = 0.0
        self._rows_step += 1
        current = feedback_current(self._rows_gain[rows], vel, self.feedback_gain)
        return self._rows.env_action(current[:, None], self.residual_scale, "current",
                                     rows).astype(np.float32)

    def residual(self, observation: np.ndarray) -> np.ndarray:
        x = self._constants.augment(np.asarray(observation, dtype=np.float32)[None])
        return np.asarray(predict_rows(self.model, x), dtype=np.float64)

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
            r = predict_rows(self.model, np.append(x[0], np.float32(rms)).astype(np.float32))
            self._gain = np.asarray(r, dtype=np.float64).reshape(1)
            self._sq = 0.0
        self._step += 1
        current = feedback_current(self._gain, np.array([vel]), self.feedback_gain)
        a = self._constants.env_action(current[:, None], self.residual_scale, "current")
        return a[0].astype(np.float32)
