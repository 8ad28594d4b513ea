"""Per-step agents on StepperDamp-v1: the zero residual, the runner's v1 path,
multi-seed training end to end, reloading and deterministic evaluation."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from stepdamp_env.bench import MotorKnowledge, run_episode
from stepdamp_env.env import StepperDampV1Env
from stepdamp_env.params import FeedforwardModel, ParameterError
from stepdamp_env.motorfile import load_system

pytest.importorskip("sb3_contrib")

from stepdamp_agents import agent_from_path  # noqa: E402
from stepdamp_agents.per_step import (ALGOS, REFERENCE_TASK, SameEpisodes, StepAgent,  # noqa: E402
                                      make_training_env, task_options)
from stepdamp_agents.train import Args, parse_seeds, train_seeds  # noqa: E402

MOTORS = ("patent", "qsh4218-51-10-049")
SHORT = {"episode_s": 0.1}


class ZeroV1:
    """ff-delay-comp inside StepperDamp-v1 with a zero action (the base alone)."""

    name = "zero-v1"
    env_id = "StepperDamp-v1"

    def env_options(self, knowledge):
        return {"base_controller": "ff-delay-comp", "estimate": knowledge.identified,
                "action_mode": "damping-gains", "agent_hz": 100.0, "history": 4,
                "context": "visible"}

    def reset(self, context):
        pass

    def act(self, observation):
        return np.zeros(8, dtype=np.float32)


def _knowledge(system, nominal):
    exact = FeedforwardModel.from_motor(system.motor)
    return MotorKnowledge(nominal=nominal, identified=exact, exact=exact)


def _plant():
    nominal = load_system("patent", {"current_noise_a": 0.01, "encoder_cpr": 4000})
    m = nominal.motor
    return nominal.replace(J=1.3 * m.J, Kd2=1.2 * m.Kd2, name="patent~test"), nominal


def _run(policy, system, nominal, speed=0.5):
    return run_episode(policy, _knowledge(system, nominal), system, mode="open-loop",
                       speed_rps=speed, seed=1_000_000, window_s=0.1, settle_s=0.1)


def test_nominal_option_sets_units_and_scales_not_the_plant():
    plant, nominal = _plant()
    env = StepperDampV1Env(motor=plant, nominal=nominal)
    own = StepperDampV1Env(motor=plant)
    ref = StepperDampV1Env(motor=nominal)
    assert env.task.units == ref.task.units != own.task.units
    assert env.task.action_scales == ref.task.action_scales
    env.reset(seed=3)
    assert env.system is plant
    with pytest.raises(ParameterError, match="nominal"):
        StepperDampV1Env(nominal=3.0)
    with pytest.raises(ParameterError, match="^nominal='nosuch'"):
        StepperDampV1Env(nominal="nosuch")


def test_v1_runner_zero_action_is_ff_delay_comp():
    """The runner's v1 path on the true plant with the drive's nominal model: a
    zero action is the ff-delay-comp baseline (v0 env, its harmonic actions as
    float32) to 1e-4 relative, and the scalar v1 run is deterministic."""
    from stepdamp_baselines import make_baseline

    plant, nominal = _plant()
    a = _run(ZeroV1(), plant, nominal)
    b = _run(ZeroV1(), plant, nominal)
    assert a.to_dict() == b.to_dict()
    ff = _run(make_baseline("ff-delay-comp"), plant, nominal)
    x, y = (r.metrics["rms_velocity_error_rad_s"] for r in (a, ff))
    assert abs(x - y) <= 2e-3 * y
    assert a.simulated_s >= a.window_start_s + a.window_s - 1e-3


def test_v1_runner_pwm_trace_records_every_period_and_changes_nothing():
    """With ``pwm_trace`` the v1 path hands ``on_step`` every PWM period of each
    step (contiguous in time, one period apart) and scores the run the same."""
    from stepdamp_env import kernel as K

    plant, nominal = _plant()
    knowledge = _knowledge(plant, nominal)

    def grab(env, obs, start):
        return env.step_trace

    def run(trace):
        return run_episode(ZeroV1(), knowledge, plant, mode="open-loop", speed_rps=0.5,
                           seed=1_000_000, window_s=0.1, settle_s=0.1, on_step=grab,
                           pwm_trace=trace)

    plain, traced = run(False), run(True)
    assert plain.to_dict() == traced.to_dict()
    assert all(t.shape[0] == 0 for t in plain.trace)
    rows = np.concatenate(traced.trace)
    period = 1.0 / plant.drive.pwm_hz
    assert rows.shape[0] == traced.steps * round(0.01 / period)
    assert np.allclose(np.diff(rows[:, K.TRACE.T]), period, rtol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["ars", "ppo", "ppo_lstm", "sac", "td3"])
def test_zero_residual_reproduces_the_base_bit_for_bit(tmp_path, algo):
    """A fresh model of every algorithm acts exactly 0 and its leaderboard policy
    gives the base controller's run bit for bit."""
    env = make_training_env(MOTORS, 2, 0, task_options(SHORT))
    kwargs = {"ars": {"n_delta": 2}, "ppo": {"n_steps": 8, "batch_size": 16},
              "ppo_lstm": {"n_steps": 8, "batch_size": 16},
              "sac": {"learning_starts": 0}, "td3": {"learning_starts": 0}}[algo]
    policy = {"ars": "LinearPolicy", "ppo_lstm": "ResidualLstmPolicy"}.get(algo,
                                                                            "ResidualMlpPolicy")
    model = ALGOS[algo](policy, env, seed=1, device="cpu", **kwargs)
    obs = env.reset()
    act, _ = model.predict(obs, deterministic=True)
    assert np.all(act == 0.0)
    path = str(tmp_path / f"{algo}.zip")
    model.save(path)
    options = {k: v for k, v in task_options().items()
               if k in ("action_mode", "agent_hz", "history", "context")}
    with open(tmp_path / f"{algo}.agent.json", "w") as fh:
        json.dump({"name": f"{algo}-per-step", "algo": algo, "env_id": "StepperDamp-v1",
                   "estimate": "identified", "env_options": options,
                   "training": {"seed": 1}}, fh)
    agent = agent_from_path(path)
    assert isinstance(agent, StepAgent) and agent.card.learned
    plant, nominal = _plant()
    assert _run(agent, plant, nominal).to_dict() == _run(ZeroV1(), plant, nominal).to_dict()


def test_same_episodes_replays_a_block_of_resets():
    env = SameEpisodes(make_training_env(MOTORS, 2, 100, task_options(SHORT)), 100, span=8)
    a, b = env.reset(), env.reset()
    env.start_block(1)
    c = env.reset()
    env.start_block(2)                  # span 8 = two blocks of 4 drives: block 2 is block 0
    d = env.reset()
    assert np.array_equal(a, b) and not np.array_equal(a, c) and np.array_equal(a, d)
    with pytest.raises(ParameterError, match="training seeds"):
        make_training_env(MOTORS, 2, 999_999, task_options(SHORT))


def test_ars_candidates_of_one_update_meet_the_same_episodes():
    """Every reset within an ARS update starts the same episodes (also the first
    update, after the reset learn() does before it); updates differ."""
    seen: list[tuple[int, bytes]] = []

    class Spy(SameEpisodes):
        def reset(self):
            obs = super().reset()
            seen.append((self.block, obs.tobytes()))
            return obs

    env = Spy(make_training_env(MOTORS, 2, 0, task_options(SHORT)), 0, span=64)
    model = ALGOS["ars"]("LinearPolicy", env, n_delta=2, n_eval_episodes=4, seed=1)
    model.learn(total_timesteps=2 * 4 * 4 * 10)
    by_update = {}
    for block, obs in seen[1:]:             # seen[0]: learn()'s own reset
        by_update.setdefault(block, set()).add(obs)
    assert len(by_update) >= 2 and all(len(v) == 1 for v in by_update.values())
    assert len(set().union(*by_update.values())) == len(by_update)


def test_task_options_and_seeds_are_checked():
    assert task_options()["action_mode"] == REFERENCE_TASK["action_mode"]
    with pytest.raises(ParameterError, match="ff-delay-comp"):
        task_options({"base_controller": "none"})
    assert parse_seeds("1-3") == (1, 2, 3) and parse_seeds("2,5") == (2, 5)
    for bad in ("a-b", "1,1", ""):
        with pytest.raises(ParameterError, match="--seeds"):
            parse_seeds(bad)
    with pytest.raises(ParameterError, match="--algo"):
        train_seeds(Args(algo="ars", env="StepperDampResidual-v0"))


@pytest.mark.slow
def test_multi_seed_training_end_to_end_reloads_deterministically(tmp_path):
    """`--seeds 1-2` trains two ARS seeds into seed1/ and seed2/; each saved model
    reloads and evaluates the same twice; the two seeds differ."""
    out = str(tmp_path / "ars")
    logs = train_seeds(Args(algo="ars", seeds=(1, 2), out=out, total_timesteps=2_000,
                            motors=MOTORS, envs_per_motor=2, eval_freq=1_000,
                            val_motors_per_preset=1, checkpoint_freq=0, progress=False,
                            tensorboard=False,
                            extra={"n_delta": 2, "n_top": 2, "env_kwargs": SHORT}))
    assert [log["config"]["training"]["seed"] for log in logs] == [1, 2]
    plant, nominal = _plant()
    results = []
    for k in (1, 2):
        path = os.path.join(out, f"seed{k}", "final.zip")
        assert os.path.isfile(path) and os.path.isfile(os.path.join(out, f"seed{k}", "best.zip"))
        runs = [_run(agent_from_path(path), plant, nominal).to_dict() for _ in range(2)]
        assert runs[0] == runs[1]
        results.append(runs[0])
        assert logs[k - 1]["evaluations"][0]["step"] == 0
    assert results[0] != results[1]
    # The run directory is one leaderboard entry pooling the seeds' best.zip.
    from stepdamp_env.bench.registry import resolve_policy

    source = resolve_policy(out)
    assert source.name == "ars-per-step@ars"
    assert sorted(source.training_seeds) == [1, 2]
    assert source.training_seeds[2]().path == os.path.join(out, "seed2", "best.zip")


def test_ars_start_action_is_the_policy_at_step_zero():
    """``start_action`` puts a constant law into ARS's bias: the fresh policy acts
    it on any observation; anything but ARS with a bias, or a wrong action, is a
    one-line error naming it."""
    from stepdamp_agents.train import set_start_action

    env = make_training_env(MOTORS, 1, 0, task_options(SHORT))
    model = ALGOS["ars"]("LinearPolicy", env, policy_kwargs={"with_bias": True}, n_delta=2,
                         n_top=2, seed=1, device="cpu")
    start = [0.5, 0, 0, 0, 0, 0, 0, 0]
    set_start_action(model, start, "ars")
    obs = env.reset()
    a, _ = model.predict(obs, deterministic=True)
    assert np.allclose(a, np.tile(start, (len(obs), 1)))
    assert model.weights.count_nonzero() == 1
    for bad in ([0.5], [2.0] + [0] * 7, "x"):
        with pytest.raises(ParameterError, match="^hyperparameter start_action"):
            set_start_action(model, bad, "ars")
    with pytest.raises(ParameterError, match="^hyperparameter start_action"):
        set_start_action(model, start, "ppo")


@pytest.mark.skipif(__import__("numba").config.NUMBA_NUM_THREADS < 2, reason="one numba thread")
def test_training_on_two_threads_gives_the_same_model_and_writes_training_json(tmp_path):
    import zipfile

    from stepdamp_agents.train import train

    weights = []
    for threads in (1, 2):
        out = str(tmp_path / f"t{threads}")
        train(Args(algo="ppo", out=out, total_timesteps=512, motors=MOTORS, envs_per_motor=2,
                   eval_freq=0, checkpoint_freq=0, progress=False, tensorboard=False,
                   num_threads=threads, extra={"n_steps": 64, "batch_size": 64, "n_epochs": 1,
                                           "env_kwargs": SHORT}))
        with zipfile.ZipFile(os.path.join(out, "final.zip")) as z:
            weights.append(z.read("policy.pth"))
        with open(os.path.join(out, "training.json"), encoding="utf-8") as fh:
            record = json.load(fh)
        assert record["num_threads"] == threads and record["env_steps"] >= 512
        assert record["simulated_seconds"] == pytest.approx(
            record["env_steps"] * record["seconds_per_env_step"])
        assert record["wall_seconds"] > 0
    assert weights[0] == weights[1]
    for bad in (0, 4096):
        with pytest.raises(ParameterError, match=r"^--num-threads .*: allowed are the integers"):
            train(Args(algo="ppo", out=str(tmp_path / "x"), num_threads=bad, progress=False))


def test_recurrent_policy_acts_through_its_memory_as_torch_does(tmp_path):
    """A trained LSTM policy's deterministic actions through the package's
    network (memory per run, any batch) equal torch's to float32 rounding over
    whole episodes, are bit-identical between a batch and its runs one by one,
    and depend on the memory (the same observation after different pasts)."""
    import torch

    env = make_training_env(MOTORS, 2, 0, task_options(SHORT))
    model = ALGOS["ppo_lstm"]("ResidualLstmPolicy", env, seed=1, device="cpu", n_steps=8,
                              batch_size=16, policy_kwargs={"lstm_hidden_size": 8,
                                                            "net_arch": [16]})
    with torch.no_grad():                       # a policy that acts, as after training
        for p in model.policy.parameters():
            p.copy_(torch.as_tensor(np.random.default_rng(3).normal(0, 0.3, p.shape)))
    from stepdamp_env.bench.network import recurrent_network

    network = recurrent_network(model.policy)
    assert network is not None
    rng = np.random.default_rng(4)
    obs = rng.uniform(-2, 2, size=(12, 4, env.observation_space.shape[0])).astype(np.float32)
    memory, state = network.initial_state(4), None
    starts = np.ones(4)
    for x in obs:
        want, state = model.predict(x, state=state, episode_start=starts, deterministic=True)
        starts = np.zeros(4)
        got = np.clip(network.step(x, memory, np.arange(4)), -1, 1)
        assert np.allclose(got, want, rtol=1e-4, atol=1e-5)
    alone = network.initial_state(4)
    for x in obs:
        for r in (2, 0, 3, 1):
            network.step(x[r:r + 1], alone, np.array([r]))
    assert np.array_equal(alone[0], memory[0]) and np.array_equal(alone[1], memory[1])
    again = network.initial_state(1)
    first = network.step(obs[0][:1], again, np.array([0]))
    second = network.step(obs[0][:1], again, np.array([0]))
    assert not np.array_equal(first, second)


def test_recurrent_network_refuses_what_it_cannot_read_and_bad_calls():
    """Two LSTM layers are refused with a one-line error; so are observations and
    rows that do not match, and a recurrent model in predict_rows (no memory)."""
    from stepdamp_env.bench.network import predict_rows, recurrent_network

    env = make_training_env(MOTORS, 2, 0, task_options(SHORT))
    deep = ALGOS["ppo_lstm"]("ResidualLstmPolicy", env, seed=1, device="cpu", n_steps=8,
                             batch_size=16, policy_kwargs={"n_lstm_layers": 2,
                                                           "lstm_hidden_size": 4})
    with pytest.raises(ValueError, match="^lstm: only a plain one-layer LSTM"):
        recurrent_network(deep.policy)
    model = ALGOS["ppo_lstm"]("ResidualLstmPolicy", env, seed=1, device="cpu", n_steps=8,
                              batch_size=16, policy_kwargs={"lstm_hidden_size": 4})
    network = recurrent_network(model.policy)
    memory = network.initial_state(2)
    obs = np.zeros((2, env.observation_space.shape[0]), dtype=np.float32)
    with pytest.raises(ValueError, match="^observations: shape"):
        network.step(obs, memory, np.array([0]))
    with pytest.raises(ValueError, match="^rows: distinct"):
        network.step(obs, memory, np.array([0, 2]))
    with pytest.raises(ValueError, match="^rows: distinct"):
        network.step(obs, memory, np.array([1, 1]))
    with pytest.raises(ValueError, match="^model: .* is recurrent"):
        predict_rows(model, obs)
    memory[0][:] = 1.0
    fresh = network.initial_state(2)            # what a new reset_batch starts from
    assert not fresh[0].any() and not fresh[1].any()


@pytest.mark.slow
def test_validations_change_no_model_unless_they_share_the_generators(tmp_path):
    """--eval-freq once changed the model it trained (a validation loads the model,
    which draws torch's generator): isolated (the default), the validations leave
    the training's generators as they were; 'shared' keeps the old behaviour that
    the committed models were trained with."""
    import zipfile

    from stepdamp_agents.train import train

    def weights(eval_freq: int, eval_rng: str = "isolated") -> bytes:
        out = str(tmp_path / f"e{eval_freq}{eval_rng}")
        train(Args(algo="ppo", out=out, total_timesteps=512, motors=MOTORS[:1],
                   envs_per_motor=2, eval_freq=eval_freq, eval_rng=eval_rng,
                   val_motors_per_preset=1, checkpoint_freq=0, progress=False,
                   tensorboard=False, extra={"n_steps": 64, "batch_size": 64, "n_epochs": 1,
                                             "env_kwargs": SHORT}))
        with zipfile.ZipFile(os.path.join(out, "final.zip")) as z:
            return z.read("policy.pth")

    alone = weights(0)
    assert weights(256) == alone
    assert weights(256, "shared") != alone
    with pytest.raises(ParameterError, match="--eval-rng"):
        train(Args(algo="ppo", out=str(tmp_path / "x"), eval_rng="both", progress=False))
