"""Scale: the batched episode runner, resumable leaderboards, the identification cache.

The batched runner must give every run exactly what the scalar runner gives
(bit for bit, every baseline and reference agent); a leaderboard interrupted and
started again must give the numbers of an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np
import pytest

from stepdamp_agents import reference_agent, reference_names
from stepdamp_baselines import BASELINE_NAMES
from stepdamp_env import kernel as K
from stepdamp_env.bench import (EpisodeSpec, ScalarPolicies, quick_protocol_v1, protocol_motors,
                                run_episode, run_episodes, run_leaderboard)
from stepdamp_env.bench.leaderboard import RESUME_DIR, identify_cached, protocol_knowledge
from stepdamp_env.bench.registry import resolve_policy
from stepdamp_env.env import StepperDampEnv
from stepdamp_env.env.engine import StepperDampBatch
from stepdamp_env.identify import identify
from stepdamp_env.parallel import pool_map
from stepdamp_env.simulation import merge_accumulator_rows, merge_accumulators

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

def _kept(resume: str) -> list[str]:
    """The batch files in a resume directory (its hidden marker left out)."""
    return sorted(n for n in os.listdir(resume) if not n.startswith("."))


@pytest.fixture(scope="module")
def specs():
    """Per suite: two motors (a preset and a drawn one) at three speeds, with their
    identified models: runs that end at different steps."""
    protocol = quick_protocol_v1()
    motors = protocol_motors(protocol)
    chosen = [motors[0], motors[-1]]
    out = {}
    for suite in protocol.suites:
        rows = []
        for m in chosen:
            seed = protocol.eval_seeds[0]
            model = identify(m.system, method=protocol.identification_method,
                             noise_seed=seed).model
            knowledge = protocol_knowledge(m, seed, model, protocol)
            for v in m.speeds(suite).speeds_rps[:3]:
                rows.append(EpisodeSpec(knowledge, m.system, v, seed, m.settle_s(suite)))
        out[suite] = rows
    return protocol, out


def _scalar(make, specs, suite, protocol):
    return [run_episode(make(), s.knowledge, s.system, mode=suite, speed_rps=s.speed_rps,
                        seed=s.seed, accel_rps2=protocol.accel_rps2, window_s=protocol.window_s,
                        settle_s=s.settle_s, measure_from_s=s.measure_from_s,
                        until_s=s.until_s).to_dict() for s in specs]


def _batched(make, specs, suite, protocol):
    return [r.to_dict() for r in run_episodes(make, specs, mode=suite,
                                              accel_rps2=protocol.accel_rps2,
                                              window_s=protocol.window_s)]


@pytest.mark.parametrize("name", BASELINE_NAMES)
def test_batched_runner_equals_scalar_runner_for_every_baseline(name, specs):
    protocol, by_suite = specs
    make = resolve_policy(name).make
    for suite, rows in by_suite.items():
        assert _batched(make, rows, suite, protocol) == _scalar(make, rows, suite, protocol), \
            (name, suite)


@pytest.mark.parametrize("name", reference_names())
def test_batched_runner_equals_scalar_runner_for_every_reference_agent(name, specs):
    protocol, by_suite = specs
    make = lambda: reference_agent(name)               # noqa: E731 (its first seed)
    # An agent trained for one suite runs in it where the fixture has it (v1: no mid-band).
    suites = make().card.suites or ()                      # None: every suite
    suite = suites[0] if len(suites) == 1 and suites[0] in by_suite else "open-loop"
    rows = by_suite[suite]
    assert _batched(make, rows, suite, protocol) == _scalar(make, rows, suite, protocol)


def test_batched_runner_adapts_a_scalar_policy_and_keeps_failed_runs(specs):
    """A policy without act_batch runs one instance per row; a run that loses its
    steps ends early, alone, and reads the same as the scalar one."""
    protocol, by_suite = specs

    class Shaker:
        """Pushes with three times the holding current on the fastest speeds only."""
        name = "shaker"

        def env_options(self, knowledge):
            return {"base_controller": "none", "action_mode": "current",
                    "current_scale_a": 3 * knowledge.nominal.drive.holding_current}

        def reset(self, context):
            self._k, self._push = 0, context.speed_rps > 2.0

        def act(self, observation):
            self._k += 1
            push = self._push and self._k > 5
            return np.array([1.0 if push else 0.0], dtype=np.float32)

    assert not hasattr(Shaker(), "act_batch")
    rows = by_suite["open-loop"]
    scalar = _scalar(Shaker, rows, "open-loop", protocol)
    assert any(r["failed"] for r in scalar) and not all(r["failed"] for r in scalar)
    assert _batched(Shaker, rows, "open-loop", protocol) == scalar
    assert isinstance(ScalarPolicies(Shaker), ScalarPolicies)


def test_merge_accumulator_rows_is_merge_accumulators_row_by_row():
    rng = np.random.default_rng(3)
    total = rng.normal(size=(6, len(K.ACC)))
    part = rng.normal(size=(6, len(K.ACC)))
    total[:, K.ACC.COUNT] = [0, 3, 2, 0, 5, 1]
    part[:, K.ACC.COUNT] = [0, 0, 4, 2, 1, 1]
    part[5, K.ACC.MIN_E] = np.nan                      # Python's min keeps the first
    expected = total.copy()
    for t, p in zip(expected, part):
        merge_accumulators(t, p)
    merge_accumulator_rows(total, part)
    assert np.array_equal(total, expected, equal_nan=True)


def test_batch_refuses_envs_of_two_layouts():
    a = StepperDampEnv(motor="patent", speed_rps=0.5, measure_from_s=0.1)
    b = StepperDampEnv(motor="patent", speed_rps=0.5, measure_from_s=0.1, action_mode="current")
    a.reset(seed=0)
    b.reset(seed=0)
    with pytest.raises(ValueError, match="one layout"):
        StepperDampBatch([a, b])


def test_a_batch_of_tasks_is_the_batch_of_their_reset_envs():
    from stepdamp_env.env import StepperDampV1Env

    kinds = [(StepperDampEnv, dict(motor="patent", speed_rps=0.5, measure_from_s=0.1)),
             (StepperDampEnv, dict(motor="qsh4218-51-10-049", speed_rps=2.0,
                                   measure_from_s=0.05, mode="servo")),
             (StepperDampV1Env, dict(motor="patent", speed_rps=0.7, measure_from_s=0.1,
                                     agent_hz=100, history=4, context="visible")),
             (StepperDampV1Env, dict(motor="qsh5718-56-28-126", nominal="patent", speed_rps=1.1,
                                     measure_from_s=0.1, agent_hz=100, history=4,
                                     context="visible", base_controller="ff-delay-comp"))]
    for version in (StepperDampEnv, StepperDampV1Env):
        options = [o for cls, o in kinds if cls is version]
        envs = [version(**o) for o in options]
        for seed, env in enumerate(envs):
            env.reset(seed=seed + 7)
        want = StepperDampBatch(envs)
        got = StepperDampBatch.of_tasks([version.task_of(**o) for o in options], [7, 8])
        for _ in range(130 if version is StepperDampEnv else 15):     # past 0.1 s
            actions = np.full((2, envs[0].action_space.shape[0]), 0.25, dtype=np.float32)
            for name in ("obs", "time_s", "speeds_rps"):
                assert np.array_equal(getattr(got, name), getattr(want, name))
            for a, b in zip(got.step(actions), want.step(actions)):
                assert np.array_equal(a, b)
        for i in (0, 1):
            assert (json.dumps(got.run_metrics(i).to_dict(), sort_keys=True)
                    == json.dumps(want.run_metrics(i).to_dict(), sort_keys=True))
    with pytest.raises(ValueError, match="one layout"):
        StepperDampBatch.of_tasks([StepperDampEnv.task_of(**o) for _, o in kinds[:1]]
                                  + [StepperDampEnv.task_of(**kinds[0][1], action_mode="current")],
                                  [0, 0])
    with pytest.raises(ValueError, match="measure_from_s"):
        StepperDampBatch.of_tasks([StepperDampEnv.task_of(motor="patent")], [0])
    with pytest.raises(ValueError, match="one seed per task"):
        StepperDampBatch.of_tasks([StepperDampEnv.task_of(**kinds[0][1])], [0, 1])


def test_predict_rows_is_sb3_predict_to_float32_and_the_same_for_any_batch():
    """The learned entries are evaluated by the fixed-order network (fixednet.mlp_forward):
    it agrees with SB3's torch predict to float32 rounding, and its rows do not
    depend on how they are batched."""
    from stepdamp_agents.policy import load_model
    from stepdamp_env.bench.network import policy_network, predict_rows
    from stepdamp_agents import reference_seeds

    for name in reference_names():
        model = load_model(next(iter(reference_seeds(name).values())))
        assert policy_network(model.policy) is not None, name
        d = model.observation_space.shape[0]
        x = np.random.default_rng(0).normal(size=(40, d)).astype(np.float32)
        torch_rows = np.stack([model.predict(row, deterministic=True)[0] for row in x])
        rows = predict_rows(model, x)
        assert rows.dtype == np.float32 and rows.shape == torch_rows.shape, name
        np.testing.assert_allclose(rows, torch_rows, rtol=0, atol=2e-6, err_msg=name)
        one_by_one = np.concatenate([predict_rows(model, x[k:k + 1]) for k in range(len(x))])
        assert np.array_equal(rows, one_by_one), name


# -- resume -------------------------------------------------------------------------
def _tiny():
    protocol = quick_protocol_v1()
    motors = protocol_motors(protocol)
    return protocol.with_custom_motors([motors[0].system]).with_suites(("open-loop",))


def _numbers(board):
    return json.dumps({k: board[k] for k in ("protocol", "entries", "identification")},
                      sort_keys=True)


class _Interrupt(Exception):
    pass


def test_an_interrupted_leaderboard_resumes_to_the_same_numbers(tmp_path):
    protocol = _tiny()
    policies = ["ff-delay-comp", "velocity-feedback", "tuned-constant-gain"]
    whole = run_leaderboard(protocol, policies, workers=1, progress=False)

    calls = {"batches": 0}

    def dies_after_two(fn, jobs, workers, **kw):
        if fn.__name__ != "_run_batch":
            return pool_map(fn, jobs, workers, **kw)

        def counted(item):
            if calls["batches"] == 2:
                raise _Interrupt
            calls["batches"] += 1
            return fn(item)
        return pool_map(counted, jobs, 1, **kw)

    resume = str(tmp_path / RESUME_DIR)
    with pytest.raises(_Interrupt):
        run_leaderboard(protocol, policies, workers=1, progress=False, resume_dir=resume,
                        backend=dies_after_two)
    assert len(_kept(resume)) == 2

    ran = []

    def records(fn, jobs, workers, **kw):
        if fn.__name__ == "_run_batch":
            ran.extend(jobs)
        return pool_map(fn, jobs, workers, **kw)

    resumed = run_leaderboard(protocol, policies, workers=1, progress=False, resume_dir=resume,
                              backend=records)
    assert _numbers(resumed) == _numbers(whole)
    assert len(ran) == len(_kept(resume)) - 2      # the two kept batches were not rerun


def test_a_changed_protocol_does_not_reuse_kept_batches(tmp_path):
    protocol = _tiny()
    resume = str(tmp_path / RESUME_DIR)
    run_leaderboard(protocol, ["ff-delay-comp"], workers=1, progress=False, resume_dir=resume)
    first = set(_kept(resume))
    other = dataclasses.replace(protocol, window_s=protocol.window_s * 2)
    run_leaderboard(other, ["ff-delay-comp"], workers=1, progress=False, resume_dir=resume)
    assert not first & set(_kept(resume))


def test_leaderboard_command_keeps_batches_until_done(tmp_path):
    from stepdamp_env.cli import main

    out = tmp_path / "board"
    args = ["leaderboard", "--quick", "--protocol", "v1", "--entries", "ff-delay-comp",
            "--suite", "open-loop", "--workers", "1", "--no-progress", "--no-plots",
            "--out", str(out)]
    os.makedirs(out / RESUME_DIR)
    (out / RESUME_DIR / f"{'0' * 16}-{'0' * 24}.json").write_text("[]")   # another run's
    assert main(args) == 0
    assert (out / "leaderboard.json").is_file()
    assert not (out / RESUME_DIR).exists()                  # gone with the finished run


# -- identification cache -----------------------------------------------------------
def test_identification_is_cached_per_motor_seed_and_version(tmp_path, monkeypatch):
    monkeypatch.setenv("STEPDAMP_CACHE_DIR", str(tmp_path))
    system = protocol_motors(_tiny())[0].system
    first = identify_cached(system, "iterative", 7)
    assert first == identify(system, method="iterative", noise_seed=7).model
    assert len(os.listdir(tmp_path / "identify")) == 1
    assert identify_cached(system, "iterative", 7) == first      # read back, exactly
    identify_cached(system, "iterative", 8)
    assert len(os.listdir(tmp_path / "identify")) == 2
    monkeypatch.setenv("STEPDAMP_CACHE_DIR", "off")
    assert identify_cached(system, "iterative", 7) == first


@pytest.mark.parametrize("name", ["adaptive-ff", "repetitive-control", "velocity-feedback",
                                  "sensorless-damping"])
def test_batched_filters_equal_scalar_filters_over_long_synthetic_runs(name, specs):
    """The vectorised filters against their scalar selves on 4000 steps of a
    synthetic ripple (every adaptation, period completion and guard path),
    action by action, with rows leaving the batch on the way."""
    from stepdamp_env.bench import policy_context, policy_env_options
    from stepdamp_env.env.layout import HARMONIC_COS, HARMONIC_SIN, OBS

    protocol, by_suite = specs
    rows = by_suite["open-loop"]
    make = resolve_policy(name).make
    probe = make()
    contexts = []
    for s in rows:
        options = policy_env_options(probe, s.knowledge)
        contexts.append(policy_context(options, s.knowledge, "open-loop", s.speed_rps,
                                       protocol.accel_rps2))
    dim = StepperDampEnv(action_mode=policy_env_options(probe, rows[0].knowledge)
                         ["action_mode"]).observation_space.shape[0]
    rng = np.random.default_rng(5)
    n, steps = len(rows), 4000
    rate = rng.uniform(0.02, 0.3, n)            # electrical angle per step (rad)
    gain = rng.uniform(0.02, 3.0, n)            # ripple size, up to divergence
    scalar = [make() for _ in rows]
    for policy, context in zip(scalar, contexts):
        policy.reset(context)
    batch = make()
    batch.reset_batch(contexts)
    live = np.arange(n)
    seen = set()
    for t in range(steps):
        x = rate * t
        obs = np.zeros((n, dim), dtype=np.float32)
        obs[:, HARMONIC_SIN] = np.stack([np.sin(x), np.sin(2 * x), np.sin(4 * x)], 1)
        obs[:, HARMONIC_COS] = np.stack([np.cos(x), np.cos(2 * x), np.cos(4 * x)], 1)
        obs[:, OBS.velocity_error] = (gain * np.sin(x + 0.4) * (1 + t / steps)
                                      + 0.01 * rng.normal(size=n))
        obs[:, OBS.position_error] = 0.1 * np.cos(x) + 0.01 * rng.normal(size=n)
        got = batch.act_batch(obs[live], live)
        want = np.stack([np.asarray(scalar[i].act(obs[i])) for i in live])
        assert np.array_equal(got, want), (name, t)
        seen.update(row.tobytes() for row in got)
        if t in (1000, 2500):                    # rows end at different steps
            live = live[1:]
    assert len(seen) > 20                        # the filters did adapt the action


@pytest.mark.parametrize("name", ["adaptive-ff", "velocity-feedback", "calibrated-table"])
def test_runs_of_two_layouts_go_in_two_batches(name, specs):
    """A motor with another PWM rate (another number of periods per step) runs in
    a batch of its own, and every run still equals its scalar run."""
    from stepdamp_env.motorfile import load_system

    protocol, by_suite = specs
    rows = by_suite["open-loop"][:3]
    slow = load_system("patent", {"pwm_hz": 16000.0})
    mixed = [rows[0], dataclasses.replace(rows[1], system=slow), rows[2],
             dataclasses.replace(rows[0], system=slow)]
    make = resolve_policy(name).make
    assert _batched(make, mixed, "open-loop", protocol) == \
        _scalar(make, mixed, "open-loop", protocol)


def test_backend_mistakes_are_one_line_errors(tmp_path, monkeypatch, capsys):
    import sys

    from stepdamp_env.cli import main

    sweep = ["sweep", "--speeds", "0.5:0.5:0.1", "--out", str(tmp_path / "s"), "--no-progress"]
    assert main(sweep + ["--ray-address", "auto"]) == 2
    assert "--ray-address needs --backend ray" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "ray", None)          # Ray not installed
    assert main(sweep + ["--backend", "ray"]) == 2
    err = capsys.readouterr().err.strip()
    assert "pip install" in err and "[ray]" in err and len(err.splitlines()) == 1


def test_kept_batches_of_a_changed_policy_file_are_not_reused(tmp_path):
    policy_file = tmp_path / "my_policy.py"
    source = open(os.path.join(ROOT, "tests", "leaderboard_policy.py")).read()
    policy_file.write_text(source)
    spec = f"{policy_file}:NominalFeedforward"
    resume = str(tmp_path / RESUME_DIR)
    run_leaderboard(_tiny(), [spec], workers=1, progress=False, resume_dir=resume)
    first = set(_kept(resume))
    policy_file.write_text(source + "\n# changed\n")
    run_leaderboard(_tiny(), [spec], workers=1, progress=False, resume_dir=resume)
    assert first and not first & set(_kept(resume))


def test_a_subclass_that_changes_act_alone_runs_per_row():
    from stepdamp_baselines import VelocityFeedback
    from stepdamp_env.bench.policy import batch_policy

    class Louder(VelocityFeedback):
        def act(self, observation):
            return np.clip(2.0 * super().act(observation), -1.0, 1.0)

    assert isinstance(batch_policy(Louder), ScalarPolicies)
    assert isinstance(batch_policy(VelocityFeedback), VelocityFeedback)


def test_a_run_that_ends_at_its_start_takes_no_step(specs):
    protocol, by_suite = specs
    rows = [dataclasses.replace(s, until_s=0.0) for s in by_suite["open-loop"][:2]]
    make = resolve_policy("ff-delay-comp").make
    got = _batched(make, rows, "open-loop", protocol)
    assert got == _scalar(make, rows, "open-loop", protocol)
    assert [r["steps"] for r in got] == [0, 0]


def test_batched_runner_equals_scalar_runner_for_a_recurrent_agent(specs, tmp_path):
    """An LSTM policy (random weights, so that it acts) keeps one memory per run:
    the batched runner, whose runs end at different steps, gives the scalar runs."""
    import json

    import torch

    from stepdamp_agents import agent_from_path
    from stepdamp_agents.per_step import ALGOS, make_training_env, task_options

    env = make_training_env(("patent",), 2, 0, task_options({"episode_s": 0.1}))
    model = ALGOS["ppo_lstm"]("ResidualLstmPolicy", env, seed=1, device="cpu", n_steps=8,
                              batch_size=16, policy_kwargs={"lstm_hidden_size": 8,
                                                            "net_arch": [16]})
    with torch.no_grad():
        for p in model.policy.parameters():
            p.copy_(torch.as_tensor(np.random.default_rng(7).normal(0, 0.2, p.shape)))
    path = str(tmp_path / "lstm.zip")
    model.save(path)
    options = {k: v for k, v in task_options().items()
               if k in ("action_mode", "agent_hz", "history", "context")}
    with open(tmp_path / "lstm.agent.json", "w") as fh:
        json.dump({"name": "ppo_lstm-per-step", "algo": "ppo_lstm", "env_id": "StepperDamp-v1",
                   "estimate": "identified", "env_options": options,
                   "training": {"seed": 1}}, fh)
    make = lambda: agent_from_path(path)               # noqa: E731
    assert make().network is not None
    protocol, by_suite = specs
    rows = by_suite["open-loop"]
    assert _batched(make, rows, "open-loop", protocol) == _scalar(make, rows, "open-loop",
                                                                  protocol)
