"""StepperDamp-v0: registration, API conformance, fidelity to the simulation core,
determinism, scalar/vector agreement, bad input, termination, rendering."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from gymnasium.vector import AutoresetMode

import stepdamp_env
from stepdamp_env import kernel as K
from stepdamp_env.env import (DEFAULT_EPISODE_STEPS, ENV_ID, StepperDampEnv,
                               StepperDampVectorEnv, register_envs)
from stepdamp_env.params import FeedforwardModel, predicted_resonances
from stepdamp_env.presets import get_preset
from stepdamp_env.simulation import simulate


# -- registration -------------------------------------------------------------------
def test_registered_on_import_and_reachable_by_module_path():
    assert ENV_ID in gym.registry
    spec = gym.spec(ENV_ID)
    assert spec.max_episode_steps == DEFAULT_EPISODE_STEPS
    assert spec.vector_entry_point is not None
    env = gym.make("stepdamp_env:StepperDamp-v0")
    assert isinstance(env.unwrapped, StepperDampEnv)
    env.close()


def test_register_twice_does_not_warn():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        register_envs()
        register_envs()


def test_make_vec_uses_native_vector_env():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # Gymnasium's own note that a newer version (v1) exists is the one expected warning.
        warnings.filterwarnings("ignore", ".*StepperDamp-v0 is out of date",
                                DeprecationWarning)
        venv = gym.make_vec(ENV_ID, num_envs=4)
    assert isinstance(venv, StepperDampVectorEnv)
    assert venv.max_episode_steps == DEFAULT_EPISODE_STEPS
    obs, info = venv.reset(seed=1)
    assert obs.shape == (4, 17) and obs.dtype == np.float32
    obs, rew, term, trunc, info = venv.step(np.zeros((4, 6), np.float32))
    assert rew.shape == (4,) and term.dtype == bool and trunc.dtype == bool
    assert venv.observation_space.contains(obs)


# -- API conformance ---------------------------------------------------------------
@pytest.mark.parametrize("kwargs", [{}, {"action_mode": "current", "privileged": True},
                                    {"mode": "servo", "randomize": True,
                                     "estimate": "nominal"}])
def test_gymnasium_check_env_passes_without_warnings(kwargs):
    env = gym.make(ENV_ID, **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # The render check re-makes the env with every render mode (one here).
        gym_check_env(env.unwrapped, skip_render_check=bool(kwargs))
    env.close()


def test_spaces_and_scaling():
    env = StepperDampEnv(privileged=True)
    assert env.action_space.dtype == np.float32
    assert np.all(env.action_space.low == -1) and np.all(env.action_space.high == 1)
    assert env.observation_space.shape == (11 + 6 + 4,)
    assert env.observation_space.dtype == np.float32
    obs, info = env.reset(seed=3)
    assert obs.dtype == np.float32 and env.observation_space.contains(obs)
    # At rest in open loop: holding current on d, nothing on q; angle 0.
    assert obs[9] == pytest.approx(1.0) and obs[2] == 0.0 and obs[3] == 1.0
    a = np.linspace(-1, 1, 6).astype(np.float32)
    obs, *_ = env.step(a)
    np.testing.assert_array_equal(obs[11:17], a)        # last action is observed
    # Default action scale: 2*max(Kd) of the patent motor (N*m).
    m = get_preset("patent").motor
    assert env.sampler.action_scales[0] == pytest.approx(2 * max(m.Kd1, m.Kd2, m.Kd4))
    cur = StepperDampEnv(action_mode="current")
    assert cur.action_space.shape == (1,)
    assert cur.sampler.action_scales[0] == pytest.approx(0.25 * 1.9)


def test_each_env_has_its_own_spaces_of_read_only_bounds():
    # The spaces of a layout are made once and copied: an env's space (its random
    # generator) is its own, and the shared bounds cannot be changed in place.
    a, b = StepperDampEnv(), StepperDampEnv()
    assert a.observation_space is not b.observation_space
    assert a.observation_space == b.observation_space and a.action_space == b.action_space
    a.action_space.seed(1)
    b.action_space.seed(2)
    assert not np.array_equal(a.action_space.sample(), b.action_space.sample())
    with pytest.raises(ValueError):
        a.observation_space.high[0] = 0.0


def test_run_metrics_dict_is_asdicts():
    import dataclasses

    env = StepperDampEnv(speed_rps=1.0, measure_from_s=0.1)
    env.reset(seed=0)
    for _ in range(400):
        env.step(np.zeros(6, dtype=np.float32))
    m = env.run_metrics()
    want = dataclasses.asdict(m)
    want["harmonic_amplitude_rad_s"] = {str(h): v for h, v in want["harmonic_amplitude_rad_s"].items()}
    want["harmonic_phasor_rad_s"] = {str(h): list(v) for h, v in want["harmonic_phasor_rad_s"].items()}
    assert m.to_dict() == want and list(m.to_dict()) == list(want)


@pytest.mark.parametrize("mode", ["open-loop", "servo"])
def test_harmonic_plus_current_is_both_modes_at_once(mode):
    """Its first six entries act as "harmonic" mode, the seventh as "current" mode:
    with the other part zero, each reproduces that mode bit for bit."""
    rng = np.random.default_rng(4)
    harmonic = rng.uniform(-1, 1, (60, 6)).astype(np.float32)
    current = rng.uniform(-1, 1, (60, 1)).astype(np.float32)
    zeros6, zeros1 = np.zeros_like(harmonic), np.zeros_like(current)
    kw = {"mode": mode, "speed_rps": 0.7}

    def states(action_mode, actions):
        env = StepperDampEnv(action_mode=action_mode, **kw)
        env.reset(seed=2)
        out = []
        for a in actions:
            obs, *_ = env.step(a)
            out.append(np.concatenate([env.drive_state, obs[:11]]))
        return np.array(out)

    both = StepperDampEnv(action_mode="harmonic+current", **kw)
    assert both.action_space.shape == (7,)
    assert both.sampler.action_scales == (both.sampler.harmonic_scale_nm,) * 6 + (
        both.sampler.current_scale_a,)
    assert np.array_equal(states("harmonic+current", np.hstack([harmonic, zeros1])),
                          states("harmonic", harmonic))
    assert np.array_equal(states("harmonic+current", np.hstack([zeros6, current])),
                          states("current", current))
    assert not np.array_equal(states("harmonic+current", np.hstack([harmonic, current])),
                              states("harmonic", harmonic))


def test_agent_rate_sets_periods_per_step():
    env = StepperDampEnv(agent_hz=500.0, speed_rps=1.0)
    env.reset(seed=0)
    env.step(np.zeros(6, np.float32))
    assert env.drive_state[K.STATE.PERIOD] == 40
    assert env.seconds_per_step == pytest.approx(2e-3)


# -- fidelity to the simulation core ---------------------------------------------------
def _env_trajectory(n_steps, **kwargs):
    env = StepperDampEnv(**kwargs)
    env.reset(seed=0)
    zero = np.zeros(env.action_space.shape, np.float32)
    theta, omega, ia = [], [], []
    for _ in range(n_steps):
        _, _, term, _, _ = env.step(zero)
        s = env.drive_state
        theta.append(s[K.STATE.THETA])
        omega.append(s[K.STATE.OMEGA])
        ia.append(s[K.STATE.IA])
        assert not term
    return np.array(theta), np.array(omega), np.array(ia)


@pytest.mark.parametrize("mode,damping,action_mode", [
    ("open-loop", "patent-ff", "harmonic"),
    ("open-loop", "none", "current"),
    ("servo", "patent-ff", "current"),
    ("servo", "none", "harmonic"),
])
def test_zero_action_reproduces_simulation_core_bit_for_bit(mode, damping, action_mode):
    system = get_preset("patent")
    speed = predicted_resonances(system)[2]          # a resonant speed: a hard case
    n_steps = 250
    theta, omega, ia = _env_trajectory(n_steps, mode=mode, base_controller=damping,
                                       action_mode=action_mode, speed_rps=speed)
    ref = simulate(system, speed_rps=speed, mode=mode, base_controller=damping, trace=True,
                   trace_every=20)
    tr = ref.trace
    # Trace row k holds the state at the start of PWM period 20k: after k agent steps.
    k = np.arange(1, n_steps + 1)
    assert np.array_equal(theta, tr["theta"][k])
    assert np.array_equal(omega, tr["omega"][k])
    assert np.array_equal(ia, tr["ia"][k])


def test_estimate_options_set_the_controller_model():
    nominal = get_preset("patent")
    env = StepperDampEnv(randomize=True, estimate="nominal")
    env.reset(seed=4)
    c = env.drive_config
    assert np.allclose(c[K.CONFIG.FF_S1:K.CONFIG.FF_C4 + 1],
                       FeedforwardModel.from_motor(nominal.motor).coefficients())
    assert c[K.CONFIG.KM_EST] == nominal.motor.Km
    assert c[K.CONFIG.KM] != nominal.motor.Km            # the plant was randomised
    exact = StepperDampEnv(randomize=True, estimate="exact")
    exact.reset(seed=4)
    ce = exact.drive_config
    assert ce[K.CONFIG.KM_EST] == ce[K.CONFIG.KM]
    ident = FeedforwardModel(Km=0.28, Kd1=0.0, Kd2=0.005, Kd4=0.01, phi1=0.0, phi2=0.5, Fs=0.0)
    env = StepperDampEnv(estimate=ident)
    env.reset(seed=0)
    assert env.drive_config[K.CONFIG.KM_EST] == 0.28
    none = StepperDampEnv(base_controller="none")
    none.reset(seed=0)
    assert none.drive_config[K.CONFIG.BASE_CONTROLLER] == 0.0


# -- determinism and scalar/vector agreement ---------------------------------------
def _rollout(env, seed, actions):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    rewards = []
    for a in actions:
        obs, r, term, trunc, _ = env.step(a)
        out.append(obs)
        rewards.append(r)
        if term or trunc:
            break
    return np.array(out), np.array(rewards)


def test_same_seed_and_actions_give_identical_results():
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (60, 6)).astype(np.float32)
    kw = dict(randomize=True)
    o1, r1 = _rollout(StepperDampEnv(**kw), 11, actions)
    o2, r2 = _rollout(StepperDampEnv(**kw), 11, actions)
    assert np.array_equal(o1, o2) and np.array_equal(r1, r2)
    o3, _ = _rollout(StepperDampEnv(**kw), 12, actions)
    assert not np.array_equal(o1, o3)


@pytest.mark.parametrize("kwargs", [{"randomize": True},
                                    {"mode": "servo", "action_mode": "current",
                                     "privileged": True}])
def test_scalar_and_vector_agree_step_for_step_through_autoreset(kwargs):
    n, horizon, steps, seed = 3, 15, 40, 21
    rng = np.random.default_rng(1)
    act_dim = 6 if kwargs.get("action_mode", "harmonic") == "harmonic" else 1
    actions = rng.uniform(-1, 1, (steps, n, act_dim)).astype(np.float32)
    venv = StepperDampVectorEnv(num_envs=n, max_episode_steps=horizon, **kwargs)
    envs = [gym.wrappers.TimeLimit(StepperDampEnv(**kwargs), horizon) for _ in range(n)]
    vobs, vinfo = venv.reset(seed=seed)
    for i, env in enumerate(envs):
        obs, info = env.reset(seed=seed + i)
        assert np.array_equal(obs, vobs[i])
        assert info["speed_rps"] == vinfo["speed_rps"][i]
    need_reset = [False] * n
    resets = 0
    for t in range(steps):
        vobs, vrew, vterm, vtrunc, _ = venv.step(actions[t])
        for i, env in enumerate(envs):
            if need_reset[i]:                        # NEXT_STEP autoreset
                obs, _ = env.reset()
                resets += 1
                rew, term, trunc = 0.0, False, False
            else:
                obs, rew, term, trunc, _ = env.step(actions[t, i])
            need_reset[i] = term or trunc
            assert np.array_equal(obs, vobs[i]), (t, i)
            assert rew == vrew[i] and term == vterm[i] and trunc == vtrunc[i], (t, i)
    assert resets >= n                               # every drive went through a reset


def test_vector_same_step_autoreset_reports_final_observation():
    venv = StepperDampVectorEnv(num_envs=2, max_episode_steps=3,
                                autoreset_mode=AutoresetMode.SAME_STEP, speed_rps=1.0)
    venv.reset(seed=0)
    a = np.zeros((2, 6), np.float32)
    for _ in range(2):
        _, _, _, trunc, infos = venv.step(a)
        assert not trunc.any() and "final_obs" not in infos
    obs, _, term, trunc, infos = venv.step(a)
    assert trunc.all() and not term.any()
    assert infos["_final_obs"].all() and infos["final_obs"][0].shape == (17,)
    assert obs[0, 8] == 0.0                          # fresh episode: command at rest
    assert infos["final_obs"][0][8] > 0.0


def test_vector_reset_seeds_and_list():
    venv = StepperDampVectorEnv(num_envs=2)
    o1, i1 = venv.reset(seed=[5, 9])
    single = StepperDampEnv()
    _, info = single.reset(seed=9)
    assert info["speed_rps"] == i1["speed_rps"][1]
    with pytest.raises(ValueError, match="num_envs=2"):
        venv.reset(seed=[1, 2, 3])


# -- speed distribution and randomisation ----------------------------------------
def test_speed_distribution_weights_resonances():
    env = StepperDampEnv(resonance_prob=0.6, resonance_spread=0.05)
    res = predicted_resonances(get_preset("patent"))
    env.reset(seed=0)
    hits, n = 0, 400
    for _ in range(n):
        _, info = env.reset()
        v, h = info["speed_rps"], info["target_harmonic"]
        if h:
            hits += 1
            assert abs(v / res[h] - 1.0) <= 0.05 + 1e-12
        else:
            assert 0.25 <= v <= 3.0
    assert 0.5 < hits / n < 0.7
    fixed = StepperDampEnv(speed_rps=2.0)
    assert fixed.reset(seed=0)[1]["speed_rps"] == 2.0


def test_randomised_motor_stays_in_documented_ranges():
    env = StepperDampEnv(randomize={"J": (0.5, 2.0), "phi1": (-1.0, 1.0)})
    nominal = get_preset("patent").motor
    env.reset(seed=0)
    for _ in range(20):
        env.reset()
        m = env.system.motor
        assert 0.5 * nominal.J <= m.J <= 2.0 * nominal.J
        assert -1.0 <= m.phi1 <= 1.0
        assert m.Km == nominal.Km


# -- reward, termination -----------------------------------------------------------
def test_reward_and_info_are_physical():
    env = StepperDampEnv(speed_rps=1.0, base_controller="none")
    env.reset(seed=0)
    for _ in range(100):
        _, r, term, trunc, info = env.step(np.zeros(6, np.float32))
    w_ref = 2 * math.pi * 1.0
    rms, iinj = info["velocity_error_rms_rad_s"], info["injected_current_rms_a"]
    assert iinj == 0.0                               # no feedforward, no residual
    assert r == pytest.approx(-(rms / w_ref) ** 2, rel=1e-12)
    assert 0 < info["lag_rad"] < get_preset("patent").motor.full_step_rad
    assert info["peak_current_a"] == pytest.approx(1.9, rel=0.05)


def test_step_loss_terminates_with_penalty():
    # A load torque above the holding torque (0.57 N*m): the rotor cannot follow.
    env = StepperDampEnv(speed_rps=1.0, overrides={"load_torque": 1.0},
                         termination_penalty=7.0)
    env.reset(seed=0)
    for _ in range(300):
        _, r, term, _, info = env.step(np.zeros(6, np.float32))
        if term:
            break
    assert term and info["step_loss"] and not info["overcurrent"]
    assert r < -7.0


def test_unsafe_current_terminates():
    env = StepperDampEnv(action_mode="current", current_scale_a=10.0, speed_rps=1.0)
    env.reset(seed=0)
    for _ in range(20):
        _, r, term, _, info = env.step(np.ones(1, np.float32))
        if term:
            break
    assert term and info["overcurrent"] and info["peak_current_a"] > 3 * 1.9


# -- bad input -------------------------------------------------------------------------
@pytest.mark.parametrize("action", [np.zeros(5, np.float32), np.zeros((1, 6)), [0.0] * 7,
                                    np.array([np.nan, 0, 0, 0, 0, 0]),
                                    np.array([0, 0, np.inf, 0, 0, 0], np.float32),
                                    np.full(6, 1.5), "abc", None])
def test_bad_action_raises_clear_error(action):
    env = StepperDampEnv()
    env.reset(seed=0)
    state = env.drive_state
    with pytest.raises(ValueError, match=r"action.*\(6,\).*\[-1, 1\]"):
        env.step(action)
    assert np.array_equal(env.drive_state, state)     # nothing advanced


def test_bad_vector_action_raises():
    venv = StepperDampVectorEnv(num_envs=3)
    venv.reset(seed=0)
    with pytest.raises(ValueError, match=r"action.*\(3, 6\)"):
        venv.step(np.zeros((3, 5)))
    a = np.zeros((3, 6))
    a[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"action.*\[-1, 1\]"):
        venv.step(a)


@pytest.mark.parametrize("kwargs,name", [
    ({"bogus": 1}, "bogus"),
    ({"mode": "closed"}, "mode"),
    ({"base_controller": "pid"}, "base_controller"),
    ({"action_mode": "torque"}, "action_mode"),
    ({"estimate": "guess"}, "estimate"),
    ({"agent_hz": 3000.0}, "agent_hz"),
    ({"agent_hz": -1.0}, "agent_hz"),
    ({"speed_rps": 0.0}, "speed_rps"),
    ({"speed_range_rps": (2.0, 1.0)}, "speed_range_rps"),
    ({"resonance_prob": 1.5}, "resonance_prob"),
    ({"randomize": {"Nr": (1, 2)}}, "Nr"),
    ({"randomize": {"J": (0.0, 2.0)}}, "J"),
    ({"current_limit_factor": 0.5}, "current_limit_factor"),
    ({"motor": "nema99"}, "nema99"),
    ({"overrides": {"R": -1.0}}, "R"),
    ({"substeps": 0}, "substeps"),
    ({"render_mode": "human"}, "render_mode"),
])
def test_bad_options_raise_value_error_naming_them(kwargs, name):
    with pytest.raises(ValueError, match=name):
        StepperDampEnv(**kwargs)
    if "render_mode" not in kwargs:
        with pytest.raises(ValueError, match=name):
            StepperDampVectorEnv(num_envs=2, **kwargs)


def test_unknown_kwarg_through_gym_make_is_value_error():
    with pytest.raises(ValueError, match="wrong_name"):
        gym.make(ENV_ID, wrong_name=3)
    with pytest.raises(ValueError, match="num_envs"):
        StepperDampVectorEnv(num_envs=0)


# -- rendering ---------------------------------------------------------------------------
def test_render_rgb_array():
    env = gym.make(ENV_ID, render_mode="rgb_array", speed_rps=1.0)
    env.reset(seed=0)
    for _ in range(30):
        env.step(env.action_space.sample())
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    assert frame.shape[0] > 100 and frame.shape[1] > 100
    assert frame.std() > 0                          # something was drawn
    env.close()


def test_measured_episode_gives_the_simulation_core_metrics():
    # The env, stepped with zero actions through a measuring window, reports the
    # very metrics simulate() computes for the same run.
    from stepdamp_env.env import StepperDampEnv
    from stepdamp_env.simulation import RunSettings, SpeedProfile, measuring_window

    system = get_preset("patent")
    speed = 1.3
    start, length = measuring_window(system, SpeedProfile(speed), RunSettings())
    env = StepperDampEnv(speed_rps=speed, measure_from_s=start)
    env.reset(seed=0)
    zero = np.zeros(env.action_space.shape, np.float32)
    while env.time_s < start + length - 1e-12:
        env.step(zero)
    ref = simulate(system, speed_rps=speed, base_controller="patent-ff", duration_s=env.time_s).metrics
    got = env.run_metrics()
    # Extremes are exact; sums differ in the last bits (summed per step, then added).
    assert (got.p2p_velocity_error_rad_s, got.max_position_lag_rad, got.step_loss) == (
        ref.p2p_velocity_error_rad_s, ref.max_position_lag_rad, ref.step_loss)
    for key in ("rms_velocity_error_rad_s", "rms_injected_current_a",
                "mean_velocity_error_rad_s"):
        assert getattr(got, key) == pytest.approx(getattr(ref, key), rel=1e-12, abs=1e-15), key
    for h in (1, 2, 4):
        assert got.harmonic_amplitude_rad_s[h] == pytest.approx(
            ref.harmonic_amplitude_rad_s[h], rel=1e-9)


@pytest.mark.parametrize("how", ["pickle", "deepcopy"])
def test_a_copied_env_has_the_same_future(how):
    """A pickled or deep-copied env once froze: its arrays stopped sharing memory."""
    import copy
    import pickle

    env = StepperDampEnv(randomize=True, mode="servo")
    env.reset(seed=4)
    rng = np.random.default_rng(0)
    for _ in range(20):
        env.step(rng.uniform(-0.3, 0.3, size=env.action_space.shape).astype(np.float32))
    twin = pickle.loads(pickle.dumps(env)) if how == "pickle" else copy.deepcopy(env)
    actions = rng.uniform(-0.3, 0.3, size=(30,) + env.action_space.shape).astype(np.float32)
    a = [env.step(x)[:2] for x in actions]
    b = [twin.step(x)[:2] for x in actions]
    assert all(np.array_equal(oa, ob) and ra == rb for (oa, ra), (ob, rb) in zip(a, b))
    assert len({float(r) for _, r in b}) > 1                # not frozen


def test_stepping_a_terminated_episode_needs_a_reset():
    env = StepperDampEnv(speed_rps=1.0, current_limit_factor=1.01, action_mode="current")
    env.reset(seed=0)
    terminated = False
    for _ in range(300):
        _, _, terminated, _, _ = env.step(np.ones(1, dtype=np.float32))
        if terminated:
            break
    assert terminated
    with pytest.raises(gym.error.ResetNeeded, match="terminated"):
        env.step(np.zeros(1, dtype=np.float32))
    env.reset(seed=1)
    env.step(np.zeros(1, dtype=np.float32))
