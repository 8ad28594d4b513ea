"""StepperDamp-v2's and v3's native vector envs give Gymnasium's ``SyncVectorEnv`` infos: the
same keys, masks, shapes, dtypes and values, step after step, in both autoreset
modes, with the reset info of drives that start over and ``final_info`` as a dict
of arrays. (v0's and v1's keep their own, which their frozen fingerprints hash.)"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import stepdamp_env  # noqa: F401

# Short episodes, so that drives end (one at a time: their ramps differ) and start over.
CASES = [("StepperDamp-v2", {"episode_s": 0.03}),
         ("StepperDamp-v2", {"episode_s": 0.004, "agent_hz": 1000.0, "action_mode": "harmonic",
                             "history": 0, "context": "hidden", "randomize": False}),
         ("StepperDamp-v3", {"episode_s": 0.03})]


def _equal(a, b, where):
    assert type(a) is type(b), (where, type(a), type(b))
    if isinstance(a, dict):
        assert sorted(a) == sorted(b), (where, sorted(a), sorted(b))
        for k in a:
            _equal(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape, (where, a.dtype, b.dtype, a.shape,
                                                           b.shape)
        if a.dtype == object:
            for i, (x, y) in enumerate(zip(a, b)):
                _equal(x, y, f"{where}[{i}]")
        else:
            np.testing.assert_array_equal(a, b, err_msg=where)
    else:
        assert a == b, (where, a, b)


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
@pytest.mark.parametrize("env_id,kwargs", CASES, ids=["defaults", "harmonic-1kHz", "v3"])
def test_native_infos_are_sync_infos(env_id, kwargs, mode):
    n = 3
    sync = gym.make_vec(env_id, num_envs=n, vectorization_mode="sync",
                        vector_kwargs={"autoreset_mode": mode}, **kwargs)
    native = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point",
                          autoreset_mode=mode, **kwargs)
    rng = np.random.default_rng(0)
    seeds = [11, 12, 13]
    got = [env.reset(seed=seeds) for env in (sync, native)]
    _equal(got[0][1], got[1][1], "reset")
    ended, mixed = 0, False
    for t in range(12):
        if t in (1, 2):                 # stagger the episodes: drives end at different steps
            mask = np.arange(n) == t - 1
            got = [env.reset(options={"reset_mask": mask}) for env in (sync, native)]
            np.testing.assert_array_equal(got[0][0], got[1][0])
            _equal(got[0][1], got[1][1], f"reset {t}")
        action = rng.uniform(-0.2, 0.2, sync.action_space.shape).astype(np.float32)
        a, b = sync.step(action), native.step(action)
        np.testing.assert_array_equal(a[0], b[0])
        for k in range(1, 4):
            np.testing.assert_array_equal(a[k], b[k])
        _equal(a[4], b[4], f"step {t}")
        ended += int((a[2] | a[3]).sum())
        mixed = mixed or 0 < int((a[2] | a[3]).sum()) < n
    assert ended >= n                   # every drive ended at least once
    assert mixed                        # and some ended while others went on
    sync.close()
    native.close()
