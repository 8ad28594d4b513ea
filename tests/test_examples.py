"""examples/ppo_stepperdamp.py stays green: a few updates run end to end, its
command line builds every field of its Args, and its evaluation of the zero action
is the env's own return of the zero action."""

from __future__ import annotations

import importlib.util
import math
import os
import sys

import gymnasium as gym
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _example():
    path = os.path.join(ROOT, "examples", "ppo_stepperdamp.py")
    spec = importlib.util.spec_from_file_location("ppo_stepperdamp", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module             # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_the_single_file_ppo_runs_and_reports_against_the_zero_action():
    ex = _example()
    args = ex.Args.from_cli(["--total-steps", "1024", "--rollout-steps", "64", "--num-envs", "8",
                             "--eval-episodes", "2", "--eval-every", "1", "--epochs", "2"])
    assert args.total_steps == 1024 and args.env_id == "StepperDamp-v3"
    history = ex.main(args)
    assert [h["env_steps"] for h in history] == [512, 1024]
    assert all(math.isfinite(h["return"]) and h["wall_s"] > 0.0 for h in history)
    # The zero action's return is the env's, episode for episode.
    env = gym.make("StepperDamp-v3")
    totals = []
    for k in range(2):
        env.reset(seed=ex.EVAL_SEED + k)
        total, done = 0.0, False
        while not done:
            _, r, term, trunc, _ = env.step(np.zeros(2, np.float32))
            total += r
            done = term or trunc
        totals.append(total)
    assert history[0]["zero_action_return"] == float(np.mean(totals))
