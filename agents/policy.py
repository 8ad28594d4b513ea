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
import math
import os
from collections import OrderedDict
from typing import Any, Sequence

import numpy as np

from stepdamp_env.bench.firmware_net import FirmwareNetwork, network_export
from stepdamp_env.bench.network import predict_rows
from stepdamp_env.io import read_json
from stepdamp_env.params import ParameterError
from stepdamp_env.bench.policy import (MotorKnowledge, PolicyCard, PolicyContext, RowPolicy,
                                       resolve_estimate)
from stepdamp_env.bench.suites import suite_of

__all__ = ["ResidualAgent", "load_agent_config", "training_coverage", "trained_suites",
           "load_model", "clear_model_cache", "agent_config_path"]

# Loaded models by the sha256 of their file's bytes (never by path: a file
# rewritten in place is loaded again), the most recent last.
_MODELS: "OrderedDict[str, Any]" = OrderedDict()
_MODELS_KEPT = 32


def agent_config_path(path: str) -> str:
    """The ``NAME.agent.json`` beside a ``NAME.zip``."""
    return os.path.splitext(path)[0] + ".agent.json"


def load_agent_config(path: str) -> dict[str, Any]:
    """The ``.agent.json`` beside a model (a one-line error if it is not an object)."""
    config = read_json(agent_config_path(path), "agent config")
    if not isinstance(config, dict):
        raise ParameterError(f"agent config {agent_config_path(path)!r} must hold a JSON object")
    return config


def training_coverage(config: dict[str, Any]) -> tuple[tuple[str, float, float], ...]:
    """What an agent's training covered, as ``PolicyCard.trained_on``: its env's
    suite, the one of its mode, drive and command (open-loop or servo on the
    current-mode drive, mid-band: open loop on the voltage-mode drive, moves:
    moves in open loop on the current-mode drive), and the speeds it drew
    (rev/s, the cruise's in a move). Those are the uniform range
    ``speed_range_rps`` and, with ``resonance_prob`` > 0, each training motor's
    resonances f_h (1 +- ``resonance_spread``), where f_h scales with
    sqrt(Km/J) over the randomisation box. The ranges are merged where they
    overlap."""
    from stepdamp_env.env.options import DEFAULT_RANDOMIZATION, EnvOptions
    from stepdamp_env.motorfile import load_system
    from stepdamp_env.presets import get_preset

    training = config.get("training", {})
    kwargs = training.get("env_kwargs", {})
    drive = (kwargs.get("overrides") or {}).get("drive_mode", kwargs.get("drive_mode", "current"))
    if drive not in ("current", "voltage"):
        return ()
    ranges = [tuple(float(v) for v in kwargs.get("speed_range_rps",
                                                   EnvOptions.speed_range_rps))]
    if float(kwargs.get("resonance_prob", EnvOptions.resonance_prob)) > 0.0:
        box = kwargs.get("randomize", False)
        box = DEFAULT_RANDOMIZATION if box is True else (box or {})
        km_lo, km_hi = box.get("Km", (1.0, 1.0))
        j_lo, j_hi = box.get("J", (1.0, 1.0))
        spread = float(kwargs.get("resonance_spread", EnvOptions.resonance_spread))
        for motor in training.get("motors", []):
            # A preset's name, or a datasheet mapping drawn from the pool.
            system = load_system(motor) if isinstance(motor, dict) else get_preset(motor)
            for f in system.predicted_resonances_rps().values():
                ranges.append((f * math.sqrt(km_lo / j_hi) * (1.0 - spread),
                               f * math.sqrt(km_hi / j_lo) * (1.0 + spread)))
    merged: list[list[float]] = []
    for lo, hi in sorted(ranges):
        if merged and lo <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], hi)
        else:
            merged.append([lo, hi])
    # The suite of the env's mode, drive and command (moves: the speeds are the cruise's).
    suite = suite_of(str(kwargs.get("mode", "open-loop")), drive,
                     str(kwargs.get("profile", "constant")))
    return tuple((suite, lo, hi) for lo, hi in merged) if suite else ()


def trained_suites(config: dict[str, Any]) -> tuple[str, ...] | None:
    """The one suite a ``stepdamp train --suite`` model runs in (its config's
    ``training.suite``); None for models trained before the option (they run in
    every suite, ranked only where their coverage reaches)."""
    suite = (config.get("training") or {}).get("suite")
    return (str(suite),) if suite else None


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

    from .algos import ALGOS, POLICIES

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


class ResidualAgent(RowPolicy):
    """Policy: base controller (patent-ff, optionally ff-delay-comp's lead) plus
    the network's residual, deterministic."""

    def __init__(self, path: str, name: str | None = None) -> None:
        from .residual import RESIDUAL_ACTIONS

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
        which = self.config.get("estimate", "identified")
        self.card = PolicyCard(sensors="encoder, currents (observation)", model=which,
                               learned=True, oracle=which == "exact",
                               trained_on=training_coverage(self.config))

    def env_options(self, knowledge: MotorKnowledge) -> dict[str, Any]:
        which = self.config.get("estimate", "identified")
        return {"base_controller": "patent-ff", "action_mode": self.action_mode,
                **self.env_extra, "estimate": resolve_estimate(which, knowledge)}

    def firmware_network(self, context: PolicyContext) -> FirmwareNetwork:
        """The gain selector's network for a drive's firmware (``stepdamp
        export``): its inputs the v0 observation, the velocity feature, the 12
        context features (their values at ``context``'s motor and speed) and the
        velocity feature's RMS over the last hold; its output the damping gain,
        held for ``hold_steps`` env steps. Only the "feedback" residual (the
        committed ``ppo-gain-selector``'s) is exported."""
        from stepdamp_env.bench.network import policy_network
        from stepdamp_env.env.layout import observation_names
        from stepdamp_env.env.options import EnvOptions

        from .residual import context_features, velocity_feature_gain

        net = policy_network(self.model.policy)
        if self.residual_action != "feedback" or net is None:
            raise ParameterError(f"entry {self.name!r} cannot be exported: export writes the "
                                 "gain selector's plain network (residual 'feedback') only")
        est = context.estimate if context.estimate is not None else context.knowledge.exact
        nominal = context.knowledge.nominal
        features, _ = context_features(nominal, est, context.mode, context.speed_rps,
                                       context.action_scale)
        constants = tuple(f"ff_model_{k}{h}" for h in (1, 2, 4) for k in ("s", "c")) + \
            tuple(f"ff_delay_comp_d{k}{h}" for h in (1, 2, 4) for k in ("s", "c"))
        names = (observation_names(self.action_mode) + ("velocity_feature",) + constants
                 + ("velocity_feature_rms",))
        if len(names) != int(net.sizes[0]):
            raise ParameterError(f"entry {self.name!r} cannot be exported: its network reads "
                                 f"{int(net.sizes[0])} inputs, not {len(names)}")
        top = max(EnvOptions.speed_range_rps[1], abs(context.speed_rps))
        return network_export(
            self, net, context, observation_names=names,
            decision_hz=float(context.agent_hz) / self.hold_steps,
            observation_units={"full_step_rad": nominal.motor.full_step_rad,
                               "command_speed_rad_s": 2.0 * math.pi * abs(context.speed_rps),
                               "speed_command_unit_rad_s": 2.0 * math.pi * top,
                               "holding_current_a": nominal.drive.holding_current,
                               "velocity_feature_per_velocity_error": velocity_feature_gain(
                                   nominal, context.speed_rps),
                               "ff_model_unit_nm": context.action_scale},
            action_names=("gain",), action_scales=(self.feedback_gain,),
            constant_inputs=dict(zip(constants, (float(v) for v in features))),
            notes=(f"v0's gain selector: every {self.hold_steps} env steps at "
                   f"{float(context.agent_hz):g} Hz it picks a gain g from the env's observation "
                   "with action_mode 'harmonic+current' (the errors over full_step_rad and "
                   "command_speed_rad_s, the speed command over speed_command_unit_rad_s, "
                   "the currents over holding_current_a), the velocity feature v = clip("
                   "velocity_error * velocity_feature_per_velocity_error, -10, 10) (float), "
                   "the drive's model (constant: the detent model over ff_model_unit_nm and "
                   "ff-delay-comp's action) and the RMS of v over the hold before (0 at the "
                   f"first); each step in between the drive adds the q current "
                   f"{self.residual_scale!r} * {context.current_scale_a!r} A * clip("
                   f"{self.feedback_gain!r} * g * v, -1, 1) to ff-delay-comp's table."))

    # The policy on rows (RowPolicy: a scalar run is row 0; all rows step together,
    # so they share the step count).
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
        if self.residual_action != "feedback":
            r = np.asarray(predict_rows(self.model, self._rows.augment(obs, rows)),
                           dtype=np.float64)
            return self._rows.env_action(r, self.residual_scale, self.residual_action,
                                         rows).astype(np.float32)
        from .residual import feedback_current

        # The network sees the whole agent observation only when it sets the gain.
        vel = self._rows.velocity_feature(obs, rows).astype(np.float64)
        if self._rows_step > 0:
            self._rows_sq[rows] += vel * vel
        if self._rows_step % self.hold_steps == 0:
            rms = (np.sqrt(self._rows_sq[rows] / self.hold_steps) if self._rows_step > 0
                   else np.zeros(len(rows)))
            x_in = np.concatenate([self._rows.augment(obs, rows),
                                   rms.astype(np.float32)[:, None]], axis=1)
            self._rows_gain[rows] = np.asarray(predict_rows(self.model, x_in),
                                               dtype=np.float64).reshape(-1)
            self._rows_sq[rows] = 0.0
        self._rows_step += 1
        current = feedback_current(self._rows_gain[rows], vel, self.feedback_gain)
        return self._rows.env_action(current[:, None], self.residual_scale, "current",
                                     rows).astype(np.float32)

