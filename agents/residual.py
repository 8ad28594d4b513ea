"""Residual learning done right: the agent starts exactly at its base controller.

Three pieces, used by :mod:`agents.train` and usable from rl-baselines3-zoo:

* **Policies whose residual starts at zero** (:class:`ResidualSACPolicy`,
  :class:`ResidualTD3Policy`, :class:`ResidualPPOPolicy`; registered as
  ``"ResidualMlpPolicy"`` in SB3's ``policy_aliases`` of SAC, TD3 and PPO by
  :func:`register_policy_aliases`). The last layer of the actor (SAC: the mean
  ``mu``; TD3: ``mu``'s last ``Linear``; PPO: ``action_net``) has zero weights and
  bias, so the deterministic action is exactly 0 for every observation. SAC's
  ``log_std`` layer is zeroed too with its bias at ``log_std_init`` (default -3),
  PPO's log-std parameter starts at ``log_std_init`` (default -3): the first
  exploration is a small perturbation of the base controller, not noise across
  the whole action range.
* **Zero-residual warm-up** (:class:`ResidualSAC`, :class:`ResidualTD3`): SB3's
  off-policy algorithms fill the replay buffer with uniformly random actions for
  ``learning_starts`` steps; these collect zero residuals instead (the base
  controller's own transitions; with ``warmup_noise_std`` > 0, Gaussian
  residuals of that standard deviation around zero).
* **The residual environment** (:class:`ResidualVecEnv` for training on the
  native vectorised env through the SB3 adapter, :class:`ResidualWrapper` for a
  scalar ``gym.make`` env, e.g. under rl-baselines3-zoo). See below.

Action scaling
--------------
``StepperDamp-v0`` in ``action_mode="harmonic"`` takes six numbers in [-1, 1]:
corrections of the patent feedforward's sin/cos coefficients of the electrical
harmonics 1, 2, 4, each times ``harmonic_scale_nm`` (default 2*max(Kd1, Kd2, Kd4)
of the nominal motor: 0.024 N*m for ``patent``). The agent's network outputs
``r`` in [-1, 1]^6 and the drive gets::

    env action = clip(a_base + residual_scale * r, -1, 1)

``a_base`` is the base controller's action: zero for ``base="patent-ff"`` (the
patent's feedforward alone) or the model-based delay compensation of
``ff-delay-comp`` for ``base="ff-delay-comp"`` (computed from the feedforward's
own model and the nominal drive, :mod:`baselines.harmonic`). ``residual_scale``
(0.1 in the YAML files) bounds how far the agent may move each coefficient: 0.1
of the action unit, i.e. a fifth of the largest detent amplitude (about 2.4 mN*m
for ``patent``); the rewards are multiplied by ``reward_scale`` (1000 in the YAML
files: a damped step's reward is about -1e-4) and the YAML files set the env's
``current_penalty`` to 0 (the leaderboard scores ripple only; with the default
0.1 the agent learned to trade ripple for less feedforward current). A zero
residual reproduces the base controller bit for bit.

Observation
-----------
The env's observation (17 numbers) plus 12 episode constants that the drive
knows from its own model (:func:`context_features`): the feedforward model's six
sin/cos coefficients in action units, and ``a_base`` of ff-delay-comp (the
speed-dependent phase lead the drive model predicts), both whatever ``base``
is. The detent phases phi1, phi2 of a motor are random, so without its
feedforward model a policy cannot know in which direction to turn the
coefficients; with it, it learns the correction the model gets wrong.

Training estimate
-----------------
In training the feedforward uses the exact model of each drawn motor
(``estimate="exact"``): the leaderboard's identified model is within about 1 %
and 0.015 rad of it (README, Identification), so this is the identified-like
model without running the identification for every training episode.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import PPO, SAC, TD3
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvStepReturn
from stable_baselines3.sac.policies import SACPolicy
from stable_baselines3.td3.policies import TD3Policy

from baselines.harmonic import _actions, phasors, torque_paths
from stepdamp_env.envs import P_W_REF, StepperDampEnv, StepperDampVectorEnv
from stepdamp_env.params import FeedforwardModel, SystemParams
from stepdamp_env.sb3 import StepperDampSB3VecEnv, make_sb3_vec_env

__all__ = ["BASES", "N_FEATURES", "context_features", "ResidualSACPolicy", "ResidualTD3Policy",
           "ResidualPPOPolicy", "ResidualSAC", "ResidualTD3", "ResidualPPO", "ALGOS",
           "register_policy_aliases", "ResidualVecEnv", "ResidualWrapper", "make_residual_vec_env"]

BASES = ("patent-ff", "ff-delay-comp")
N_FEATURES = 12
DEFAULT_LOG_STD_INIT = -3.0


# ---------------------------------------------------------------------------
# What the drive knows: features and the base action
# ---------------------------------------------------------------------------
def context_features(nominal: SystemParams, estimate: FeedforwardModel, mode: str,
                     speed_rps: float, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """(12 features, ff-delay-comp's action) of one episode, float32.

    ``nominal``: the datasheet system (drive model); ``estimate``: the
    feedforward's model; ``scale``: ``harmonic_scale_nm`` of the episode.
    """
    base = phasors(estimate)
    g = torque_paths(nominal, mode, speed_rps, estimate)
    dc = _actions(base / g, base, scale)
    coeffs = np.asarray(estimate.coefficients(), dtype=np.float32) / np.float32(scale)
    return np.concatenate([coeffs, dc]).astype(np.float32), dc


def _combine(base_action: np.ndarray, residual: np.ndarray, residual_scale: float) -> np.ndarray:
    return np.clip(base_action + residual_scale * np.asarray(residual, dtype=np.float64),
                   -1.0, 1.0)


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
    """``policy="ResidualMlpPolicy"`` for SAC, TD3 and PPO (and their subclasses here)."""
    SAC.policy_aliases["ResidualMlpPolicy"] = ResidualSACPolicy
    TD3.policy_aliases["ResidualMlpPolicy"] = ResidualTD3Policy
    PPO.policy_aliases["ResidualMlpPolicy"] = ResidualPPOPolicy


class _ZeroWarmup:
    """Mixin: the warm-up collects zero (or small Gaussian) residuals, not uniform ones."""

    warmup_noise_std: float = 0.0

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

    def __init__(self, policy: Any = "ResidualMlpPolicy", *args: Any,
                 warmup_noise_std: float = 0.0, **kwargs: Any):
        self.warmup_noise_std = float(warmup_noise_std)
        super().__init__(policy, *args, **kwargs)


class ResidualTD3(_ZeroWarmup, TD3):
    """TD3 with zero-residual warm-up (``policy="ResidualMlpPolicy"`` by default)."""

    policy_aliases = {**TD3.policy_aliases, "ResidualMlpPolicy": ResidualTD3Policy}

    def __init__(self, policy: Any = "ResidualMlpPolicy", *args: Any,
                 warmup_noise_std: float = 0.0, **kwargs: Any):
        self.warmup_noise_std = float(warmup_noise_std)
        super().__init__(policy, *args, **kwargs)


class ResidualPPO(PPO):
    """PPO with ``policy="ResidualMlpPolicy"`` by default (on-policy: no warm-up)."""

    policy_aliases = {**PPO.policy_aliases, "ResidualMlpPolicy": ResidualPPOPolicy}

    def __init__(self, policy: Any = "ResidualMlpPolicy", *args: Any, **kwargs: Any):
        super().__init__(policy, *args, **kwargs)


ALGOS = {"sac": ResidualSAC, "td3": ResidualTD3, "ppo": ResidualPPO}


# ---------------------------------------------------------------------------
# Environments
# ---------------------------------------------------------------------------
def _augmented_space(space: spaces.Box) -> spaces.Box:
    high = np.concatenate([space.high, np.full(N_FEATURES, 10.0, dtype=np.float32)])
    low = np.concatenate([space.low, np.full(N_FEATURES, -10.0, dtype=np.float32)])
    return spaces.Box(low, high, dtype=np.float32)


class ResidualVecEnv(VecEnv):
    """Training env: one or more native StepperDamp vector envs (SB3 adapter)
    side by side, observations with the 12 context features, actions residuals
    on top of ``base`` (see the module docstring), rewards times ``reward_scale``.

    Each part may be around another preset (``motor``); the part's ``motor`` is
    the nominal system whose drive model the features use. Parts must use
    ``action_mode="harmonic"`` and ``estimate="exact"`` or ``"nominal"``.
    """

    def __init__(self, parts: Sequence[StepperDampSB3VecEnv], base: str = "patent-ff",
                 residual_scale: float = 0.25, reward_scale: float = 1.0) -> None:
        if base not in BASES:
            raise ValueError(f"base={base!r} is not one of {list(BASES)}")
        self.parts = list(parts)
        for p in self.parts:
            o = p.venv.options
            if o.action_mode != "harmonic":
                raise ValueError("ResidualVecEnv needs action_mode='harmonic'")
            if isinstance(o.estimate, FeedforwardModel):
                raise ValueError("ResidualVecEnv: estimate must be 'exact' or 'nominal'")
        self.base = base
        self.residual_scale = float(residual_scale)
        self.reward_scale = float(reward_scale)
        n = sum(p.num_envs for p in self.parts)
        first = self.parts[0].venv
        self.render_mode = None            # before VecEnv.__init__, which looks for it
        super().__init__(n, _augmented_space(first.single_observation_space),
                         first.single_action_space)
        self._features = np.zeros((n, N_FEATURES), dtype=np.float32)
        self._base_actions = np.zeros((n, 6))
        self._actions: np.ndarray | None = None

    def _update(self, k0: int, part: StepperDampSB3VecEnv, idx: Sequence[int]) -> None:
        v: StepperDampVectorEnv = part.venv
        f = v._factory
        for i in idx:
            system = v.systems[i]
            est = (FeedforwardModel.from_motor(system.motor) if v.options.estimate == "exact"
                   else f.nominal_estimate)
            speed = float(v._par[i, P_W_REF]) / (2.0 * math.pi)
            feats, dc = context_features(f.nominal, est, v.options.mode, speed, f.action_scale)
            self._features[k0 + i] = feats
            self._base_actions[k0 + i] = dc if self.base == "ff-delay-comp" else 0.0

    def _obs(self, obs_parts: list[np.ndarray]) -> np.ndarray:
        return np.concatenate([np.concatenate(obs_parts, axis=0), self._features], axis=1)

    def reset(self) -> np.ndarray:
        obs_parts, k0 = [], 0
        for j, p in enumerate(self.parts):
            seeds = self._seeds[k0:k0 + p.num_envs]
            if any(s is not None for s in seeds):
                p.seed(None)
                p._seeds = list(seeds)
            obs_parts.append(p.reset())
            self._update(k0, p, range(p.num_envs))
            k0 += p.num_envs
        self._reset_seeds()
        self._reset_options()
        return self._obs(obs_parts)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions, dtype=np.float64)

    def step_wait(self) -> VecEnvStepReturn:
        a = _combine(self._base_actions, self._actions, self.residual_scale)
        obs_parts, rews, dones, infos, k0 = [], [], [], [], 0
        for p in self.parts:
            n = p.num_envs
            o, r, d, inf = p.step(a[k0:k0 + n])
            done_idx = np.flatnonzero(d)
            for i in done_idx:     # the finished episode's features go with its last obs
                inf[i]["terminal_observation"] = np.concatenate(
                    [inf[i]["terminal_observation"], self._features[k0 + i]])
            self._update(k0, p, done_idx)
            obs_parts.append(o)
            rews.append(r)
            dones.append(d)
            infos += inf
            k0 += n
        self._actions = None
        return (self._obs(obs_parts), np.concatenate(rews) * np.float32(self.reward_scale),
                np.concatenate(dones), infos)

    def close(self) -> None:
        for p in self.parts:
            p.close()

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [getattr(self, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *args: Any, indices=None, **kwargs: Any) -> list[Any]:
        return [getattr(self, method_name)(*args, **kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self):
        return [None for _ in range(self.num_envs)]


def make_residual_vec_env(motors: Sequence[str], envs_per_motor: int, seed: int, *,
                          base: str = "patent-ff", residual_scale: float = 0.25,
                          reward_scale: float = 1.0, max_episode_steps: int = 300,
                          **options: Any) -> ResidualVecEnv:
    """A :class:`ResidualVecEnv` with ``envs_per_motor`` drives around each of
    ``motors``; drive k is seeded ``seed + k`` (seeds must stay below 1_000_000)."""
    opts = {"action_mode": "harmonic", "estimate": "exact", **options}
    parts = [make_sb3_vec_env(num_envs=envs_per_motor, max_episode_steps=max_episode_steps,
                              motor=m, **opts) for m in motors]
    env = ResidualVecEnv(parts, base=base, residual_scale=residual_scale,
                         reward_scale=reward_scale)
    n = env.num_envs
    if not 0 <= seed and seed + n < 1_000_000:
        raise ValueError(f"training seeds must be in [0, 1_000_000), got {seed}..{seed + n}")
    env.seed(seed)
    return env


class ResidualWrapper(gym.Wrapper):
    """The same residual problem on a scalar ``StepperDamp-v0`` (``gym.make``), for
    rl-baselines3-zoo (``env_wrapper``). Kwargs as :class:`ResidualVecEnv`."""

    def __init__(self, env: gym.Env, base: str = "patent-ff", residual_scale: float = 0.25,
                 reward_scale: float = 1.0) -> None:
        super().__init__(env)
        if base not in BASES:
            raise ValueError(f"base={base!r} is not one of {list(BASES)}")
        inner: StepperDampEnv = env.unwrapped
        if inner.options.action_mode != "harmonic" or \
                isinstance(inner.options.estimate, FeedforwardModel):
            raise ValueError("ResidualWrapper needs action_mode='harmonic' and estimate "
                             "'exact' or 'nominal'")
        self.base = base
        self.residual_scale = float(residual_scale)
        self.reward_scale = float(reward_scale)
        self.observation_space = _augmented_space(env.observation_space)
        self._features = np.zeros(N_FEATURES, dtype=np.float32)
        self._base_action = np.zeros(6)

    def reset(self, **kwargs: Any):
        obs, info = self.env.reset(**kwargs)
        inner: StepperDampEnv = self.env.unwrapped
        f = inner._factory
        est = (FeedforwardModel.from_motor(inner.system.motor)
               if inner.options.estimate == "exact" else f.nominal_estimate)
        self._features, dc = context_features(f.nominal, est, inner.options.mode,
                                              info["speed_rps"], f.action_scale)
        self._base_action = dc if self.base == "ff-delay-comp" else np.zeros(6)
        return np.concatenate([obs, self._features]), info

    def step(self, action: Any):
        a = _combine(self._base_action, action, self.residual_scale)
        obs, reward, terminated, truncated, info = self.env.step(a)
        return (np.concatenate([obs, self._features]), reward * self.reward_scale, terminated,
                truncated, info)


# Importing this module makes policy="ResidualMlpPolicy" resolvable (zoo: --gym-packages).
register_policy_aliases()
