"""rl-baselines3-zoo trains and evaluates the residual task with the committed YAML.

Runs when the optional extra is installed (``pip install -e ".[zoo]"``; ``.ci/run``
does); skipped otherwise.
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("rl_zoo3")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.parametrize("algo", ["ppo"])
def test_zoo_trains_and_evaluates_the_documented_command(tmp_path, algo):
    """docs/agents.md's command, shortened: 256 steps on 4 envs, an evaluation every 64."""
    cmd = [sys.executable, "-m", "rl_zoo3.train", "--algo", algo,
           "--env", "StepperDampResidual-v0", "--gym-packages", "stepdamp_agents.residual",
           "--conf-file", os.path.join(ROOT, "agents", "hyperparams", f"{algo}.yml"),
           "-n", "256", "--eval-freq", "64", "--eval-episodes", "2", "--seed", "1",
           "-params", "n_envs:4", "--log-folder", str(tmp_path / "logs")]
    env = dict(os.environ, MPLBACKEND="Agg")
    out = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    run = tmp_path / "logs" / algo / "StepperDampResidual-v0_1"
    assert (run / "StepperDampResidual-v0.zip").is_file()
    evals = np.load(run / "evaluations.npz")
    assert evals["results"].shape == (4, 2)               # 4 evaluations of 2 episodes
    assert np.all(np.isfinite(evals["results"]))
    assert np.all(evals["ep_lengths"] == 4)               # 1600 env steps / 400 per gain


@pytest.mark.parametrize("algo,package,n_envs", [("ars", "stepdamp_env", 1),
                                                 ("ppo", "stepdamp_agents.residual", 2)])
def test_zoo_trains_the_per_step_task(tmp_path, algo, package, n_envs):
    """The YAMLs' StepperDamp-v1 entries under the zoo (commands in their comments)."""
    cmd = [sys.executable, "-m", "rl_zoo3.train", "--algo", algo, "--env", "StepperDamp-v1",
           "--gym-packages", package,
           "--conf-file", os.path.join(ROOT, "agents", "hyperparams", f"{algo}.yml"),
           "-n", "400", "--eval-freq", "-1", "--seed", "1", "--log-folder", str(tmp_path / "logs"),
           "-params", f"n_envs:{n_envs}"] + (["n_steps:100", "batch_size:100"] if algo == "ppo"
                                             else [])
    out = subprocess.run(cmd, cwd=tmp_path, env=dict(os.environ, MPLBACKEND="Agg"),
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert (tmp_path / "logs" / algo / "StepperDamp-v1_1" / "StepperDamp-v1.zip").is_file()


V2_PARAMS = {"ars": ["n_envs:1"], "ppo": ["n_envs:2", "n_steps:100", "batch_size:100"],
             "ppo_lstm": ["n_envs:2", "n_steps:100", "batch_size:100"],
             "sac": ["n_envs:2", "learning_starts:200"], "td3": ["n_envs:2", "learning_starts:200"]}


@pytest.mark.slow
@pytest.mark.parametrize("algo", sorted(V2_PARAMS))
def test_zoo_trains_and_evaluates_every_yaml_on_v2(tmp_path, algo):
    """Each YAML's StepperDamp-v2 entry, as its comment says to run it, with the zoo's
    evaluations on: the evaluation env (built from the id alone) is the training task."""
    if algo in ("ars", "ppo_lstm"):
        pytest.importorskip("sb3_contrib")
    package = "stepdamp_env" if algo == "ars" else "stepdamp_agents.residual"
    cmd = [sys.executable, "-m", "rl_zoo3.train", "--algo", algo, "--env", "StepperDamp-v2",
           "--gym-packages", package,
           "--conf-file", os.path.join(ROOT, "agents", "hyperparams", f"{algo}.yml"),
           "-n", "800", "--eval-freq", "400", "--eval-episodes", "2", "--seed", "1",
           "--log-folder", str(tmp_path / "logs"), "-params", *V2_PARAMS[algo]]
    out = subprocess.run(cmd, cwd=tmp_path, env=dict(os.environ, MPLBACKEND="Agg"),
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    run = tmp_path / "logs" / algo / "StepperDamp-v2_1"
    evals = np.load(run / "evaluations.npz")
    assert evals["results"].shape[1] == 2 and len(evals["results"]) >= 1
    assert np.all(np.isfinite(evals["results"]))
    assert np.all(evals["ep_lengths"] == 100)           # 1 s at 100 Hz: v2's defaults


V3_PARAMS = {"ppo": ["n_steps:100"], "sac": ["learning_starts:200"],
             "td3": ["learning_starts:200"]}


@pytest.mark.slow
@pytest.mark.parametrize("algo", sorted(V3_PARAMS))
def test_zoo_trains_and_evaluates_the_library_defaults_on_v3(tmp_path, algo):
    """Each YAML's StepperDamp-v3 entry (the library's defaults on 8 envs) with the
    zoo's evaluations on; ``import stepdamp_env`` registers the id."""
    cmd = [sys.executable, "-m", "rl_zoo3.train", "--algo", algo, "--env", "StepperDamp-v3",
           "--gym-packages", "stepdamp_env",
           "--conf-file", os.path.join(ROOT, "agents", "hyperparams", f"{algo}.yml"),
           "-n", "1600", "--eval-freq", "100", "--eval-episodes", "2", "--seed", "1",
           "--log-folder", str(tmp_path / "logs"), "-params", *V3_PARAMS[algo]]
    out = subprocess.run(cmd, cwd=tmp_path, env=dict(os.environ, MPLBACKEND="Agg"),
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    evals = np.load(tmp_path / "logs" / algo / "StepperDamp-v3_1" / "evaluations.npz")
    assert evals["results"].shape[1] == 2 and len(evals["results"]) >= 1
    assert np.all(np.isfinite(evals["results"]))
    assert np.all(evals["ep_lengths"] == 100)
