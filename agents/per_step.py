"""Per-step residual agents on ``StepperDamp-v1``: ARS, PPO, SAC and TD3.

The residual is the env's own: ``StepperDamp-v1`` runs the base controller
(``ff-delay-comp``) inside the drive, and an action of zero is that controller
bit for bit; every algorithm here starts at exactly zero (ARS from zero weights,
sb3-contrib's ``zero_policy``; PPO, SAC and TD3 with the zero last layer of
:mod:`stepdamp_agents.residual`), so a fresh agent *is* the base controller.

The reference task (:data:`stepdamp_agents.task.REFERENCE_TASK`):
``damping-gains`` actions (the gains of a damping law that the kernel runs
every PWM period at 20 kHz), a decision every 10 ms (100 Hz), the last 4
decisions' position and velocity errors (``history=4``), the visible context
(the held speed over the drive model's three resonance speeds and its detent
model), 1 s episodes, training motors drawn around the four presets
(``randomize=True``, seeds below ``TRAINING_SEED_LIMIT``), open loop, the
protocol's sensors and the exact detent model (the identified one is within
about 1 % of it).

Pieces:

* :class:`PresetsVecEnv`: an SB3 ``VecEnv`` of native v1 vector envs, one per
  preset, side by side (drive k seeded ``seed + k``);
* :class:`SameEpisodes`: a ``VecEnvWrapper`` that replays the same drives'
  episodes for ``repeat`` consecutive resets (ARS's candidates are then
  compared on common motors, speeds and noise: the motor-to-motor spread of
  the return is ten times the effect of a gain);
* :class:`ResidualARS`, :class:`ResidualRecurrentPPO` (sb3-contrib's
  RecurrentPPO, an LSTM before PPO's heads, its action net zero; ``ppo_lstm``)
  and :data:`ALGOS` (``ars``, ``ppo``, ``ppo_lstm``, ``sac``, ``td3``);
* :class:`StepAgent`: a trained model as a leaderboard policy (``env_id`` =
  ``StepperDamp-v1``), its options from its ``.agent.json``.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import (VecEnv, VecEnvStepReturn,
                                                           VecEnvWrapper)

from stepdamp_env.bench.firmware_net import FirmwareNetwork, network_export
from stepdamp_env.bench.policy import (MotorKnowledge, PolicyCard, PolicyContext, RowPolicy,
                                       resolve_estimate)
from stepdamp_env.bench.protocol import TRAINING_SEED_LIMIT
from stepdamp_env.bench.suites import get_suite
from stepdamp_env.params import DRIVE_MODES, ParameterError
from stepdamp_env.sb3 import StepperDampSB3VecEnv, make_sb3_vec_env_v1

from .residual import WholeVecEnv
from .task import ENV_ID_V1, INTERFACE_OPTIONS, REFERENCE_TASK, task_options

__all__ = ["ENV_ID_V1", "REFERENCE_TASK", "INTERFACE_OPTIONS", "task_options", "PresetsVecEnv",
           "SameEpisodes",
           "make_training_env", "ResidualARS", "ResidualRecurrentPPO", "ResidualLstmPolicy",
           "ALGOS", "POLICIES", "StepAgent"]


class PresetsVecEnv(WholeVecEnv):
    """Native ``StepperDamp-v1`` vector envs side by side as one SB3 ``VecEnv``."""

    def __init__(self, parts: Sequence[StepperDampSB3VecEnv]) -> None:
        self.parts = list(parts)
        first = self.parts[0]
        self.render_mode = None
        super().__init__(sum(p.num_envs for p in self.parts), first.observation_space,
                         first.action_space)
        self._cuts = np.cumsum([0] + [p.num_envs for p in self.parts])
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        for p, lo in zip(self.parts, self._cuts[:-1]):
            if self._seeds[lo] is not None:     # seed() gave consecutive seeds
                p.seed(self._seeds[lo])
        self._reset_seeds()
        return np.concatenate([p.reset() for p in self.parts])

    def seed(self, seed: int | None = None) -> Sequence[None | int]:
        """Seeds drive k with ``seed + k`` at the next reset."""
        if seed is not None and not 0 <= seed <= TRAINING_SEED_LIMIT - self.num_envs:
            raise ParameterError(f"training seeds must lie in [0, {TRAINING_SEED_LIMIT}); got "
                                 f"{seed}..{seed + self.num_envs - 1}")
        return super().seed(seed)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        obs, rew, done, infos = [], [], [], []
        for p, lo, hi in zip(self.parts, self._cuts[:-1], self._cuts[1:]):
            o, r, d, i = p.step(self._actions[lo:hi])
            obs.append(o)
            rew.append(r)
            done.append(d)
            infos.extend(i)
        self._actions = None
        return np.concatenate(obs), np.concatenate(rew), np.concatenate(done), infos

    def close(self) -> None:
        for p in self.parts:
            p.close()


class SameEpisodes(VecEnvWrapper):
    """Every reset of one block starts the same episodes: drive k seeded
    ``seed + (block * num_envs) % window + k``, ``window`` the largest multiple of
    ``num_envs`` within ``span`` seeds (the blocks cycle through the run's own
    training seeds).

    ARS evaluates its ``2 * n_delta`` candidates one after the other, each from
    a reset; :class:`ResidualARS` starts a block per update
    (:meth:`start_block`), so the + and - perturbations of one update meet the
    same motors, speeds and sensor noise.
    """

    def __init__(self, venv: VecEnv, seed: int, span: int = 1000) -> None:
        super().__init__(venv)
        n = self.num_envs
        if span < n:
            raise ParameterError(f"span={span!r} is outside its allowed range [num_envs = {n}, "
                                 "inf)")
        if not 0 <= seed <= TRAINING_SEED_LIMIT - span:
            raise ParameterError(f"training seeds must lie in [0, {TRAINING_SEED_LIMIT}); got "
                                 f"{seed}..{seed + span - 1}")
        self.first_seed, self.window, self.block = int(seed), (span // n) * n, 0

    def start_block(self, block: int) -> None:
        """The episodes of the following resets: those of ``block``."""
        self.block = int(block)

    def reset(self) -> np.ndarray:
        self.venv.seed(self.first_seed + (self.block * self.num_envs) % self.window)
        return self.venv.reset()

    def step_wait(self) -> VecEnvStepReturn:
        return self.venv.step_wait()


def make_training_env(motors: Sequence[Any], envs_per_motor: int, seed: int,
                      options: dict[str, Any], num_threads: int = 1) -> PresetsVecEnv:
    """``envs_per_motor`` drives around each motor of ``motors`` (preset names or
    datasheet mappings; v1 ``options``
    without ``motor``), drive k seeded ``seed + k``, each preset's drives stepped
    on ``num_threads`` of numba's threads."""
    opts = {k: v for k, v in options.items() if k != "motor"}
    env = PresetsVecEnv([make_sb3_vec_env_v1(envs_per_motor, motor=m, num_threads=num_threads,
                                             **opts) for m in motors])
    env.seed(seed)
    return env


def __getattr__(name: str) -> Any:
    # The algorithms live in .algos (sb3-contrib loads on first use).
    if name in ("ResidualARS", "ResidualRecurrentPPO", "ResidualLstmPolicy", "ALGOS", "POLICIES"):
        from . import algos

        return getattr(algos, name)
    raise AttributeError(name)


class StepAgent(RowPolicy):
    """A per-step agent as a leaderboard policy: it runs in ``StepperDamp-v1`` with
    the base controller ff-delay-comp on the drive's ``estimate`` model and acts
    every ``1/agent_hz`` s with the model's deterministic action. A recurrent
    model (``ppo_lstm``) keeps one memory per run, zero at :meth:`reset` or
    :meth:`reset_batch`; :meth:`act` is the run of the last :meth:`reset`."""

    env_id = ENV_ID_V1

    def __init__(self, path: str, name: str | None = None) -> None:
        from stepdamp_env.bench.network import recurrent_network

        from .policy import load_agent_config, load_model, trained_suites, training_coverage

        self.path = path
        self.config = load_agent_config(path)
        self.name = name or self.config.get("name", "per-step-agent")
        self.model = load_model(path)
        # A recurrent policy's memory: one row per run of the last reset.
        self.network = recurrent_network(self.model.policy)
        self._memory = None if self.network is None else self.network.initial_state(1)
        self.options = {k: v for k, v in self.config.get("env_options", {}).items()
                        if k in INTERFACE_OPTIONS}
        self.estimate = self.config.get("estimate", "identified")
        suites = trained_suites(self.config)
        extra = {} if suites is None else {
            "suites": suites, "not_in_suites": f"trained for {suites[0]} only"}
        self.card = PolicyCard(sensors="encoder, currents (observation)", model=self.estimate,
                               learned=True, oracle=self.estimate == "exact",
                               trained_on=training_coverage(self.config), **extra)

    def env_options(self, knowledge: MotorKnowledge) -> dict[str, Any]:
        return {"base_controller": "ff-delay-comp", **self.options,
                "estimate": resolve_estimate(self.estimate, knowledge)}

    @property
    def firmware_modes(self) -> tuple[str, ...]:
        """The modes ``stepdamp export`` writes its network for: those of the suites
        it was trained for (every mode for a model trained before ``--suite``)."""
        suites = self.card.suites
        if suites is None:
            return ("open-loop", "servo")
        return tuple(m for m in ("open-loop", "servo")
                     if any(get_suite(s).mode == m for s in suites))

    @property
    def firmware_drives(self) -> tuple[str, ...]:
        """The drives (``drive_mode``) ``stepdamp export`` writes its network for:
        those of the suites it was trained for (both for a model trained before
        ``--suite``)."""
        suites = self.card.suites
        return tuple(d for d in DRIVE_MODES
                     if suites is None or any(get_suite(s).drive_mode == d for s in suites))

    def firmware_network(self, context: PolicyContext) -> FirmwareNetwork:
        """The model's network for a drive's firmware (``stepdamp export``), with
        the units of its observation and action and its constant context inputs
        at ``context``'s motor and speed; a one-line ``ParameterError`` for a
        recurrent model, one that is not a plain network, or a drive it was not
        trained for."""
        from stepdamp_env.bench.network import policy_network
        from stepdamp_env.env import ACTION_NAMES_V1, CONTEXT_NAMES, EnvOptionsV1, TaskV1
        from stepdamp_env.env.v1_options import observation_names_v1

        if self.network is not None:
            raise ParameterError(f"entry {self.name!r} cannot be exported: its network is "
                                 "recurrent (an LSTM with a memory per run); export writes "
                                 "feed-forward networks only")
        net = policy_network(self.model.policy)
        if net is None:
            raise ParameterError(f"entry {self.name!r} cannot be exported: its policy is not "
                                 "a plain network of linear layers")
        nominal = context.knowledge.nominal
        drive = nominal.drive.drive_mode
        # The suites it was trained for that run this mode and drive (moves: open
        # loop on the current-mode drive).
        if self.card.suites is not None and not any(
                (get_suite(s).mode, get_suite(s).drive_mode) == (context.mode, drive)
                for s in self.card.suites):
            raise ParameterError(f"entry {self.name!r} cannot be exported for {context.mode} "
                                 f"on a {drive}-mode drive: it was trained for "
                                 f"{', '.join(self.card.suites)} only (suite "
                                 f"{self.card.suites[0]!r}: mode "
                                 f"{get_suite(self.card.suites[0]).mode}, drive_mode "
                                 f"{get_suite(self.card.suites[0]).drive_mode})")
        options = self.env_options(context.knowledge)
        task = TaskV1(EnvOptionsV1.from_kwargs({
            **options, "motor": nominal, "nominal": nominal, "mode": context.mode,
            "speed_rps": context.speed_rps}))
        o = task.options
        names = observation_names_v1(o.action_mode, o.history, o.context, o.privileged)
        if len(names) != int(net.sizes[0]) or task.obs_dim != len(names):
            raise ParameterError(f"entry {self.name!r} cannot be exported: its network reads "
                                 f"{int(net.sizes[0])} inputs, its env gives {len(names)}")
        constants = ({} if o.context != "visible" else dict(zip(
            CONTEXT_NAMES, (float(v) for v in task.context(options["estimate"],
                                                           context.speed_rps)))))
        u = task.units
        scales = ("damping-gains: Kv in A*s/rad, Kp in A/rad, the resonant rates Kr in A/rad"
                  if o.action_mode == "damping-gains" else
                  "gain-phase: the gain over Kv and the phase over pi/4"
                  if o.action_mode == "gain-phase" else
                  "harmonic corrections in N*m, a q current in A")
        return network_export(
            self, net, context, observation_names=names, decision_hz=float(o.agent_hz),
            observation_units={"position_unit_rad": u.position_unit_rad,
                               "velocity_unit_rad_s": u.velocity_unit_rad_s,
                               "current_unit_a": u.current_unit_a,
                               "speed_unit_rad_s": u.speed_unit_rad_s},
            action_names=ACTION_NAMES_V1[o.action_mode], action_scales=task.action_scales,
            constant_inputs=constants,
            notes=(f"The inputs are StepperDamp-v1's observation with action_mode "
                   f"{o.action_mode!r}, history {o.history}, context {o.context!r} (the env's "
                   "docstring: the errors over the units below, the last action, the earlier "
                   "errors newest first, the episode's context), its speed estimate "
                   f"{o.velocity_estimator!r}. The action is held for one decision by "
                   f"StepperDamp-v1's drive: ff-delay-comp's table on the {self.estimate} "
                   f"detent model plus its {o.action_mode!r} law, each entry times its "
                   f"scale ({scales})."))

    # The policy on rows (RowPolicy: a scalar run is row 0; a recurrent model's
    # memory starts at reset_batch).
    def reset_batch(self, contexts: Sequence[PolicyContext]) -> None:
        if self.network is not None:
            self._memory = self.network.initial_state(len(contexts))

    def act_batch(self, observations: np.ndarray, rows: np.ndarray) -> np.ndarray:
        from stepdamp_env.bench.network import predict_rows

        if self.network is not None:
            actions = self.network.step(observations, self._memory, rows)
            low, high = self.model.action_space.low, self.model.action_space.high
            return np.clip(np.clip(actions, low, high).astype(np.float32), -1.0, 1.0)
        return np.clip(np.asarray(predict_rows(self.model, observations), dtype=np.float32),
                       -1.0, 1.0)
