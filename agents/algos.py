"""The residual algorithms, by name: :data:`ALGOS` (``ars``, ``ppo``,
``ppo_lstm``, ``sac``, ``td3``) and the policy classes a saved model of each
names (:data:`POLICIES`); the v0 gain selector's :data:`V0_ALGOS`. Every policy's
deterministic residual is exactly zero at initialisation (the base controller).

:class:`ResidualARS` is sb3-contrib's ARS from zero weights; when its env (or an
env it wraps) has ``start_block(k)`` (:class:`.per_step.SameEpisodes`), each
update's candidates run on one block of common episodes.
:class:`ResidualRecurrentPPO` is sb3-contrib's RecurrentPPO with a zero action
net. sb3-contrib and the SB3 algorithms load on first use, or when
:func:`register_policy_aliases` runs (importing :mod:`stepdamp_agents.residual`
does: the zoo's ``ppo_lstm`` names ``ResidualLstmPolicy``).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
import torch as th
from stable_baselines3 import PPO, SAC, TD3
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.sac.policies import SACPolicy
from stable_baselines3.td3.policies import TD3Policy

from stepdamp_env.params import ParameterError

__all__ = ["ALGOS", "POLICIES", "V0_ALGOS", "V0_POLICIES", "DEFAULT_LOG_STD_INIT",
           "ResidualSACPolicy", "ResidualTD3Policy", "ResidualPPOPolicy", "ResidualSAC",
           "ResidualTD3", "ResidualPPO", "register_policy_aliases", "ResidualARS",
           "ResidualRecurrentPPO", "ResidualLstmPolicy"]

DEFAULT_LOG_STD_INIT = -3.0


# ---------------------------------------------------------------------------
# Policies whose deterministic residual is exactly zero at initialisation
# ---------------------------------------------------------------------------
def _zero_linear(layer: th.nn.Module, bias: float = 0.0) -> None:
    with th.no_grad():
        layer.weight.zero_()
        layer.bias.fill_(bias)


class ResidualSACPolicy(SACPolicy):
    """SAC policy with zeroed ``mu`` (action 0) and ``log_std`` (std exp(log_std_init))."""

    def __init__(self, *args: Any, log_std_init: float = DEFAULT_LOG_STD_INIT, **kwargs: Any):
        self._residual_log_std_init = log_std_init
        kwargs.setdefault("log_std_init", log_std_init)   # only used by gSDE
        super().__init__(*args, **kwargs)

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        _zero_linear(self.actor.mu)
        if isinstance(self.actor.log_std, th.nn.Linear):
            _zero_linear(self.actor.log_std, self._residual_log_std_init)


class ResidualTD3Policy(TD3Policy):
    """TD3 policy whose actor's last ``Linear`` (and its target's) is zero."""

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        for actor in (self.actor, self.actor_target):
            last = [m for m in actor.mu if isinstance(m, th.nn.Linear)][-1]
            _zero_linear(last)


class ResidualPPOPolicy(ActorCriticPolicy):
    """PPO policy with a zero ``action_net`` and ``log_std_init`` = -3 by default."""

    def __init__(self, *args: Any, log_std_init: float = DEFAULT_LOG_STD_INIT, **kwargs: Any):
        super().__init__(*args, log_std_init=log_std_init, **kwargs)

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        _zero_linear(self.action_net)


def register_policy_aliases() -> None:
    """``policy="ResidualMlpPolicy"`` for SAC, TD3 and PPO (and their subclasses here),
    and ``policy="ResidualLstmPolicy"`` for sb3-contrib's RecurrentPPO where it is
    installed (the zoo's ``ppo_lstm``)."""
    SAC.policy_aliases["ResidualMlpPolicy"] = ResidualSACPolicy
    TD3.policy_aliases["ResidualMlpPolicy"] = ResidualTD3Policy
    PPO.policy_aliases["ResidualMlpPolicy"] = ResidualPPOPolicy
    try:
        from sb3_contrib import RecurrentPPO
    except ImportError:
        return
    RecurrentPPO.policy_aliases["ResidualLstmPolicy"] = _residual_recurrent_ppo()[1]


class _ZeroWarmup:
    """Mixin: the warm-up collects zero (or small Gaussian) residuals, not uniform ones."""

    warmup_noise_std: float = 0.0

    def __init__(self, policy: Any = "ResidualMlpPolicy", *args: Any,
                 warmup_noise_std: float = 0.0, **kwargs: Any):
        self.warmup_noise_std = float(warmup_noise_std)
        super().__init__(policy, *args, **kwargs)

    def _sample_action(self, learning_starts: int, action_noise=None, n_envs: int = 1):
        if self.num_timesteps < learning_starts:
            shape = (n_envs, *self.action_space.shape)
            if self.warmup_noise_std > 0.0:
                a = np.clip(self.warmup_noise_std * np.random.standard_normal(shape), -1, 1)
            else:
                a = np.zeros(shape)
            a = a.astype(np.float32)
            return a, a.copy()
        return super()._sample_action(learning_starts, action_noise, n_envs)


class ResidualSAC(_ZeroWarmup, SAC):
    """SAC with zero-residual warm-up (``policy="ResidualMlpPolicy"`` by default)."""

    policy_aliases = {**SAC.policy_aliases, "ResidualMlpPolicy": ResidualSACPolicy}


class ResidualTD3(_ZeroWarmup, TD3):
    """TD3 with zero-residual warm-up (``policy="ResidualMlpPolicy"`` by default)."""

    policy_aliases = {**TD3.policy_aliases, "ResidualMlpPolicy": ResidualTD3Policy}


class ResidualPPO(PPO):
    """PPO with ``policy="ResidualMlpPolicy"`` by default (on-policy: no warm-up)."""

    policy_aliases = {**PPO.policy_aliases, "ResidualMlpPolicy": ResidualPPOPolicy}

    def __init__(self, policy: Any = "ResidualMlpPolicy", *args: Any, **kwargs: Any):
        super().__init__(policy, *args, **kwargs)


#: The v0 gain selector's algorithms (StepperDampResidual-v0) and their policy classes.
V0_ALGOS = {"sac": ResidualSAC, "td3": ResidualTD3, "ppo": ResidualPPO}
V0_POLICIES = {"sac": ResidualSACPolicy, "td3": ResidualTD3Policy, "ppo": ResidualPPOPolicy}


@functools.cache
def _residual_ars():
    from sb3_contrib import ARS

    class ResidualARS(ARS):
        """sb3-contrib's ARS, its policy from zero (``zero_policy``: the base controller)."""

        def __init__(self, policy: Any = "LinearPolicy", env: Any = None, **kwargs: Any) -> None:
            kwargs.setdefault("zero_policy", True)
            if not kwargs["zero_policy"]:
                raise ParameterError("zero_policy=False: a residual agent starts at zero")
            super().__init__(policy, env, **kwargs)

        def evaluate_candidates(self, candidate_weights: Any, callback: Any,
                                async_eval: Any) -> Any:
            # One block of episodes per update, whatever reset came before.
            env = self.env
            while env is not None and not hasattr(env, "start_block"):
                env = getattr(env, "venv", None)
            if env is not None:
                env.start_block(self._n_updates)
            return super().evaluate_candidates(candidate_weights, callback, async_eval)

        def _trigger_callback(self, _locals: dict, _globals: dict, callback: Any,
                              n_envs: int) -> None:
            # evaluate_policy calls this once per drive and step: one timestep each
            # (sb3-contrib adds n_envs per call, counting every step n_envs times).
            self.num_timesteps += 1
            callback.on_step()

    return ResidualARS


@functools.cache
def _residual_recurrent_ppo():
    import torch as th
    from sb3_contrib import RecurrentPPO
    from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy

    class ResidualLstmPolicy(RecurrentActorCriticPolicy):
        """sb3-contrib's LSTM actor-critic with a zero ``action_net`` (its
        deterministic action is 0, the base controller, whatever the LSTM's
        state) and ``log_std_init`` -3 by default."""

        def __init__(self, *args: Any, log_std_init: float = DEFAULT_LOG_STD_INIT,
                     **kwargs: Any) -> None:
            super().__init__(*args, log_std_init=log_std_init, **kwargs)

        def _build(self, lr_schedule: Any) -> None:
            super()._build(lr_schedule)
            with th.no_grad():
                self.action_net.weight.zero_()
                self.action_net.bias.zero_()

    class ResidualRecurrentPPO(RecurrentPPO):
        """sb3-contrib's RecurrentPPO, ``policy="ResidualLstmPolicy"`` by default."""

        policy_aliases = {**RecurrentPPO.policy_aliases, "ResidualLstmPolicy": ResidualLstmPolicy}

        def __init__(self, policy: Any = "ResidualLstmPolicy", *args: Any, **kwargs: Any) -> None:
            super().__init__(policy, *args, **kwargs)

    return ResidualRecurrentPPO, ResidualLstmPolicy


def __getattr__(name: str) -> Any:
    # sb3-contrib and the SB3 algorithms load on first use.
    if name == "ResidualARS":
        return _residual_ars()
    if name in ("ResidualRecurrentPPO", "ResidualLstmPolicy"):
        return _residual_recurrent_ppo()[name == "ResidualLstmPolicy"]
    if name in ("ALGOS", "POLICIES"):
        rppo, lstm_policy = _residual_recurrent_ppo()
        # ARS's models name their own policy class (linear or MLP).
        if name == "ALGOS":
            return {"ars": _residual_ars(), **V0_ALGOS, "ppo_lstm": rppo}
        return {**V0_POLICIES, "ppo_lstm": lstm_policy}
    raise AttributeError(name)
