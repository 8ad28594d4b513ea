"""Shared helpers for the tests."""

from __future__ import annotations

import functools
import inspect
import os

import numpy as np
import pytest

from stepdamp_env import kernel as K
from stepdamp_env.numba_cache import call_with_frame_room
from stepdamp_env.presets import get_preset
from stepdamp_env.simulation import (RunSettings, SpeedProfile, build_config, initial_state,
                                     new_accumulators)


def pytest_configure(config):
    """Under pytest-xdist, the files run in collection order (LONG_FIRST; xdist
    otherwise sorts --dist loadfile's files by their test counts), and the
    controller compiles (where numba's cache is cold) the kernels, env steps and
    SIMD lanes once, on two processes, before the workers start; otherwise every
    worker compiles the same code at once, which costs CI minutes. Without
    xdist, or in a worker, nothing happens here."""
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False
    from stepdamp_env.bench.warmup import warm_lanes, warm_up

    try:
        kernels = warm_up(get_preset("patent"), workers=2)
        lanes = warm_lanes(workers=2, always=True, here=False)   # workers do not fork from here
        # On CI's log: the compile is a large share of CI's time on a cold cache.
        print(f"conftest: numba's cache warm after {kernels:.0f} s (kernels) + {lanes:.0f} s "
              "(SIMD lanes)", flush=True)
    except Exception:       # noqa: BLE001 - only a head start: the workers compile it
        pass


#: Files whose tests take minutes (CI's log, --durations): collected first, so
#: that pytest-xdist's --dist loadfile starts them at once, not last and alone.
LONG_FIRST = ("test_cpu_determinism.py", "test_agents.py", "test_properties.py",
              "test_bench_v1.py", "test_zoo.py")


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(LONG_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(LONG_FIRST)))   # stable


@pytest.fixture(autouse=True, scope="session")
def _sb3_logs_in_the_tests_tmp(tmp_path_factory):
    """SB3's ``learn`` without a logger of its own makes a folder ``SB3-<date>``
    in the system's temporary folder, one per call (about 280 left in /tmp by
    earlier runs): here they go below pytest's basetemp."""
    import os

    before = os.environ.get("SB3_LOGDIR")
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3-logs"))
    yield
    if before is None:
        os.environ.pop("SB3_LOGDIR", None)
    else:
        os.environ["SB3_LOGDIR"] = before


@pytest.hookimpl(tryfirst=True)
def pytest_pyfunc_call(pyfuncitem):
    """Each test runs with room on CPython's frame stack, so that numba compiling
    inside it does not thrash the stack's chunks (numba_cache.call_with_frame_room)."""
    fn = pyfuncitem.obj
    params = inspect.signature(fn).parameters
    kwargs = {k: v for k, v in pyfuncitem.funcargs.items() if k in params}
    call_with_frame_room(functools.partial(fn, **kwargs))
    return True


#: The flags exported C must compile clean with.
STRICT_C_FLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]


def c_compiler() -> str:
    """The C compiler on PATH (cc or gcc); the test is skipped without one."""
    import shutil

    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler (cc or gcc) on PATH: the generated C cannot be compiled "
                    "and checked against the Python law here")
    return cc


def compiled_driver(source_c, driver_text, out_dir) -> str:
    """The executable of an exported ``source_c`` with a test's ``main.c``
    (``driver_text``), built in ``out_dir`` with :data:`STRICT_C_FLAGS`, -O2 and
    libm; the build must succeed without a warning."""
    import subprocess

    cc = c_compiler()
    main = os.path.join(str(out_dir), "main.c")
    with open(main, "w") as fh:
        fh.write(driver_text)
    exe = os.path.join(str(out_dir), "driver")
    build = subprocess.run([cc, *STRICT_C_FLAGS, "-O2", "-o", exe, str(source_c), main, "-lm"],
                           capture_output=True, text=True, timeout=120)
    assert build.returncode == 0, build.stderr
    return exe


def recorded_episode(entry, knowledge, mode, until_s, **run):
    """A run of the entry at its plant's h=4 resonance (``run_episode`` seed 3)
    with every observation its policy read and every action it gave (float32
    rows): (observations, actions, speed in rev/s, the run's result)."""
    import numpy as np

    from stepdamp_env.bench import run_episode
    from stepdamp_env.bench.registry import resolve_policy

    policy = resolve_policy(entry).make()
    seen, acted = [], []
    act_batch = policy.act_batch

    def recording(observations, rows):
        actions = act_batch(observations, rows)
        seen.append(np.array(observations, dtype=np.float32))
        acted.append(np.array(actions, dtype=np.float32))
        return actions

    policy.act_batch = recording
    speed = knowledge.plant.predicted_resonances_rps()[4]
    result = run_episode(policy, knowledge, knowledge.plant, mode=mode, speed_rps=speed, seed=3,
                         measure_from_s=0.0, window_s=until_s, until_s=until_s, **run)
    assert not result.terminated
    return np.concatenate(seen), np.concatenate(acted), speed, result


def run_raw(system, profile, settings=None, n_periods=1000, state=None, window_start_s=0.0,
            trace_every=1):
    """Run the kernel directly; returns (config, final state, accumulators, trace)."""
    settings = settings or RunSettings()
    c = build_config(system, profile, settings, window_start_s=window_start_s)
    s = initial_state(c) if state is None else state
    acc = new_accumulators()
    trace = np.zeros((-(-n_periods // trace_every), len(K.TRACE)))
    rows = K.run_periods(c, s, acc, np.zeros(len(K.INPUT)), n_periods, trace, trace_every)
    return c, s, acc, {name: trace[:rows, i] for i, name in enumerate(K.TRACE_NAMES)}


@pytest.fixture(scope="session")
def patent():
    return get_preset("patent")


@pytest.fixture(scope="session")
def still():
    """A profile that holds the command at zero."""
    return SpeedProfile(speed_rps=0.0)
