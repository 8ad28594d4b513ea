"""Residual learning done right: the agent starts exactly at its base controller.

Three pieces, used by :mod:`stepdamp_agents.train` and usable from rl-baselines3-zoo:

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
own model and the nominal drive, :mod:`stepdamp_baselines.harmonic`). ``residual_scale``
bounds how far the agent may move each coefficient: 0.1 of the action unit, for
example, is a fifth of the largest detent amplitude (about 2.4 mN*m for
``patent``); the reference task (:mod:`stepdamp_agents.task`) uses the "feedback" residual
with ``residual_scale`` 0.05 of ``current_scale_a``; the rewards are multiplied by
``reward_scale`` (1000 there: a damped step's reward is about -1e-4) and it sets the env's
``current_penalty`` to 0 (the leaderboard scores ripple only; with the default
0.1 the agent learned to trade ripple for less feedforward current). A zero
residual reproduces the base controller bit for bit.

Other residual kinds (``residual_action``): ``"current"`` adds a q current
``residual_scale * r`` (``current_scale_a`` units, env ``action_mode=
"harmonic+current"``) to the base every env step; ``"feedback"`` (the reference's
choice) lets the agent pick a damping gain ``g`` every ``hold_steps`` env steps
and injects ``residual_scale * clip(feedback_gain * g * v, -1, 1)`` each step in
between, ``v`` the velocity feature (:func:`velocity_feature_gain`); see
:class:`HeldFeedbackVecEnv`.

Observation
-----------
The env's observation, the velocity feature ``v`` (w_cmd - w_fb in units of
1e-3 * wn * full step of the datasheet motor), then 12 episode constants that the drive
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
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvStepReturn

from stepdamp_baselines.harmonic import harmonic_actions, phasors, torque_paths
from stepdamp_env.bench.protocol import TRAINING_SEED_LIMIT
from stepdamp_env.env import (DEFAULT_EPISODE_STEPS, ENV_ID, OBS, StepperDampEnv,
                              StepperDampVectorEnv)
from stepdamp_env.params import FeedforwardModel, SystemParams
from stepdamp_env.sb3 import StepperDampSB3VecEnv, make_sb3_vec_env

from .algos import V0_ALGOS as ALGOS, V0_POLICIES as POLICIES
from .algos import (ResidualPPO, ResidualPPOPolicy, ResidualSAC, ResidualSACPolicy, ResidualTD3,
                    ResidualTD3Policy, register_policy_aliases)
from .task import RESIDUAL_ENV_ID, task_kwargs

__all__ = ["BASES", "RESIDUAL_ACTIONS", "N_FEATURES", "context_features", "velocity_feature_gain",
           "EpisodeConstants", "ResidualSACPolicy", "ResidualTD3Policy",
           "ResidualPPOPolicy", "ResidualSAC", "ResidualTD3", "ResidualPPO", "ALGOS", "POLICIES",
           "register_policy_aliases", "ResidualVecEnv", "HeldFeedbackVecEnv", "feedback_current",
           "ResidualWrapper", "make_residual_vec_env", "make_residual_env", "WholeVecEnv",
           "register_residual_env", "RESIDUAL_ENV_ID"]

BASES = ("patent-ff", "ff-delay-comp")
# What the agent's residual acts on, and the env action mode that carries it.
RESIDUAL_ACTIONS = {"harmonic": "harmonic", "current": "harmonic+current",
                    "feedback": "harmonic+current"}
N_FEATURES = 13
# The velocity feature's unit: this fraction of wn*full_step (wn: the nominal
# rotor's natural frequency on its holding-current spring). A settled ripple of
# a few hundredths of rad/s is then of order 1 on every preset.
VELOCITY_FEATURE_UNIT = 1e-3
FEATURE_BOUND = 10.0


# ---------------------------------------------------------------------------
# What the drive knows: features and the base action
# ---------------------------------------------------------------------------
def context_features(nominal: SystemParams, estimate: FeedforwardModel, mode: str,
                     speed_rps: float, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """(12 episode features, ff-delay-comp's harmonic action) of one episode, float32.

    ``nominal``: the datasheet system (drive model); ``estimate``: the
    feedforward's model; ``scale``: ``harmonic_scale_nm`` of the episode.
    """
    base = phasors(estimate)
    g = torque_paths(nominal, mode, speed_rps, estimate)
    dc = harmonic_actions(base / g, base, scale)
    coeffs = np.asarray(estimate.coefficients(), dtype=np.float32) / np.float32(scale)
    return np.concatenate([coeffs, dc]).astype(np.float32), dc


def velocity_feature_gain(nominal: SystemParams, speed_rps: float) -> float:
    """Factor from the env's observation 1 ((w_cmd - w_fb)/w_cmd) to the velocity
    feature: w_cmd - w_fb in units of VELOCITY_FEATURE_UNIT * wn * full_step.

    A damping current proportional to the velocity error is then the same
    linear function of the feature on every motor (wn, J from the datasheet).
    """
    m = nominal.motor
    wn = math.sqrt(m.Km * nominal.drive.holding_current * m.Nr / m.J)
    return 2.0 * math.pi * abs(speed_rps) / (VELOCITY_FEATURE_UNIT * wn * m.full_step_rad)


class EpisodeConstants:
    """Per-drive rows of what the residual layer adds: the velocity feature's
    gain, the 12 context features and the base controller's harmonic action."""

    def __init__(self, n: int) -> None:
        self.velocity_gain = np.zeros(n)
        self.features = np.zeros((n, N_FEATURES - 1), dtype=np.float32)
        self.base_action = np.zeros((n, 6))

    def set(self, i: int, nominal: SystemParams, estimate: FeedforwardModel, mode: str,
            speed_rps: float, harmonic_scale: float, base: str) -> None:
        feats, dc = context_features(nominal, estimate, mode, speed_rps, harmonic_scale)
        self.features[i] = feats
        self.base_action[i] = dc if base == "ff-delay-comp" else 0.0
        self.velocity_gain[i] = velocity_feature_gain(nominal, speed_rps)

    def velocity_feature(self, obs: np.ndarray, rows: Any = slice(None)) -> np.ndarray:
        """The velocity feature of env observations (n, d): (n,) float32, the
        first column :meth:`augment` adds."""
        return np.clip(obs[:, OBS.velocity_error] * self.velocity_gain[rows], -FEATURE_BOUND,
                       FEATURE_BOUND).astype(np.float32)

    def augment(self, obs: np.ndarray, rows: Any = slice(None)) -> np.ndarray:
        """Env observations (n, d) -> agent observations (n, d + N_FEATURES)."""
        return np.concatenate([obs, self.velocity_feature(obs, rows)[:, None],
                               self.features[rows]], axis=1)

    def env_action(self, residual: np.ndarray, residual_scale: float, residual_action: str,
                   rows: Any = slice(None)) -> np.ndarray:
        """Agent residuals (n, k) -> env actions (see the module docstring)."""
        r = residual_scale * np.asarray(residual, dtype=np.float64)
        base = self.base_action[rows]
        if residual_action == "harmonic":
            return np.clip(base + r, -1.0, 1.0)
        return np.concatenate([base, np.clip(r, -1.0, 1.0)], axis=1)


def _check_residual_action(residual_action: str) -> str:
    if residual_action not in RESIDUAL_ACTIONS:
        raise ValueError(f"residual_action={residual_action!r} is not one of "
                         f"{list(RESIDUAL_ACTIONS)}")
    return residual_action


def _residual_space(residual_action: str) -> spaces.Box:
    n = 6 if residual_action == "harmonic" else 1
    return spaces.Box(-1.0, 1.0, shape=(n,), dtype=np.float32)


def feedback_current(gain: np.ndarray, velocity_feature: np.ndarray, feedback_gain: float
                     ) -> np.ndarray:
    """The "feedback" residual's current residual (then scaled as a "current"
    one) of the held agent action ``gain``:
    ``clip(feedback_gain * gain * velocity_feature, -1, 1)``."""
    return np.clip(feedback_gain * np.asarray(gain, dtype=np.float64)
                   * np.asarray(velocity_feature, dtype=np.float64), -1.0, 1.0)


# ---------------------------------------------------------------------------
# Environments
# ---------------------------------------------------------------------------
def _augmented_space(space: spaces.Box) -> spaces.Box:
    bound = np.full(N_FEATURES, FEATURE_BOUND, dtype=np.float32)
    return spaces.Box(np.concatenate([space.low, -bound]), np.concatenate([space.high, bound]),
                      dtype=np.float32)


class WholeVecEnv(VecEnv):
    """A VecEnv whose attributes and methods are its own, not per drive's."""

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


class ResidualVecEnv(WholeVecEnv):
    """Training env: one or more native StepperDamp vector envs (SB3 adapter)
    side by side, observations with the 13 features, actions residuals on top
    of ``base`` (see the module docstring), rewards times ``reward_scale``.

    Each part may be around another preset (``motor``); the part's ``motor`` is
    the nominal system whose drive model the features use. Parts must use the
    env action mode of ``residual_action`` (``RESIDUAL_ACTIONS``) and
    ``estimate="exact"`` or ``"nominal"``.
    """

    def __init__(self, parts: Sequence[StepperDampSB3VecEnv], base: str = "patent-ff",
                 residual_scale: float = 0.25, reward_scale: float = 1.0,
                 residual_action: str = "harmonic") -> None:
        if base not in BASES:
            raise ValueError(f"base={base!r} is not one of {list(BASES)}")
        self.residual_action = _check_residual_action(residual_action)
        self.parts = list(parts)
        for p in self.parts:
            o = p.venv.options
            if o.action_mode != RESIDUAL_ACTIONS[residual_action]:
                raise ValueError(f"residual_action={residual_action!r} needs action_mode="
                                 f"{RESIDUAL_ACTIONS[residual_action]!r}, got {o.action_mode!r}")
            if isinstance(o.estimate, FeedforwardModel):
                raise ValueError("ResidualVecEnv: estimate must be 'exact' or 'nominal'")
        self.base = base
        self.residual_scale = float(residual_scale)
        self.reward_scale = float(reward_scale)
        n = sum(p.num_envs for p in self.parts)
        first = self.parts[0].venv
        self.render_mode = None            # before VecEnv.__init__, which looks for it
        super().__init__(n, _augmented_space(first.single_observation_space),
                         _residual_space(residual_action))
        self.constants = EpisodeConstants(n)
        self._actions: np.ndarray | None = None

    def _update(self, k0: int, part: StepperDampSB3VecEnv, idx: Sequence[int]) -> None:
        v: StepperDampVectorEnv = part.venv
        f = v.sampler
        speeds = v.speeds_rps
        for i in idx:
            self.constants.set(k0 + i, f.nominal, f.episode_estimate(v.systems[i]),
                               v.options.mode, float(speeds[i]), f.harmonic_scale_nm, self.base)

    def reset(self) -> np.ndarray:
        seeds = self._seeds                 # set by seed(): drive k gets seeds[k]
        if any(s is not None and not 0 <= s < TRAINING_SEED_LIMIT for s in seeds):
            raise ValueError(f"training seeds must be in [0, {TRAINING_SEED_LIMIT}), got "
                             f"{min(seeds)}..{max(seeds)}")
        obs_parts, k0 = [], 0
        for p in self.parts:
            if seeds[k0] is not None:
                # seed(None) first, as 0.1 did: it draws from numpy's global stream,
                # which SB3's sampling shares, so training runs repeat 0.1's.
                p.seed(None)
                p.seed(seeds[k0])           # the part's drives: seeds[k0] + i
            obs_parts.append(p.reset())
            self._update(k0, p, range(p.num_envs))
            k0 += p.num_envs
        self._reset_seeds()
        self._reset_options()
        return self.constants.augment(np.concatenate(obs_parts, axis=0))

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions, dtype=np.float64)

    def step_wait(self) -> VecEnvStepReturn:
        # float32 like every policy's action (the leaderboard agent's too).
        a = self.constants.env_action(self._actions, self.residual_scale,
                                      self.residual_action).astype(np.float32)
        obs_parts, rews, dones, infos, k0 = [], [], [], [], 0
        for p in self.parts:
            n = p.num_envs
            o, r, d, inf = p.step(a[k0:k0 + n])
            # The finished episode's constants go with its last observation.
            for i in np.flatnonzero(d):
                inf[i]["terminal_observation"] = self.constants.augment(
                    inf[i]["terminal_observation"][None], [k0 + i])[0]
            self._update(k0, p, np.flatnonzero(d))
            obs_parts.append(o)
            rews.append(r)
            dones.append(d)
            infos += inf
            k0 += n
        self._actions = None
        return (self.constants.augment(np.concatenate(obs_parts, axis=0)),
                np.concatenate(rews) * np.float32(self.reward_scale), np.concatenate(dones),
                infos)

    def close(self) -> None:
        for p in self.parts:
            p.close()


def make_residual_vec_env(motors: Sequence[str], envs_per_motor: int, seed: int, *,
                          base: str = "patent-ff", residual_scale: float = 0.25,
                          reward_scale: float = 1.0, residual_action: str = "harmonic",
                          hold_steps: int = 1, feedback_gain: float = 0.1,
                          max_episode_steps: int = DEFAULT_EPISODE_STEPS,
                          **options: Any) -> VecEnv:
    """A :class:`ResidualVecEnv` with ``envs_per_motor`` drives around each of
    ``motors`` (for ``residual_action="feedback"`` inside a
    :class:`HeldFeedbackVecEnv` of ``hold_steps``); drive k is seeded ``seed + k``
    (seeds must stay below ``TRAINING_SEED_LIMIT``)."""
    n = len(motors) * envs_per_motor
    if not 0 <= seed <= TRAINING_SEED_LIMIT - n:
        raise ValueError(f"training seeds must be in [0, {TRAINING_SEED_LIMIT}), got "
                         f"{seed}..{seed + n - 1}")
    opts = {"estimate": "exact", **options,
            "action_mode": RESIDUAL_ACTIONS[_check_residual_action(residual_action)]}
    parts = [make_sb3_vec_env(num_envs=envs_per_motor, max_episode_steps=max_episode_steps,
                              motor=m, **opts) for m in motors]
    env = ResidualVecEnv(parts, base=base, residual_scale=residual_scale,
                         reward_scale=reward_scale,
                         residual_action="current" if residual_action == "feedback"
                         else residual_action)
    if residual_action == "feedback":
        env = HeldFeedbackVecEnv(env, hold_steps, feedback_gain)
    env.seed(seed)
    return env


class HeldFeedbackVecEnv(WholeVecEnv):
    """The "feedback" residual: the agent picks a velocity-feedback gain every
    ``hold_steps`` env steps; in between, every env step applies
    :func:`feedback_current` of the latest velocity feature (a damping current).

    Wraps a :class:`ResidualVecEnv` with ``residual_action="current"``. One
    step of this env is ``hold_steps`` env steps: its reward is their mean, its
    observation the last augmented one plus the RMS velocity feature over the
    hold (0 after a reset). Episodes should last a whole number of holds; a
    drive that terminates mid-hold restarts at once with gain 0 until the next
    decision (its first observation then shows a few steps of the new episode,
    with RMS 0).
    """

    def __init__(self, inner: ResidualVecEnv, hold_steps: int, feedback_gain: float) -> None:
        if inner.residual_action != "current":
            raise ValueError("HeldFeedbackVecEnv needs a ResidualVecEnv with "
                             "residual_action='current'")
        if not isinstance(hold_steps, (int, np.integer)) or hold_steps < 1:
            raise ValueError(f"hold_steps={hold_steps!r} is outside its allowed range "
                             "[1, inf) (integer)")
        self.inner = inner
        self.hold_steps = int(hold_steps)
        self.feedback_gain = float(feedback_gain)
        self.residual_action = "feedback"
        self.render_mode = None
        space = inner.observation_space
        super().__init__(inner.num_envs,
                         spaces.Box(np.append(space.low, 0.0).astype(np.float32),
                                    np.append(space.high, FEATURE_BOUND).astype(np.float32),
                                    dtype=np.float32),
                         _residual_space("feedback"))
        self._vel_col = int(inner.parts[0].venv.single_observation_space.shape[0])
        self._gain = np.zeros(self.num_envs)
        self._last: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        if self._seeds[0] is not None:
            self.inner.seed(self._seeds[0])
        self._last = self.inner.reset()
        self._reset_seeds()
        self._reset_options()
        return np.concatenate([self._last, np.zeros((self.num_envs, 1), np.float32)], axis=1)

    def step_async(self, actions: np.ndarray) -> None:
        self._gain = np.asarray(actions, dtype=np.float64).reshape(self.num_envs)

    def step_wait(self) -> VecEnvStepReturn:
        n = self.num_envs
        gain = self._gain.copy()
        reward = np.zeros(n)
        count = np.zeros(n)
        sq = np.zeros(n)
        done = np.zeros(n, dtype=bool)
        infos: list[dict] = [{} for _ in range(n)]
        obs = self._last
        for _ in range(self.hold_steps):
            current = feedback_current(gain, obs[:, self._vel_col], self.feedback_gain)
            obs, r, d, inf = self.inner.step(current[:, None])
            live = ~done
            reward[live] += r[live]
            count[live] += 1
            sq[live] += obs[live, self._vel_col].astype(np.float64) ** 2
            for i in np.flatnonzero(d & live):
                infos[i] = dict(inf[i])
                infos[i]["terminal_observation"] = np.append(
                    inf[i]["terminal_observation"],
                    np.float32(math.sqrt(sq[i] / count[i]))).astype(np.float32)
                gain[i] = 0.0
            done |= d
        self._last = obs
        # A restarted drive's observation starts its new episode: RMS 0, as after a reset.
        rms = np.where(done, 0.0, np.sqrt(sq / np.maximum(count, 1))).astype(np.float32)
        return (np.concatenate([obs, rms[:, None]], axis=1),
                (reward / np.maximum(count, 1)).astype(np.float32), done, infos)

    def close(self) -> None:
        self.inner.close()


class ResidualWrapper(gym.Wrapper):
    """The same residual problem on a scalar ``StepperDamp-v0`` (``gym.make``); the
    env of ``StepperDampResidual-v0`` (:func:`make_residual_env`, rl-baselines3-zoo).
    Kwargs as :class:`ResidualVecEnv`; the
    env's ``action_mode`` must be that of ``residual_action``."""

    def __init__(self, env: gym.Env, base: str = "patent-ff", residual_scale: float = 0.25,
                 reward_scale: float = 1.0, residual_action: str = "harmonic",
                 hold_steps: int = 1, feedback_gain: float = 0.1) -> None:
        super().__init__(env)
        if base not in BASES:
            raise ValueError(f"base={base!r} is not one of {list(BASES)}")
        self.residual_action = _check_residual_action(residual_action)
        if not isinstance(hold_steps, (int, np.integer)) or hold_steps < 1:
            raise ValueError(f"hold_steps={hold_steps!r} is outside its allowed range "
                             "[1, inf) (integer)")
        self.hold_steps = int(hold_steps) if residual_action == "feedback" else 1
        self.feedback_gain = float(feedback_gain)
        inner: StepperDampEnv = env.unwrapped
        mode = RESIDUAL_ACTIONS[residual_action]
        if inner.options.action_mode != mode or \
                isinstance(inner.options.estimate, FeedforwardModel):
            raise ValueError(f"ResidualWrapper(residual_action={residual_action!r}) needs "
                             f"action_mode={mode!r} and estimate 'exact' or 'nominal'")
        self.base = base
        self.residual_scale = float(residual_scale)
        self.reward_scale = float(reward_scale)
        space = _augmented_space(env.observation_space)
        if residual_action == "feedback":      # + the RMS velocity feature over the hold
            space = spaces.Box(np.append(space.low, 0.0).astype(np.float32),
                               np.append(space.high, FEATURE_BOUND).astype(np.float32),
                               dtype=np.float32)
        self.observation_space = space
        self.action_space = _residual_space(residual_action)
        self.constants = EpisodeConstants(1)
        self._vel_col = int(env.observation_space.shape[0])
        self._last: np.ndarray | None = None

    def reset(self, **kwargs: Any):
        obs, info = self.env.reset(**kwargs)
        inner: StepperDampEnv = self.env.unwrapped
        f = inner.sampler
        self.constants.set(0, f.nominal, f.episode_estimate(inner.system), inner.options.mode,
                           info["speed_rps"], f.harmonic_scale_nm, self.base)
        self._last = self.constants.augment(obs[None])
        return self._observation(self._last, 0.0), info

    def _observation(self, augmented: np.ndarray, rms: float) -> np.ndarray:
        if self.residual_action != "feedback":
            return augmented[0]
        return np.append(augmented[0], np.float32(rms)).astype(np.float32)

    def step(self, action: Any):
        if self.residual_action != "feedback":
            a = self.constants.env_action(np.asarray(action)[None], self.residual_scale,
                                          self.residual_action)[0]
            obs, reward, terminated, truncated, info = self.env.step(a.astype(np.float32))
            self._last = self.constants.augment(obs[None])
            return self._last[0], reward * self.reward_scale, terminated, truncated, info
        # "feedback": hold the gain for hold_steps env steps (as HeldFeedbackVecEnv).
        gain = np.asarray(action, dtype=np.float64).reshape(1)
        total, sq, k = 0.0, 0.0, 0
        terminated = truncated = False
        info: dict = {}
        while k < self.hold_steps and not (terminated or truncated):
            current = feedback_current(gain, self._last[:, self._vel_col], self.feedback_gain)
            a = self.constants.env_action(current[:, None], self.residual_scale, "current")[0]
            obs, reward, terminated, truncated, info = self.env.step(a.astype(np.float32))
            self._last = self.constants.augment(obs[None])
            total += reward * self.reward_scale
            sq += float(self._last[0, self._vel_col]) ** 2
            k += 1
        return (self._observation(self._last, math.sqrt(sq / k)), total / k, terminated,
                truncated, info)


def make_residual_env(drive: dict[str, Any] | None = None, render_mode: str | None = None,
                      **residual: Any) -> ResidualWrapper:
    """The entry point of ``gym.make("StepperDampResidual-v0", drive=..., **residual)``.

    ``drive`` updates :data:`stepdamp_agents.task.REFERENCE_DRIVE` (the
    ``StepperDamp-v0`` options, with ``max_episode_steps``) and ``residual``
    updates :data:`stepdamp_agents.task.REFERENCE_RESIDUAL` (the
    :class:`ResidualWrapper` kwargs): without arguments it is the reference task.
    """
    drive_kwargs, residual_kwargs = task_kwargs({"drive": drive, **residual})
    # The drive's action mode follows the residual, as in make_residual_vec_env.
    drive_kwargs["action_mode"] = RESIDUAL_ACTIONS[
        _check_residual_action(residual_kwargs["residual_action"])]
    if render_mode is not None:
        drive_kwargs["render_mode"] = render_mode
    return ResidualWrapper(gym.make(ENV_ID, **drive_kwargs), **residual_kwargs)


def register_residual_env() -> None:
    """Register ``StepperDampResidual-v0`` (idempotent). No time limit of its own:
    the wrapped drive's ``max_episode_steps`` ends the episode."""
    if RESIDUAL_ENV_ID not in gym.registry:
        gym.register(id=RESIDUAL_ENV_ID, entry_point=f"{__name__}:make_residual_env")


# Importing this module makes policy="ResidualMlpPolicy" and the residual task's id
# resolvable (zoo: --gym-packages stepdamp_agents.residual).
register_policy_aliases()
register_residual_env()
