"""Residual agents: zero residual = base controller, zero warm-up, short training end to end."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from agents.policy import ResidualAgent, load_model  # noqa: E402
from agents.residual import (ALGOS, ResidualSAC, ResidualTD3, ResidualWrapper,  # noqa: E402
                             context_features, make_residual_vec_env)
from agents.train import Args, load_hyperparams, split_hyperparams, train  # noqa: E402
from baselines import make_baseline  # noqa: E402
from baselines.base import MotorKnowledge, PolicyContext  # noqa: E402
from stepdamp_env.envs import StepperDampEnv  # noqa: E402
from stepdamp_env.params import FeedforwardModel, get_preset  # noqa: E402

torch.set_num_threads(1)
MOTOR = "qsh4218-51-10-049"


def _venv(n=2, **kw):
    return make_residual_vec_env([MOTOR], n, 10, randomize=True, **kw)


def _save(model, path, algo, base):
    model.save(path)
    with open(os.path.splitext(path)[0] + ".agent.json", "w") as fh:
        json.dump({"name": f"{algo}-residual", "algo": algo, "base": base,
                   "residual_scale": 0.1}, fh)


def _context(system, speed, scale, mode="open-loop"):
    exact = FeedforwardModel.from_motor(system.motor)
    knowledge = MotorKnowledge(nominal=get_preset(MOTOR), identified=exact, exact=exact)
    return PolicyContext(knowledge=knowledge, estimate=exact, mode=mode, speed_rps=speed,
                         action_mode="harmonic", action_scale=scale, agent_hz=1000.0)


def _trajectory(policy, system, speed, steps=150, seed=3):
    options = policy.env_options(_context(system, speed, 0.0).knowledge)
    env = StepperDampEnv(motor=system, speed_rps=speed, **options)
    obs, _ = env.reset(seed=seed)
    policy.reset(_context(system, speed, env.unwrapped._factory.action_scale))
    out = [obs]
    for _ in range(steps):
        obs, *_ = env.step(policy.act(obs))
        out.append(obs)
    return np.array(out), env.drive_state


@pytest.mark.parametrize("algo", ["sac", "td3", "ppo"])
@pytest.mark.parametrize("base,baseline", [("patent-ff", "patent-ff-identified"),
                                           ("ff-delay-comp", "ff-delay-comp")])
def test_zero_residual_reproduces_base_controller(tmp_path, algo, base, baseline):
    venv = _venv(base=base)
    model = ALGOS[algo]("ResidualMlpPolicy", venv, seed=0, device="cpu")
    obs = venv.reset()
    rng = np.random.default_rng(0)
    probe = np.concatenate([obs, rng.uniform(-1, 1, size=(64, obs.shape[1]))]).astype(np.float32)
    actions, _ = model.predict(probe, deterministic=True)
    assert np.array_equal(actions, np.zeros_like(actions))
    path = str(tmp_path / f"{algo}.zip")
    _save(model, path, algo, base)
    agent = ResidualAgent(path)
    system = get_preset(MOTOR).replace(Kd2=0.9 * get_preset(MOTOR).motor.Kd2)
    speed = system.predicted_resonances_rps()[2]
    got, s_got = _trajectory(agent, system, speed)
    want, s_want = _trajectory(make_baseline(baseline), system, speed)
    # Bit for bit: the sensed observation (the last-action entries differ in size when the
    # baseline acts in "current" mode) and the whole drive state.
    assert np.array_equal(got[:, :11], want[:, :11]) and np.array_equal(s_got, s_want)


@pytest.mark.parametrize("cls", [ResidualSAC, ResidualTD3])
def test_warmup_collects_zero_residuals(cls):
    model = cls("ResidualMlpPolicy", _venv(), seed=0, device="cpu", learning_starts=100,
                policy_kwargs={"net_arch": [8]})
    model._last_obs = model.env.reset()
    action, buffer_action = model._sample_action(100, None, n_envs=2)
    assert np.array_equal(action, np.zeros((2, 6))) and np.array_equal(buffer_action, action)


def test_wrapper_matches_vector_env_features():
    import gymnasium as gym

    import stepdamp_env  # noqa: F401

    env = ResidualWrapper(gym.make("StepperDamp-v0", motor=MOTOR, randomize=True),
                          base="ff-delay-comp", residual_scale=0.1)
    obs, info = env.reset(seed=5)
    inner = env.unwrapped
    feats, dc = context_features(inner._factory.nominal,
                                 FeedforwardModel.from_motor(inner.system.motor), "open-loop",
                                 info["speed_rps"], inner._factory.action_scale)
    assert obs.shape == (29,) and np.array_equal(obs[17:], feats)
    obs2, *_ = env.step(np.zeros(6, dtype=np.float32))
    assert np.allclose(obs2[11:17], dc)             # the base action was applied


def test_hyperparams_files_parse():
    for algo in ("sac", "td3", "ppo"):
        sp = split_hyperparams(load_hyperparams(Args(algo=algo)))
        assert sp["policy"] == "ResidualMlpPolicy"
        assert sp["wrapper_kwargs"]["base"] in ("patent-ff", "ff-delay-comp")
        assert sp["env_kwargs"]["randomize"] is True


def test_short_training_end_to_end_and_deterministic_reload(tmp_path):
    out = str(tmp_path / "run")
    log = train(Args(algo="sac", seed=4, out=out, total_timesteps=3000, motors=(MOTOR,),
                     envs_per_motor=4, eval_freq=2000, val_motors_per_preset=1,
                     checkpoint_freq=2000, progress=False, tensorboard=False,
                     extra={"learning_starts": 1000, "batch_size": 64}))
    assert log["total_timesteps"] == 3000 and len(log["evaluations"]) >= 2
    for name in ("final.zip", "final.agent.json", "best.zip", "train_log.json"):
        assert os.path.isfile(os.path.join(out, name))
    assert os.path.isdir(os.path.join(out, "checkpoints"))
    path = os.path.join(out, "final.zip")
    system = get_preset(MOTOR).replace(Kd4=1.1 * get_preset(MOTOR).motor.Kd4)
    speed = system.predicted_resonances_rps()[4]
    a, s_a = _trajectory(ResidualAgent(path), system, speed, steps=100)
    from agents import policy as P

    P._MODELS.clear()                                # reload from disk
    b, s_b = _trajectory(ResidualAgent(path), system, speed, steps=100)
    assert np.array_equal(a, b) and np.array_equal(s_a, s_b)
    assert load_model(path).policy.actor.mu.weight.abs().sum() > 0     # it did learn


def test_cli_train_parses():
    from stepdamp_env.cli import build_parser

    ns = build_parser().parse_args(["train", "--algo", "td3", "--total-timesteps", "10",
                                    "--set", "learning_starts=5"])
    assert ns.algo == "td3" and ns.total_timesteps == 10 and ns.extra == ["learning_starts=5"]
