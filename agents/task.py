"""The residual tasks: their Gymnasium ids and reference configurations.

``StepperDamp-v1`` with :data:`REFERENCE_TASK` is the per-step agents' task
(:mod:`stepdamp_agents.per_step`). The rest of this module is the v0 gain
selector's:

``gym.make("StepperDampResidual-v0")`` (registered by ``import stepdamp_env``
through the entry-point group ``stepdamp.envs``, and on importing
:mod:`stepdamp_agents.residual`) is a ``StepperDamp-v0`` drive wrapped as the
residual problem (:class:`stepdamp_agents.residual.ResidualWrapper`). Its
defaults are the reference agents' task (on one preset, ``patent``, drawn
around; ``stepdamp train`` spreads its drives over all four), so an env made
without arguments is the training task; rl-baselines3-zoo relies on that, since
it builds its evaluation env without the YAML's ``env_kwargs``. ``stepdamp train`` starts
from the same defaults and applies the YAML's ``env_kwargs`` on top.

This module imports neither torch nor SB3.
"""

from __future__ import annotations

import copy
from typing import Any

from stepdamp_env.bench.protocol import POLICY_OPTIONS_V1
from stepdamp_env.bench.suites import SUITES_BY_NAME
from stepdamp_env.env.registration import ENV_ID_V1, V2_DEFAULTS
from stepdamp_env.params import ParameterError

__all__ = ["RESIDUAL_ENV_ID", "REFERENCE_DRIVE", "REFERENCE_RESIDUAL", "task_kwargs",
           "ENV_ID_V1", "REFERENCE_TASK", "INTERFACE_OPTIONS", "task_options", "SUITE_TASKS",
           "suite_task"]

RESIDUAL_ENV_ID = "StepperDampResidual-v0"

#: ``StepperDamp-v0`` options of the training drive (``max_episode_steps`` is
#: gym.make's time limit): open loop at 4 kHz, the protocol's sensors, the exact
#: feedforward model, resonant speeds with probability 0.75, ripple-only reward.
REFERENCE_DRIVE: dict[str, Any] = {
    "motor": "patent", "randomize": True, "mode": "open-loop",
    "action_mode": "harmonic+current", "agent_hz": 4000, "velocity_estimator": "kalman",
    "estimate": "exact", "resonance_prob": 0.75, "current_penalty": 0.0,
    "max_episode_steps": 1600,
    "overrides": {"current_noise_a": 0.01, "encoder_cpr": 4000},
}

#: The residual on top of the base controller: one damping gain per 400 env steps
#: (0.1 s of drive time at 4 kHz), residual current up to 0.05 of the current scale.
REFERENCE_RESIDUAL: dict[str, Any] = {
    "base": "ff-delay-comp", "residual_action": "feedback", "hold_steps": 400,
    "feedback_gain": 0.1, "residual_scale": 0.05, "reward_scale": 1000.0,
}


def task_kwargs(env_kwargs: dict[str, Any] | None = None
                ) -> tuple[dict[str, Any], dict[str, Any]]:
    """(drive options, residual kwargs): the reference updated by ``env_kwargs``,
    whose ``drive`` entry updates the drive options key by key and whose other
    keys (those of :data:`REFERENCE_RESIDUAL`) update the residual kwargs."""
    if env_kwargs is not None and not isinstance(env_kwargs, dict):
        raise ParameterError(f"env_kwargs={env_kwargs!r} must be a mapping: drive: {{...}} "
                             f"and keys of {sorted(REFERENCE_RESIDUAL)}")
    given = dict(env_kwargs or {})
    drive = given.pop("drive", None) or {}
    if not isinstance(drive, dict):
        raise ParameterError(f"env_kwargs drive={drive!r} must be a mapping of "
                             "StepperDamp-v0 options")
    unknown = sorted(set(given) - set(REFERENCE_RESIDUAL))
    if unknown:
        raise ParameterError(f"env_kwargs: unknown key(s) {unknown}; allowed: 'drive' (the "
                             f"StepperDamp-v0 options) and {sorted(REFERENCE_RESIDUAL)}")
    return ({**copy.deepcopy(REFERENCE_DRIVE), **copy.deepcopy(drive)},
            {**REFERENCE_RESIDUAL, **given})


#: ``StepperDamp-v1`` options of the per-step agents' reference training task:
#: damping-gains at 100 Hz on ff-delay-comp, history 4, the visible context,
#: randomised motors around the presets, 1 s episodes (the ramp's transient
#: dominates a 0.4 s return), the protocol's sensors, the exact detent model.
REFERENCE_TASK: dict[str, Any] = copy.deepcopy(V2_DEFAULTS)    # StepperDamp-v2's defaults

#: What ``stepdamp train --suite`` sets on top of the task for each suite
#: (:attr:`stepdamp_env.bench.suites.Suite.training_task`; v4's moves suite since 0.19.0).
SUITE_TASKS: dict[str, dict[str, Any]] = {name: copy.deepcopy(dict(s.training_task))
                                          for name, s in SUITES_BY_NAME.items()}


def suite_task(env_kwargs: dict[str, Any], suite: str) -> dict[str, Any]:
    """``env_kwargs`` (StepperDamp-v1 options) with :data:`SUITE_TASKS`'s settings
    for ``suite`` on top (``overrides`` merged key by key)."""
    if suite not in SUITE_TASKS:
        raise ParameterError(f"suite {suite!r} is not one of {list(SUITE_TASKS)}")
    extra = copy.deepcopy(SUITE_TASKS[suite])
    out = copy.deepcopy(env_kwargs)
    overrides = {**(out.get("overrides") or {}), **extra.pop("overrides", {})}
    out.update(extra)
    if overrides:
        out["overrides"] = overrides
    return out


# What the agent's interface is: these options go with the model to the leaderboard.
INTERFACE_OPTIONS = tuple(k for k in POLICY_OPTIONS_V1
                          if k not in ("base_controller", "estimate", "current_penalty"))


def task_options(env_kwargs: dict[str, Any] | None = None) -> dict[str, Any]:
    """The per-step task :data:`REFERENCE_TASK` updated by ``env_kwargs``
    (StepperDamp-v1 options); the base controller stays ff-delay-comp."""
    if env_kwargs is not None and not isinstance(env_kwargs, dict):
        raise ParameterError(f"env_kwargs={env_kwargs!r} must be a mapping of StepperDamp-v1 "
                             "options")
    out = {**copy.deepcopy(REFERENCE_TASK), **copy.deepcopy(env_kwargs or {})}
    if out.get("base_controller") != "ff-delay-comp":
        raise ParameterError(f"env_kwargs base_controller={out.get('base_controller')!r}: the "
                             "agents are residuals on 'ff-delay-comp'")
    return out
