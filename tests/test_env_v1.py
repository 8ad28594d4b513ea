"""StepperDamp-v1: API conformance, scalar/vector agreement, units, reward, the damping law."""

from __future__ import annotations

import math
import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import stepdamp_env  # noqa: F401  (registers the envs)
from stepdamp_env import kernel as K
from stepdamp_env.env import (ENV_ID_V1, EnvOptionsV1, MotorUnits, StepperDampEnv,
                              StepperDampV1Env, StepperDampV1VectorEnv, observation_names_v1)
from stepdamp_env.params import ParameterError
from stepdamp_env.motorfile import load_system
from stepdamp_env.response import current_path, velocity_filter
from stepdamp_env.simulation import RunSettings, SpeedProfile, build_config, initial_state

V1_OPTION_SETS = [
    {},
    {"action_mode": "harmonic", "history": 3, "context": "visible", "privileged": True},
    {"action_mode": "current", "mode": "servo", "randomize": True, "estimate": "nominal",
     "base_controller": "patent-ff"},
    {"action_mode": "harmonic+current", "base_controller": "none", "velocity_estimator": "kalman",
     "motor": "qsh4218-51-10-049", "agent_hz": 500.0},
]


@pytest.mark.parametrize("env_id", [ENV_ID_V1, "StepperDamp-v2"])
def test_v1_is_registered_with_both_entry_points_and_no_outer_time_limit(env_id):
    spec = gym.spec(env_id)
    assert spec.vector_entry_point is not None and spec.max_episode_steps is None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make(env_id)
        venv = gym.make_vec(env_id, num_envs=3)
    # Gymnasium's only note: there is a newer version (v3).
    notes = {str(w.message) for w in caught}
    assert notes and all("is out of date" in n and "`v3`" in n for n in notes), notes
    assert isinstance(env.unwrapped, StepperDampV1Env)
    assert isinstance(venv, StepperDampV1VectorEnv)


def test_v2_passes_the_env_checkers_and_warns_on_the_benchmarks_seeds():
    from stepdamp_env.env import StepperDampV2Env, StepperDampV2VectorEnv

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=".*StepperDamp-v2 is out of date")
        gym_check_env(gym.make("StepperDamp-v2").unwrapped)
        sb3_check_env(StepperDampV2Env(), warn=True)
        StepperDampV2Env().reset(seed=999_999)
        StepperDampV2VectorEnv(2).reset(seed=[1, 999_999])
    with pytest.warns(UserWarning, match="seeds from 1,000,000 draw the motors"):
        StepperDampV2Env().reset(seed=1_000_000)
    with pytest.warns(UserWarning, match="seed 1000001"):
        StepperDampV2VectorEnv(2).reset(seed=[1, 1_000_001])
    with pytest.warns(UserWarning, match="seed 2000000"):
        StepperDampV2VectorEnv(2).reset(seed=2_000_000)


def test_v2_is_v1_with_the_agents_task_as_defaults():
    from stepdamp_agents.task import REFERENCE_TASK

    env = gym.make("StepperDamp-v2")
    assert env.unwrapped.options == StepperDampV1Env(**REFERENCE_TASK).options
    assert env.unwrapped.options.agent_hz == 100.0 and env.observation_space.shape == (36,)
    with pytest.raises(ValueError, match="unknown option.*for StepperDamp-v2"):
        gym.make("StepperDamp-v2", no_such_option=1)
    # A given option replaces its default; the others stay.
    assert gym.make("StepperDamp-v2", agent_hz=50.0).unwrapped.options.history == 4
    a, b = gym.make("StepperDamp-v2"), StepperDampV1Env(**REFERENCE_TASK)
    oa, ob = a.reset(seed=5)[0], b.reset(seed=5)[0]
    np.testing.assert_array_equal(oa, ob)
    action = np.full(8, 0.3, dtype=np.float32)
    for _ in range(3):
        sa, sb = a.step(action), b.step(action)
        np.testing.assert_array_equal(sa[0], sb[0])
        assert sa[1:4] == sb[1:4]


@pytest.mark.parametrize("kwargs", V1_OPTION_SETS)
def test_v1_passes_both_env_checkers_with_warnings_as_errors(kwargs):
    env = gym.make(ENV_ID_V1, **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(env.unwrapped, skip_render_check=bool(kwargs))
        sb3_check_env(StepperDampV1Env(**kwargs), warn=True)


@pytest.mark.parametrize("kwargs", V1_OPTION_SETS[:3])
def test_scalar_and_vector_v1_agree_step_for_step(kwargs):
    n, steps = 3, 60
    venv = StepperDampV1VectorEnv(n, autoreset_mode="SameStep", episode_s=0.025, **kwargs)
    envs = [StepperDampV1Env(episode_s=0.025, **kwargs) for _ in range(n)]
    vo, _ = venv.reset(seed=11)
    so = [e.reset(seed=11 + i)[0] for i, e in enumerate(envs)]
    np.testing.assert_array_equal(vo, np.stack(so))
    rng = np.random.default_rng(0)
    for _ in range(steps):
        a = rng.uniform(-0.3, 0.3, size=venv.action_space.shape).astype(np.float32)
        vo, vr, vt, vtr, info = venv.step(a)
        for i, e in enumerate(envs):
            o, r, t, tr, inf = e.step(a[i])
            assert (r, t, tr) == (vr[i], vt[i], vtr[i])
            if t or tr:
                np.testing.assert_array_equal(info["final_obs"][i], o)
                assert info["final_info"][i] == inf
                o, _ = e.reset()
            np.testing.assert_array_equal(vo[i], o)


def test_v1_time_limit_is_the_envs_own_and_it_refuses_to_step_on():
    env = StepperDampV1Env(episode_s=0.01)             # 10 steps at 1 kHz
    env.reset(seed=0)
    flags = [env.step(np.zeros(8, np.float32))[3] for _ in range(10)]
    assert flags == [False] * 9 + [True]
    with pytest.raises(gym.error.ResetNeeded, match="truncated"):
        env.step(np.zeros(8, np.float32))
    env.reset()
    env.step(np.zeros(8, np.float32))
    venv = StepperDampV1VectorEnv(2, episode_s=0.005, agent_hz=1000.0)
    venv.reset(seed=0)
    ends = [venv.step(np.zeros((2, 8), np.float32))[3].tolist() for _ in range(6)]
    assert ends[4] == [True, True] and ends[5] == [False, False]


def test_zero_gains_are_the_base_controller_alone_bit_for_bit():
    """damping-gains at 0 == current at 0 (the law adds exactly nothing)."""
    a = StepperDampV1Env(action_mode="damping-gains", randomize=True)
    b = StepperDampV1Env(action_mode="current", randomize=True)
    a.reset(seed=5)
    b.reset(seed=5)
    for _ in range(100):
        ra = a.step(np.zeros(8, np.float32))
        rb = b.step(np.zeros(1, np.float32))
        np.testing.assert_array_equal(ra[0][:11], rb[0][:11])
        assert ra[1] == rb[1]
    np.testing.assert_array_equal(a.drive_state, b.drive_state)


def test_v1_draws_the_same_episodes_as_v0():
    for seed in range(5):
        i0 = StepperDampEnv(randomize=True).reset(seed=seed)[1]
        e1 = StepperDampV1Env(randomize=True)
        i1 = e1.reset(seed=seed)[1]
        assert i0 == i1


def test_units_come_from_the_nominal_model_not_the_plant():
    env = StepperDampV1Env(randomize=True)
    u = env.task.units
    nominal = load_system("patent")
    m = nominal.motor
    k = m.Km * nominal.drive.holding_current * m.Nr
    assert u.stiffness_nm_per_rad == pytest.approx(k)
    assert u.position_unit_rad == pytest.approx(max(m.Kd1, m.Kd2, m.Kd4) / k)
    assert u.velocity_unit_rad_s == pytest.approx(math.sqrt(k / m.J) * u.position_unit_rad)
    for seed in range(3):
        env.reset(seed=seed)
        assert env.task.units == u                   # episodes differ, units do not
    # A motor without detent still has finite, positive units.
    bare = MotorUnits.of(load_system("patent", {"Kd1": 0.0, "Kd2": 0.0, "Kd4": 0.0}))
    assert bare.position_unit_rad > 0 and math.isfinite(bare.current_unit_a)


def test_observation_names_match_the_space():
    for kw in V1_OPTION_SETS:
        env = StepperDampV1Env(**kw)
        o = EnvOptionsV1(**kw)
        names = observation_names_v1(o.action_mode, o.history, o.context, o.privileged)
        assert len(names) == env.observation_space.shape[0]


def test_history_holds_the_previous_error_samples_newest_first():
    env = StepperDampV1Env(history=3)
    obs = [env.reset(seed=2)[0]]
    for _ in range(5):
        obs.append(env.step(np.zeros(8, np.float32))[0])
    h0 = 11 + 8
    for t in range(3, 6):
        for lag in (1, 2, 3):
            np.testing.assert_array_equal(obs[t][h0 + 2 * (lag - 1):h0 + 2 * lag], obs[t - lag][:2])


def test_visible_context_is_the_speed_over_the_predicted_resonances():
    env = StepperDampV1Env(context="visible", speed_rps=1.0)
    obs, _ = env.reset(seed=0)
    res = load_system("patent").predicted_resonances_rps()
    np.testing.assert_allclose(obs[19:22], [1.0 / res[h] for h in (4, 2, 1)], rtol=1e-6)


def test_context_and_infos_stay_in_their_space_and_match_the_scalar_env():
    env = StepperDampV1Env(context="visible", speed_rps=8.0)     # 12x the h = 4 resonance
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs) and obs[19] == 10.0
    venv = StepperDampV1VectorEnv(2, episode_s=0.01)
    venv.reset(seed=0)
    infos = venv.step(np.zeros((2, 8), np.float32))[4]
    env = StepperDampV1Env(episode_s=0.01)
    env.reset(seed=0)
    info = env.step(np.zeros(8, np.float32))[4]
    assert set(info) <= set(infos) and infos["time_s"][0] == info["time_s"] == 0.001


def test_termination_loses_the_worst_reward_of_every_step_left():
    # A load beyond the holding torque: the rotor slips at once.
    env = StepperDampV1Env(overrides={"load_torque": 0.9}, speed_rps=1.0, base_controller="none")
    env.reset(seed=0)
    for t in range(1, 400):
        _, r, term, trunc, info = env.step(np.zeros(8, np.float32))
        if term:
            break
    assert term and info["step_loss"]
    assert r <= -10.0 * (400 - t)
    with pytest.raises(gym.error.ResetNeeded, match="terminated"):
        env.step(np.zeros(8, np.float32))


def test_bad_v1_options_get_one_line_naming_them():
    for kw, name in [({"history": -1}, "history"), ({"context": "shown"}, "context"),
                     ({"episode_s": 0.0}, "episode_s"), ({"action_mode": "gains"}, "action_mode"),
                     ({"base_controller": "adaptive-ff"}, "base_controller"),
                     ({"damping_ratio_scale": -1}, "damping_ratio_scale"),
                     ({"episode_s": 1e-4}, "episode_s"), ({"spead_rps": 1.0}, "spead_rps"),
                     ({"speed_rps": -1.0}, "speed_rps")]:
        with pytest.raises(ParameterError, match=name) as err:
            StepperDampV1Env(**kw)
        assert "\n" not in str(err.value)
    env = StepperDampV1Env()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(np.full(8, 2.0, np.float32))


def test_v1_render_and_copies():
    env = StepperDampV1Env(render_mode="rgb_array", speed_rps=1.0)
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.zeros(8, np.float32))
    img = env.render()
    assert img.ndim == 3 and img.shape[2] == 3 and img.std() > 0
    twin = pickle.loads(pickle.dumps(env))
    a = env.step(np.full(8, 0.1, np.float32))
    b = twin.step(np.full(8, 0.1, np.float32))
    np.testing.assert_array_equal(a[0], b[0])


# -- the damping law -----------------------------------------------------------------
def _ringdown(kv_gain: float, system, n_periods: int = 4000, amplitude: float = 0.05) -> float:
    """Decay rate (1/s) of the rotor released ``amplitude`` full steps off its detent at rest."""
    settings = RunSettings(base_controller="none")
    c = build_config(system, SpeedProfile(speed_rps=1e-6), settings, window_start_s=math.inf)
    s = initial_state(c, theta0=amplitude * system.motor.full_step_rad)
    law = np.zeros(len(K.LAW))
    law[K.LAW.KV] = kv_gain
    law[K.LAW.LIMIT] = 10.0
    trace = np.zeros((n_periods, len(K.TRACE)))
    K.run_periods_law(c, s, np.zeros(len(K.ACC)), np.zeros(len(K.INPUT)), law, n_periods, trace, 1)
    t, theta = trace[:, K.TRACE.T], trace[:, K.TRACE.THETA]
    # Envelope of the oscillation: peaks of |theta| over successive half periods.
    peaks = [i for i in range(1, len(theta) - 1)
             if abs(theta[i]) >= abs(theta[i - 1]) and abs(theta[i]) > abs(theta[i + 1])]
    tp, ap = t[peaks], np.abs(theta[peaks])
    keep = ap > 0.05 * ap[0]
    return -np.polyfit(tp[keep], np.log(ap[keep]), 1)[0]


def test_velocity_feedback_adds_the_damping_linear_theory_predicts():
    """To first order in the gain, kv adds Kv*Km*Re(P)/(2J) to the decay rate of the
    rotor on its spring, P = F*G*exp(-j wn dt) at wn: the drive's velocity
    estimate F, the current path G and the law's one period of delay. (The
    undamped decay is not D/(2J): the current loop adds electrical damping.)"""
    system = load_system("patent", {"Fs": 0.0, "encoder_cpr": 1_000_000,
                                    "velocity_cutoff_hz": 2000.0})
    m = system.motor
    wn = system.natural_frequency()
    dt = 1.0 / system.drive.pwm_hz
    path = (velocity_filter(system, wn) * current_path(system, wn)
            * complex(math.cos(wn * dt), -math.sin(wn * dt)))
    base = _ringdown(0.0, system)
    added = []
    for zeta in (0.025, 0.05):
        kv = 2.0 * zeta * m.J * wn / m.Km
        predicted = kv * m.Km * path.real / (2.0 * m.J)
        added.append((_ringdown(kv, system) - base) / predicted)
    assert added[0] == pytest.approx(1.0, abs=0.1)
    assert added[1] == pytest.approx(1.0, abs=0.12)
    # A negative gain takes damping away (the sign is the law's, not the estimator's).
    assert _ringdown(-2.0 * 0.025 * m.J * wn / m.Km, system) < base


def test_resonant_gain_cancels_the_ripple_at_its_harmonic():
    """At the h = 4 resonance without feedforward, a resonant term on h = 4 with
    the phase of the plant's path drives that harmonic's ripple towards zero."""
    env = StepperDampV1Env(base_controller="none", speed_rps=0.68, episode_s=0.6)
    env.reset(seed=0)
    free = [env.step(np.zeros(8, np.float32))[4]["velocity_error_rms_rad_s"] for _ in range(600)]
    env.reset(seed=0)
    a = np.zeros(8, np.float32)
    a[0] = 0.2                                      # some velocity feedback
    a[6] = 0.2                                      # r4_re
    held = [env.step(a)[4]["velocity_error_rms_rad_s"] for _ in range(600)]
    a[6] = 0.0
    only_kv = StepperDampV1Env(base_controller="none", speed_rps=0.68, episode_s=0.6)
    only_kv.reset(seed=0)
    kv = [only_kv.step(a)[4]["velocity_error_rms_rad_s"] for _ in range(600)]
    late = slice(400, 600)
    assert np.mean(held[late]) < 0.3 * np.mean(kv[late]) < 0.3 * np.mean(free[late])


def _rollout(make, steps=40):
    env = make()
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    out = [obs]
    for _ in range(steps):
        obs, reward, terminated, truncated, _ = env.step(
            rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        out += [obs, reward, terminated, truncated]
    return out


@pytest.mark.skipif(__import__("numba").config.NUMBA_NUM_THREADS < 2, reason="one numba thread")
@pytest.mark.parametrize("kwargs", [{}, {"action_mode": "harmonic", "randomize": True}])
def test_vector_envs_on_two_threads_give_the_same_bits(kwargs):
    from stepdamp_env.env import StepperDampVectorEnv

    for cls, opts in ((StepperDampV1VectorEnv, {"agent_hz": 500.0, **kwargs}),
                      (StepperDampVectorEnv, {"action_mode": "harmonic"})):
        one = _rollout(lambda: cls(num_envs=5, **opts))
        two = _rollout(lambda: cls(num_envs=5, num_threads=2, **opts))
        assert all(np.array_equal(a, b) for a, b in zip(one, two, strict=True))


@pytest.mark.parametrize("kwargs", [{}, {"action_mode": "harmonic", "randomize": True},
                                    {"velocity_estimator": "kalman", "randomize": True}])
def test_the_vector_env_in_simd_lanes_gives_the_same_bits(kwargs):
    from stepdamp_env.lanes import simd_by_default

    # 37 drives: a full group of lanes and part of one; the Kalman filter is not
    # the lanes' variant, so the kernel takes those drives over.
    threads = min(2, __import__("numba").config.NUMBA_NUM_THREADS)
    opts = {"agent_hz": 500.0, **kwargs}
    plain = _rollout(lambda: StepperDampV1VectorEnv(num_envs=37, simd=False, **opts), steps=15)
    assert StepperDampV1VectorEnv(num_envs=37, **opts).simd == simd_by_default(37)
    assert not StepperDampV1VectorEnv(num_envs=31, **opts).simd
    for t in (1, threads):
        lanes = _rollout(lambda: StepperDampV1VectorEnv(num_envs=37, simd=True, num_threads=t,
                                                        **opts), steps=15)
        assert all(np.array_equal(a, b) for a, b in zip(plain, lanes, strict=True))


def test_simd_is_checked_with_one_line():
    with pytest.raises(ParameterError, match=r"^simd='yes': allowed are True, False and None"):
        StepperDampV1VectorEnv(num_envs=2, simd="yes")


def test_num_threads_is_checked_with_one_line():
    import numba

    top = numba.config.NUMBA_NUM_THREADS
    for bad in (0, top + 1, 1.5, True):
        with pytest.raises(ParameterError,
                           match=rf"^num_threads=.*: allowed are the integers in \[1, {top}\]"):
            StepperDampV1VectorEnv(num_envs=2, num_threads=bad)


def _two_thread_rollout(_: int) -> list:
    return _rollout(lambda: StepperDampV1VectorEnv(num_envs=3, num_threads=2, agent_hz=500.0),
                    steps=5)


@pytest.mark.skipif(__import__("numba").config.NUMBA_NUM_THREADS < 2, reason="one numba thread")
def test_a_child_forked_after_parallel_steps_serially_with_the_same_bits():
    import multiprocessing

    if "fork" not in multiprocessing.get_all_start_methods():
        pytest.skip("no fork on this platform")
    here = _two_thread_rollout(0)           # the parallel path runs in this process first
    with multiprocessing.get_context("fork").Pool(1) as pool:
        there = pool.map_async(_two_thread_rollout, [0]).get(timeout=120)[0]
    assert all(np.array_equal(a, b) for a, b in zip(here, there, strict=True))


def test_v1_options_share_their_drive_with_v0_checked_once(monkeypatch):
    # EnvOptionsV1.shared() gives v0 the same drive options (checked once, by v1)
    # and its own at v0's checks: equal to v0's options made from keywords.
    from stepdamp_env.env.options import EnvOptions

    o = EnvOptionsV1(motor="patent-0.9-degree", mode="servo", speed_rps=1.5,
                     randomize={"J": (0.9, 1.1)}, base_controller="none",
                     measure_from_s=0.2, agent_hz=500.0)
    want = EnvOptions(**o.drive_options(), action_mode="harmonic+current",
                      base_controller="none")
    assert o.shared() == want
    assert EnvOptionsV1().shared() == EnvOptions(**EnvOptionsV1().drive_options(),
                                                 action_mode="harmonic+current")
    checks = []
    monkeypatch.setattr(EnvOptions, "check_drive", lambda self: checks.append(self))
    assert o.shared() == want and checks == []
    monkeypatch.undo()
    with pytest.raises(ParameterError, match="action_mode"):
        EnvOptions.of_drive(o, action_mode="gains")
    with pytest.raises(ParameterError, match="current_penalty"):
        EnvOptions.of_drive(o, current_penalty=-1.0)
    with pytest.raises(ParameterError, match=r"\['mode', 'nominal'\]"):
        EnvOptions.of_drive(o, mode="servo", nominal="patent")
