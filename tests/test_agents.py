"""Residual agents: zero residual = base controller, zero warm-up, short training end to end."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from stepdamp_agents.policy import ResidualAgent, clear_model_cache, load_model  # noqa: E402
from stepdamp_agents.residual import (ALGOS, ResidualSAC, ResidualTD3, ResidualWrapper,  # noqa: E402
                             context_features, make_residual_vec_env)
from stepdamp_agents.train import Args, load_hyperparams, split_hyperparams, train  # noqa: E402
from stepdamp_agents.task import RESIDUAL_ENV_ID  # noqa: E402
from stepdamp_baselines import make_baseline  # noqa: E402
from stepdamp_env import kernel as K  # noqa: E402
from stepdamp_env.bench import (MotorKnowledge, PolicyContext, policy_env_options,  # noqa: E402
                                run_episode)
from stepdamp_env.env import StepperDampEnv  # noqa: E402
from stepdamp_env.params import FeedforwardModel  # noqa: E402
from stepdamp_env.presets import get_preset  # noqa: E402

torch.set_num_threads(1)
MOTOR = "qsh4218-51-10-049"


def _venv(n=2, **kw):
    return make_residual_vec_env([MOTOR], n, 10, randomize=True, **kw)


def _save(model, path, algo, base, residual_action="harmonic", env_options=None):
    model.save(path)
    with open(os.path.splitext(path)[0] + ".agent.json", "w") as fh:
        json.dump({"name": f"{algo}-residual", "algo": algo, "base": base,
                   "residual_scale": 0.1, "residual_action": residual_action,
                   "env_options": env_options or {}}, fh)


def _context(system, speed, scale, mode="open-loop"):
    exact = FeedforwardModel.from_motor(system.motor)
    knowledge = MotorKnowledge(nominal=get_preset(MOTOR), identified=exact, exact=exact)
    return PolicyContext(knowledge=knowledge, estimate=exact, mode=mode, speed_rps=speed,
                         action_mode="harmonic", action_scale=scale, agent_hz=1000.0)


def _trajectory(policy, system, speed, steps=150, seed=3):
    """Observations after each of ``steps`` agent steps and the final drive state."""
    def record(env, obs, start):
        return obs, env.drive_state

    knowledge = _context(system, speed, 0.0).knowledge
    agent_hz = policy_env_options(policy, knowledge).get("agent_hz", 1000.0)
    result = run_episode(policy, knowledge, system, mode="open-loop", speed_rps=speed,
                         seed=seed, until_s=(steps - 0.5) / agent_hz, on_step=record)
    assert len(result.trace) == steps
    return np.array([o for o, _ in result.trace]), result.trace[-1][1]


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["sac", "td3", "ppo"])
@pytest.mark.parametrize("base,baseline,residual_action", [
    ("patent-ff", "patent-ff-identified", "harmonic"),
    ("ff-delay-comp", "ff-delay-comp", "harmonic"),
    ("ff-delay-comp", "ff-delay-comp", "current"),
])
def test_zero_residual_reproduces_base_controller(tmp_path, algo, base, baseline,
                                                  residual_action):
    venv = _venv(base=base, residual_action=residual_action)
    model = ALGOS[algo]("ResidualMlpPolicy", venv, seed=0, device="cpu")
    obs = venv.reset()
    rng = np.random.default_rng(0)
    probe = np.concatenate([obs, rng.uniform(-1, 1, size=(64, obs.shape[1]))]).astype(np.float32)
    actions, _ = model.predict(probe, deterministic=True)
    assert np.array_equal(actions, np.zeros_like(actions))
    path = str(tmp_path / f"{algo}.zip")
    _save(model, path, algo, base, residual_action)
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
    feats, dc = context_features(inner.sampler.nominal,
                                 FeedforwardModel.from_motor(inner.system.motor), "open-loop",
                                 info["speed_rps"], inner.sampler.action_scales[0])
    assert obs.shape == (30,) and np.array_equal(obs[18:], feats)
    obs2, *_ = env.step(np.zeros(6, dtype=np.float32))
    assert np.allclose(obs2[11:17], dc)             # the base action was applied
    venv = make_residual_vec_env([MOTOR], 1, 5, randomize=True, base="ff-delay-comp",
                                 residual_scale=0.1)
    assert np.array_equal(venv.reset()[0], obs)     # same seed, same augmented observation


def test_current_residual_velocity_feature_is_the_physical_velocity_error():
    """Feature 17 = (w_cmd - w_fb) / (1e-3 * wn * full step) of the nominal motor, and a
    residual r drives the q current r * residual_scale * current_scale_a."""
    import gymnasium as gym

    import stepdamp_env  # noqa: F401

    env = ResidualWrapper(gym.make("StepperDamp-v0", motor=MOTOR, speed_rps=0.5,
                                   action_mode="harmonic+current", agent_hz=4000.0),
                          base="ff-delay-comp", residual_scale=0.1, residual_action="current")
    assert env.action_space.shape == (1,) and env.observation_space.shape == (31,)
    env.reset(seed=1)
    m = get_preset(MOTOR).motor
    wn = np.sqrt(m.Km * get_preset(MOTOR).drive.holding_current * m.Nr / m.J)
    inner = env.unwrapped
    for _ in range(40):
        obs, *_ = env.step(np.array([0.5], dtype=np.float32))
        s = inner.drive_state
        want = (s[K.STATE.OMEGA_CMD] - s[K.STATE.OMEGA_FB]) / (1e-3 * wn * m.full_step_rad)
        assert obs[18] == pytest.approx(np.clip(want, -10, 10), rel=1e-5, abs=1e-6)
        assert obs[17] == pytest.approx(0.05)       # last env action's current entry
        assert s[K.STATE.OMEGA_CMD] > 0


def test_hyperparams_files_parse():
    for algo in ("sac", "td3", "ppo"):
        sp = split_hyperparams(load_hyperparams(Args(algo=algo, env=RESIDUAL_ENV_ID)))
        assert sp["policy"] == "ResidualMlpPolicy"
        assert sp["wrapper_kwargs"]["base"] in ("patent-ff", "ff-delay-comp")
        assert sp["env_kwargs"]["randomize"] is True


@pytest.mark.slow
def test_short_training_end_to_end_and_deterministic_reload(tmp_path):
    out = str(tmp_path / "run")
    # 400 decisions (2 evaluations, a checkpoint): CI's budget.
    log = train(Args(algo="sac", env=RESIDUAL_ENV_ID, seed=4, out=out, total_timesteps=400,
                     motors=(MOTOR,),
                     envs_per_motor=4, eval_freq=200, val_motors_per_preset=1,
                     checkpoint_freq=200, progress=False, tensorboard=False,
                     # One thread: beside another xdist worker, two spin on two cores.
                     num_threads=1, extra={"learning_starts": 100, "batch_size": 64}))
    assert log["total_timesteps"] == 400 and len(log["evaluations"]) >= 2
    for name in ("final.zip", "final.agent.json", "best.zip", "train_log.json"):
        assert os.path.isfile(os.path.join(out, name))
    assert os.path.isdir(os.path.join(out, "checkpoints"))
    path = os.path.join(out, "final.zip")
    system = get_preset(MOTOR).replace(Kd4=1.1 * get_preset(MOTOR).motor.Kd4)
    speed = system.predicted_resonances_rps()[4]
    a, s_a = _trajectory(ResidualAgent(path), system, speed, steps=100)
    clear_model_cache()                              # reload from disk
    b, s_b = _trajectory(ResidualAgent(path), system, speed, steps=100)
    assert np.array_equal(a, b) and np.array_equal(s_a, s_b)
    assert load_model(path).policy.actor.mu.weight.abs().sum() > 0     # it did learn


def test_residual_task_id_made_without_arguments_is_the_reference_task():
    """The zoo builds its evaluation env with gym.make(id) and no env_kwargs: that env
    must be the training task (the YAMLs carry no env_kwargs)."""
    import gymnasium as gym

    from stepdamp_agents.task import REFERENCE_DRIVE, REFERENCE_RESIDUAL, RESIDUAL_ENV_ID

    env = gym.make(RESIDUAL_ENV_ID)
    inner = env.unwrapped
    for key, value in REFERENCE_DRIVE.items():
        if key not in ("max_episode_steps", "overrides"):
            assert getattr(inner.options, key) == value, key
    assert env.get_wrapper_attr("hold_steps") == REFERENCE_RESIDUAL["hold_steps"]
    assert env.get_wrapper_attr("base") == REFERENCE_RESIDUAL["base"]
    venv = make_residual_vec_env([MOTOR], 1, 10, **{k: v for k, v in REFERENCE_DRIVE.items()
                                                      if k != "motor"}, **REFERENCE_RESIDUAL)
    assert env.observation_space == venv.observation_space
    assert env.action_space == venv.action_space
    for algo in ("sac", "td3", "ppo"):
        sp = split_hyperparams(load_hyperparams(Args(algo=algo, env=RESIDUAL_ENV_ID)))
        assert sp["env_kwargs"] == REFERENCE_DRIVE and sp["wrapper_kwargs"] == REFERENCE_RESIDUAL
    # Steps end with the drive's own time limit: 1600 env steps = 4 held gains.
    env.reset(seed=3)
    ends = [env.step(np.zeros(1, np.float32))[3] for _ in range(4)]
    assert ends == [False, False, False, True]
    assert gym.make(RESIDUAL_ENV_ID, hold_steps=200, drive={"motor": MOTOR}).unwrapped \
        .options.motor == MOTOR
    from stepdamp_agents.task import task_kwargs
    from stepdamp_env.params import ParameterError

    for bad in ({"agent_hz": 2000}, {"drive": [1]}, [1]):       # a drive key at the top level
        with pytest.raises(ParameterError, match="env_kwargs"):
            task_kwargs(bad)
    drive, _ = task_kwargs()
    drive["overrides"]["J"] = 2.0                                 # a copy, not the reference
    assert REFERENCE_DRIVE["overrides"] == {"current_noise_a": 0.01, "encoder_cpr": 4000}
    env.close()
    venv.close()


def test_cli_train_parses():
    from stepdamp_env.cli import build_parser

    ns = build_parser().parse_args(["train", "--algo", "td3", "--total-timesteps", "10",
                                    "--hyperparam", "learning_starts=5"])
    assert ns.algo == "td3" and ns.total_timesteps == 10 and ns.extra == ["learning_starts=5"]


def test_feedback_residual_is_the_same_in_training_scalar_wrapper_and_leaderboard_agent(tmp_path):
    """"feedback": a gain held for hold_steps, a damping current in between. The native
    vector env (training), the scalar wrapper (zoo) and the leaderboard agent run the
    same drive through the same actions, bit for bit."""
    import gymnasium as gym

    import stepdamp_env  # noqa: F401

    hold, decisions, seed = 7, 4, 11
    speed = get_preset(MOTOR).predicted_resonances_rps()[4]
    env_kw = dict(motor=MOTOR, speed_rps=speed, agent_hz=4000.0, velocity_estimator="kalman",
                  overrides={"current_noise_a": 0.01})
    res_kw = dict(base="ff-delay-comp", residual_scale=0.05, residual_action="feedback",
                  hold_steps=hold, feedback_gain=0.1)
    venv = make_residual_vec_env([MOTOR], 1, seed, max_episode_steps=1000, **res_kw,
                                 **{k: v for k, v in env_kw.items() if k != "motor"})
    model = ALGOS["ppo"]("ResidualMlpPolicy", venv, seed=0, device="cpu",
                         policy_kwargs={"net_arch": [8]})
    venv.seed(seed)                             # the model seeded it with its own seed
    with torch.no_grad():                       # a gain that depends on the observation
        model.policy.action_net.weight.normal_(0.0, 0.02)
        model.policy.action_net.bias.fill_(0.3)
    path = str(tmp_path / "fb.zip")
    model.save(path)
    with open(str(tmp_path / "fb.agent.json"), "w") as fh:
        json.dump({"name": "ppo-gain-selector", "algo": "ppo", **res_kw,
                   "env_options": {"agent_hz": 4000.0, "velocity_estimator": "kalman"}}, fh)

    scalar = ResidualWrapper(gym.make("StepperDamp-v0", action_mode="harmonic+current",
                                      **env_kw), **res_kw)
    obs_v = venv.reset()
    obs_s, _ = scalar.reset(seed=seed)
    assert obs_s.shape == (32,) and np.array_equal(obs_v[0], obs_s) and obs_s[-1] == 0.0
    gains = []
    for _ in range(decisions):
        a, _ = model.predict(obs_s, deterministic=True)
        gains.append(float(a[0]))
        obs_s, r_s, *_ = scalar.step(a)
        obs_v, r_v, *_ = venv.step(a[None])
        # Rewards: float32 in the SB3 vector env, float64 in the scalar one.
        assert np.array_equal(obs_v[0], obs_s) and r_v[0] == pytest.approx(r_s, rel=1e-6)
    assert obs_s[-1] > 0 and len(set(gains)) == decisions      # the gain really changed
    state_training = scalar.unwrapped.drive_state

    clear_model_cache()
    agent = ResidualAgent(path)
    system = get_preset(MOTOR).replace(current_noise_a=0.01)
    exact = FeedforwardModel.from_motor(system.motor)
    knowledge = MotorKnowledge(nominal=get_preset(MOTOR), identified=exact, exact=exact)
    options = agent.env_options(knowledge)
    assert options["action_mode"] == "harmonic+current" and options["agent_hz"] == 4000.0
    env = StepperDampEnv(motor=system, speed_rps=speed, **options)
    obs, _ = env.reset(seed=seed)
    f = env.sampler
    agent.reset(PolicyContext(knowledge=knowledge, estimate=exact, mode="open-loop",
                              speed_rps=speed, action_mode="harmonic+current",
                              action_scale=f.harmonic_scale_nm, agent_hz=4000.0,
                              current_scale_a=f.current_scale_a))
    for _ in range(hold * decisions):
        obs, *_ = env.step(agent.act(obs))
    assert np.array_equal(env.drive_state, state_training)


@pytest.mark.slow
def test_reference_agent_is_listed_and_beats_the_model_based_baselines():
    """The committed reference model (agents/reference/ppo-gain-selector.seed*) runs in the
    leaderboard by default under its name; on the quick protocol's open-loop suite it
    damps below half of patent-ff-identified and below ff-delay-comp."""
    import dataclasses

    from stepdamp_agents import reference_names
    from stepdamp_env.bench import default_policy_names, quick_protocol, run_leaderboard

    assert "ppo-gain-selector" in reference_names() and "ppo-gain-selector" in default_policy_names()
    with open(os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                           "agents", "reference", "ppo-gain-selector.seed1.train_log.json")) as fh:
        log = json.load(fh)
    assert log["config"]["training"]["seed"] == 1 and log["train_wall_s"] < 20 * 60
    protocol = dataclasses.replace(quick_protocol(), suites=("open-loop",))
    board = run_leaderboard(protocol, ["patent-ff-identified", "ff-delay-comp", "ppo-gain-selector"],
                            workers=1, progress=False)
    iqm = {e["name"]: e["headline"]["iqm"] for e in board["entries"]}
    assert iqm["ppo-gain-selector"] < 0.5 * iqm["patent-ff-identified"]
    assert iqm["ppo-gain-selector"] < iqm["ff-delay-comp"]


def test_training_seeds_stay_below_the_protocol_limit():
    """Training seeds seed .. seed + n - 1 must all lie below TRAINING_SEED_LIMIT
    (the evaluation seeds start there); the guard once never fired."""
    from stepdamp_env.bench import TRAINING_SEED_LIMIT

    for seed in (TRAINING_SEED_LIMIT, TRAINING_SEED_LIMIT - 1, -1):
        with pytest.raises(ValueError, match="training seeds"):
            make_residual_vec_env([MOTOR], 2, seed, randomize=True)
    make_residual_vec_env([MOTOR], 2, TRAINING_SEED_LIMIT - 2, randomize=True).close()


def test_policy_kwargs_are_parsed_never_executed(tmp_path):
    """`--set policy_kwargs=...` and the YAML key once went through eval()."""
    from stepdamp_agents.train import parse_policy_kwargs

    out = parse_policy_kwargs("dict(net_arch=[64, 64], log_std_init=-1.5, "
                              "activation_fn=nn.Tanh, extra={'a': (1, 2)})")
    assert out == {"net_arch": [64, 64], "log_std_init": -1.5,
                   "activation_fn": torch.nn.Tanh, "extra": {"a": (1, 2)}}
    assert parse_policy_kwargs("dict(activation_fn=th.nn.ReLU)")["activation_fn"] is torch.nn.ReLU
    marker = tmp_path / "ran"
    for text in (f"__import__('pathlib').Path({str(marker)!r}).touch()",
                 "dict(x=open('/etc/passwd'))", "dict(x=nn.Module.__subclasses__)",
                 "dict(x=nn.functional)", "[1, 2]"):
        with pytest.raises(ValueError, match="policy_kwargs"):
            parse_policy_kwargs(text)
    assert not marker.exists()
