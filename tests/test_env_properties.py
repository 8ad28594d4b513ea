"""Property-based: arbitrary in-range actions and parameter draws never give a NaN or
inf, never an observation outside its space, never an unhandled exception."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stepdamp_env.env import StepperDampEnv, StepperDampVectorEnv

unit = st.floats(-1.0, 1.0, allow_nan=False, width=32)

options = st.fixed_dictionaries({
    "mode": st.sampled_from(["open-loop", "servo"]),
    "base_controller": st.sampled_from(["patent-ff", "none"]),
    "action_mode": st.sampled_from(["harmonic", "current"]),
    "estimate": st.sampled_from(["exact", "nominal"]),
    "privileged": st.booleans(),
    "agent_hz": st.sampled_from([500.0, 1000.0, 4000.0]),
    "speed_rps": st.one_of(st.none(), st.floats(0.05, 8.0)),
    "randomize": st.one_of(st.booleans(), st.fixed_dictionaries({
        "J": st.tuples(st.floats(0.2, 1.0), st.floats(1.0, 5.0)),
        "Kd4": st.tuples(st.floats(0.0001, 1.0), st.floats(1.0, 3.0)),
        "R": st.tuples(st.floats(0.5, 1.0), st.floats(1.0, 2.0)),
    })),
    # Up to far past the safe current: termination must handle it.
    "current_scale_a": st.floats(0.01, 20.0),
    "harmonic_scale_nm": st.floats(0.001, 2.0),
    "motor": st.sampled_from(["patent", "qsh4218-51-10-049", "qsh6018-65-28-210"]),
})


def _check(obs, space):
    assert obs.dtype == np.float32 and np.all(np.isfinite(obs))
    assert space.contains(obs)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(opts=options, seed=st.integers(0, 2**31 - 1),
       actions=st.lists(st.lists(unit, min_size=6, max_size=6), min_size=1, max_size=40))
def test_scalar_env_stays_finite(opts, seed, actions):
    env = StepperDampEnv(**opts)
    obs, info = env.reset(seed=seed)
    _check(obs, env.observation_space)
    k = env.action_space.shape[0]
    for a in actions:
        obs, r, term, trunc, info = env.step(np.asarray(a[:k], np.float32))
        _check(obs, env.observation_space)
        assert np.isfinite(r) and isinstance(r, float)
        assert all(np.isfinite(info[key]) for key in ("velocity_error_rms_rad_s", "lag_rad",
                                                      "injected_current_rms_a"))
        if term:
            obs, _ = env.reset()
            _check(obs, env.observation_space)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(opts=options, seed=st.integers(0, 2**31 - 1), n=st.integers(1, 5),
       data=st.data())
def test_vector_env_stays_finite(opts, seed, n, data):
    venv = StepperDampVectorEnv(num_envs=n, max_episode_steps=7, **opts)
    obs, _ = venv.reset(seed=seed)
    assert np.all(np.isfinite(obs))
    k = venv.single_action_space.shape[0]
    for _ in range(12):
        a = np.array(data.draw(st.lists(st.lists(unit, min_size=k, max_size=k),
                                        min_size=n, max_size=n)), dtype=np.float32)
        obs, r, term, trunc, _ = venv.step(a)
        assert venv.observation_space.contains(obs)
        assert np.all(np.isfinite(obs)) and np.all(np.isfinite(r))
