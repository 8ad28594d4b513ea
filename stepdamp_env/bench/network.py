"""The deterministic action of a stable-baselines3 policy, the same on every CPU.

torch picks its matrix kernels by instruction set and batch shape, so a
network's last bits depend on the CPU. :func:`predict_rows` evaluates an SB3
policy's deterministic action through :class:`PolicyNetwork` instead: its
``nn.Linear`` layers and activations, read through public modules, run by
:func:`stepdamp_env.fixednet.mlp_forward` (every sum in input order in
float64, one row at a time whatever the batch). Used by every learned entry
and by bare SB3 models on the leaderboard; :class:`RecurrentNetwork` does the
same for sb3-contrib's LSTM policies (RecurrentPPO), whose memory the caller
keeps per run. Training still uses torch. torch
and SB3 are imported when a network is first read, never by importing this
module.
"""

from __future__ import annotations

import warnings
import weakref
from typing import Any, Sequence

import numpy as np

__all__ = ["PolicyNetwork", "policy_network", "predict_rows", "RecurrentNetwork",
           "recurrent_network"]


class PolicyNetwork:
    """The deterministic action network of an SB3 policy, evaluated by
    :func:`stepdamp_env.fixednet.mlp_forward`: the same bits on every CPU and for
    any batch size (torch picks its matrix kernels by instruction set and batch
    shape). Read through public modules: ``nn.Linear`` layers with ReLU or tanh
    between them, for PPO/A2C (the Gaussian's mean), TD3, SAC (tanh of the mean)
    and ARS policies on a flat Box observation; :func:`policy_network` says None
    for anything else."""

    def __init__(self, layers: Sequence[Any], final_tanh: bool) -> None:
        import torch.nn as nn

        from stepdamp_env.fixednet import ACTIVATION

        IDENTITY, RELU, TANH = ACTIVATION.IDENTITY, ACTIVATION.RELU, ACTIVATION.TANH

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
        from stepdamp_env.fixednet import mlp_forward

        x = np.ascontiguousarray(observations, dtype=np.float32)
        return mlp_forward(x, self.weights, self.biases, self.sizes,
                           self.activations).astype(np.float32)


# Networks by policy object (a model's network is read once; models are loaded
# anew from their bytes, never changed in place).
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
    if network is not None and not _agrees_with_torch(policy, network):
        network = None          # a subclass computes its action otherwise
    _NETWORKS[policy] = network
    return network


def _agrees_with_torch(policy: Any, network: PolicyNetwork) -> bool:
    """The network gives the policy's own deterministic action (through torch) on
    probe observations, to float32 rounding: the layers read are the ones used."""
    import torch

    low = np.maximum(policy.observation_space.low, -3.0)
    high = np.minimum(policy.observation_space.high, 3.0)
    probe = np.random.default_rng(0).uniform(low, high, size=(16, low.size)).astype(np.float32)
    policy.set_training_mode(False)
    with torch.no_grad():
        want = _torch_action(policy)(torch.as_tensor(probe)).cpu().numpy()
    got = network(probe)
    return got.shape == want.reshape(got.shape).shape and \
        bool(np.allclose(got, want.reshape(got.shape), rtol=1e-4, atol=1e-5))


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
    if recurrent_network(policy) is not None:
        raise ValueError(f"model: {type(policy).__name__} is recurrent; its actions need the "
                         "memory of each run (RecurrentNetwork.step, as StepAgent keeps it)")
    obs = np.asarray(observations, dtype=np.float32).reshape(
        (-1, *policy.observation_space.shape))
    network = policy_network(policy)
    if network is not None:
        actions = network(obs)
    else:
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


class RecurrentNetwork:
    """The deterministic action of sb3-contrib's ``RecurrentActorCriticPolicy``
    (one LSTM layer, not shared with the critic, before the actor's
    :class:`PolicyNetwork` head), evaluated by
    :func:`stepdamp_env.fixednet.lstm_step` and ``mlp_forward``: the same bits
    on every CPU and for any batch. The memory (hidden and cell state, float64)
    is the caller's: :meth:`initial_state` for a batch of runs, :meth:`step`
    advances the rows it is given."""

    def __init__(self, lstm: Any, head: Sequence[Any]) -> None:
        def flat(name: str) -> np.ndarray:
            return getattr(lstm, name).detach().cpu().numpy().astype(np.float64).ravel()

        if lstm.num_layers != 1 or lstm.bidirectional or lstm.proj_size or \
                not lstm.bias or lstm.batch_first:
            raise ValueError("lstm: only a plain one-layer LSTM with biases is read")
        self.hidden = int(lstm.hidden_size)
        self.inputs = int(lstm.input_size)
        self.w_ih, self.w_hh = flat("weight_ih_l0"), flat("weight_hh_l0")
        self.bias = flat("bias_ih_l0") + flat("bias_hh_l0")
        self.head = PolicyNetwork(head, final_tanh=False)
        if int(self.head.sizes[0]) != self.hidden:
            raise ValueError(f"head: takes {int(self.head.sizes[0])} inputs, the LSTM gives "
                             f"{self.hidden}")

    def initial_state(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Zero memory (hidden, cell) for ``n`` runs, as at an episode's start."""
        return np.zeros((n, self.hidden)), np.zeros((n, self.hidden))

    def step(self, observations: np.ndarray, memory: tuple[np.ndarray, np.ndarray],
             rows: np.ndarray) -> np.ndarray:
        """Raw actions (float64, k x action dim) of the observation rows of runs
        ``rows``; their memory moves one step on, in place."""
        from stepdamp_env.fixednet import lstm_step, mlp_forward

        h, c = memory
        rows = np.ascontiguousarray(rows, dtype=np.int64).ravel()
        x = np.ascontiguousarray(observations, dtype=np.float32)
        # lstm_step does not check bounds: a wrong shape or row would read or
        # write outside the arrays.
        if x.shape != (rows.size, self.inputs):
            raise ValueError(f"observations: shape {x.shape}, expected ({rows.size}, "
                             f"{self.inputs}) (one row per entry of rows)")
        if h.shape != c.shape or h.ndim != 2 or h.shape[1] != self.hidden or \
                h.dtype != np.float64 or c.dtype != np.float64:
            raise ValueError(f"memory: two float64 arrays (runs, {self.hidden}) from "
                             "initial_state")
        if rows.size and (rows.min() < 0 or rows.max() >= h.shape[0] or
                          np.unique(rows).size != rows.size):
            raise ValueError(f"rows: distinct run numbers in [0, {h.shape[0]}) expected, got "
                             f"{rows.tolist()}")
        lstm_step(x, rows, h, c, self.w_ih, self.w_hh, self.bias)
        return mlp_forward(np.ascontiguousarray(h[rows]), self.head.weights, self.head.biases,
                           self.head.sizes, self.head.activations)


_RECURRENT: "weakref.WeakKeyDictionary[Any, RecurrentNetwork | None]" = \
    weakref.WeakKeyDictionary()


def recurrent_network(policy: Any) -> RecurrentNetwork | None:
    """The :class:`RecurrentNetwork` of a recurrent SB3 policy; None for a policy
    without memory (:func:`predict_rows` serves those). A recurrent policy that
    cannot be read this way is a ``ValueError``: acting without its memory would
    be another policy."""
    if policy in _RECURRENT:
        return _RECURRENT[policy]
    network = None
    if hasattr(policy, "lstm_actor"):
        from gymnasium import spaces
        from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy
        from stable_baselines3.common.distributions import DiagGaussianDistribution
        from stable_baselines3.common.torch_layers import FlattenExtractor

        name = type(policy).__name__
        if not (isinstance(policy, RecurrentActorCriticPolicy) and not policy.shared_lstm and
                isinstance(policy.action_dist, DiagGaussianDistribution) and
                isinstance(policy.pi_features_extractor, FlattenExtractor) and
                isinstance(policy.observation_space, spaces.Box) and
                len(policy.observation_space.shape) == 1 and
                type(policy).get_distribution is RecurrentActorCriticPolicy.get_distribution):
            raise ValueError(f"{name}: a recurrent policy this package cannot evaluate "
                             "deterministically (one LSTM layer, flat Box observations, "
                             "Gaussian actions)")
        network = RecurrentNetwork(policy.lstm_actor,
                                   [*policy.mlp_extractor.policy_net, policy.action_net])
        if not _recurrent_agrees_with_torch(policy, network):
            raise ValueError(f"{name}: its LSTM does not give torch's actions")
    _RECURRENT[policy] = network
    return network


def _recurrent_agrees_with_torch(policy: Any, network: RecurrentNetwork) -> bool:
    """Eight steps of two runs through torch and through the network agree to
    float32 rounding."""
    import torch

    low = np.maximum(policy.observation_space.low, -3.0)
    high = np.minimum(policy.observation_space.high, 3.0)
    probe = np.random.default_rng(0).uniform(low, high, size=(8, 2, low.size)).astype(np.float32)
    policy.set_training_mode(False)
    shape = (policy.lstm_actor.num_layers, 2, policy.lstm_actor.hidden_size)
    state = (torch.zeros(shape), torch.zeros(shape))
    memory = network.initial_state(2)
    rows = np.arange(2)
    for obs in probe:
        with torch.no_grad():
            dist, state = policy.get_distribution(torch.as_tensor(obs), state,
                                                  torch.zeros(2))
            want = dist.get_actions(deterministic=True).cpu().numpy()
        got = network.step(obs, memory, rows)
        if got.shape != want.reshape(got.shape).shape or not np.allclose(
                got, want.reshape(got.shape), rtol=1e-4, atol=1e-5):
            return False
    return True
