"""Hardening: each class of failure of the audit (issue "Hardening") has a test here
or beside its subject (test_params: None / numpy scalars; test_env: pickling and
stepping a terminated episode; test_sensors: the Kalman design; test_agents:
policy_kwargs never executed; test_properties: the property-based suite)."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import textwrap
import time

import gymnasium as gym
import numpy as np
import pytest

import stepdamp_env  # noqa: F401  (registers the env)
from stepdamp_env import io as sio
from stepdamp_env.cli import main
from stepdamp_env.env import EpisodeGuard, StepperDampEnv
from stepdamp_env.params import ParameterError, current_loop_radius, fastest_plant_mode, required_substeps
from stepdamp_env.motorfile import load_system
from stepdamp_env.presets import get_preset
from stepdamp_env.simulation import RunSettings, SpeedProfile, measuring_window, simulate


# -- values in range that the integrator or the current loop cannot run --------------
@pytest.mark.parametrize("override, fields", [
    ({"J": 1e-9}, "D, J"), ({"D": 100.0}, "D, J"), ({"L": 1e-9}, "R, L"),
    ({"Km": 100.0}, "Km, L, J")])
def test_a_too_stiff_system_is_refused_with_the_substeps_it_needs(override, fields):
    system = load_system("patent", override)
    need = required_substeps(system)
    with pytest.raises(ParameterError, match=f"{fields}.*substeps"):
        simulate(system, speed_rps=1.0)
    if need <= 1000:
        run = simulate(system, profile=SpeedProfile(1.0),
                       settings=RunSettings(substeps=need, window_s=0.05))
        values = [v for v in run.metrics.to_dict().values() if isinstance(v, float)]
        assert all(math.isfinite(v) for v in values)


def test_the_substeps_follow_the_fastest_mode_and_the_env_refuses_likewise():
    base = load_system("patent")
    system = base.replace(D=5.0)             # D/J sets the fastest mode here
    rate, fields = fastest_plant_mode(system)
    assert fields == "D, J" and rate == pytest.approx(5.0 / base.motor.J, rel=1e-3)
    h = 1.0 / base.drive.pwm_hz
    assert required_substeps(system) == math.ceil(rate * h / 2.5) == 3
    with pytest.raises(ParameterError, match="substeps"):      # at construction
        StepperDampEnv(motor=base.replace(J=1e-9))
    assert StepperDampEnv(motor=system, substeps=3).reset(seed=0)[0].shape


def test_the_presets_need_one_substep_and_have_stable_current_loops():
    for name in ("patent", "qsh4218-51-10-049", "qsh5718-56-28-126", "qsh6018-65-28-210"):
        system = load_system(name)
        assert required_substeps(system) == 1
        assert current_loop_radius(system) < 1.0


def test_an_unstable_current_loop_is_refused_and_a_lossless_winding_runs():
    with pytest.raises(ParameterError, match="Ki_current.*unstable"):
        load_system("patent", {"Ki_current": 1e9})
    with pytest.raises(ParameterError, match="Kp_current.*unstable"):
        load_system("patent", {"Kp_current": 1e6})
    system = load_system("patent", {"R": 1e-300})        # was a ZeroDivisionError
    for mode in ("open-loop", "servo"):
        run = simulate(system, profile=SpeedProfile(1.0),
                       settings=RunSettings(mode=mode, window_s=0.05))
        assert math.isfinite(run.metrics.rms_velocity_error_rad_s)


def test_a_rotor_that_runs_away_is_refused_after_the_run_never_nan():
    """J = 1e-12 kg*m^2 with 151 substeps passes the check at the command speed; after
    losing its steps under a load near its holding torque, with D = 0, the rotor runs
    away past what those substeps integrate: a one-line error, not NaN metrics."""
    base = get_preset("patent")
    hold = base.motor.Km * base.drive.holding_current
    system = base.replace(J=1e-12, Nr=50, D=0.0, load_torque=0.99 * hold)
    with pytest.raises(ParameterError, match="diverged.*J=1e-12.*load_torque") as info:
        simulate(system, profile=SpeedProfile(speed_rps=10.0, accel_rps2=1e4),
                 settings=RunSettings(substeps=151, settle_s=0.0, window_s=0.02),
                 duration_s=0.15)
    assert "\n" not in str(info.value)
    # The same motor with damping keeps its steps and gives finite metrics.
    ok = simulate(base.replace(J=1e-6), speed_rps=1.0,
                  settings=RunSettings(settle_s=0.0, window_s=0.02), duration_s=0.2)
    assert math.isfinite(ok.metrics.rms_velocity_error_rad_s)


@pytest.mark.parametrize("make, name", [
    (lambda: SpeedProfile(speed_rps=None), "speed_rps"),
    (lambda: SpeedProfile(speed_rps="1"), "speed_rps"),
    (lambda: SpeedProfile(speed_rps=True), "speed_rps"),
    (lambda: SpeedProfile(speed_rps=1.0, distance_rev=math.nan), "distance_rev"),
    (lambda: SpeedProfile(speed_rps=1.0, distance_rev="x"), "distance_rev"),
    (lambda: RunSettings(estimate="guess"), "estimate"),
])
def test_run_arguments_of_the_wrong_type_are_named(make, name):
    with pytest.raises(ParameterError, match=name):
        make()


def test_numpy_scalars_are_accepted_as_plain_numbers():
    p = SpeedProfile(speed_rps=np.float32(1.5), accel_rps2=np.float32(100.0))
    assert type(p.speed_rps) is float and type(p.accel_rps2) is float
    r = RunSettings(substeps=np.int64(2), noise_seed=np.int64(3), window_s=np.float32(0.25))
    assert type(r.substeps) is int and type(r.window_s) is float
    env = StepperDampEnv(accel_rps2=np.float32(100.0), speed_rps=np.float32(1.0))
    obs, _ = env.reset(seed=0)
    assert np.all(np.isfinite(env.step(np.zeros(6, np.float32))[0]))


def test_extreme_env_rewards_stay_physical():
    # Was -6.5e220: the stiff system is refused, the valid extreme one stays bounded.
    env = StepperDampEnv(motor=load_system("patent", {"J": 1e-7}), speed_rps=1.0)
    env.reset(seed=0)
    for _ in range(50):
        _, r, term, _, _ = env.step(np.ones(env.action_space.shape, np.float32))
        assert math.isfinite(r) and abs(r) < 1e6
        if term:
            break


# -- the env ---------------------------------------------------------------------------
def test_stepping_after_truncation_needs_a_reset_with_the_guard():
    env = EpisodeGuard(gym.make("StepperDamp-v0", max_episode_steps=3))
    env.reset(seed=0)
    zero = np.zeros(env.action_space.shape, np.float32)
    flags = [env.step(zero)[3] for _ in range(3)]
    assert flags == [False, False, True]
    with pytest.raises(gym.error.ResetNeeded, match="truncated"):
        env.step(zero)
    env.reset()
    assert env.step(zero)[3] is False


# -- the command line ------------------------------------------------------------------
WINDOW_START_1RPS = measuring_window(load_system("patent"), SpeedProfile(1.0), RunSettings())[0]


@pytest.mark.parametrize("argv, option", [
    (["simulate", "--speed", "0"], "--speed"),
    (["simulate", "--speed", "1", "--accel", "1e-300"], "--accel"),
    (["simulate", "--speed", "1", "--duration", str(WINDOW_START_1RPS)], "--duration"),
    (["simulate", "--speed", "1", "--set", "encoder_cpr=nan"], "encoder_cpr"),
    (["simulate", "--speed", "1", "--set", "J=1e-9"], "substeps"),
    (["simulate", "--speed", "1", "--set", "Ki_current=1e9"], "Ki_current"),
    (["simulate", "--speed", "1", "--substeps", "nan"], "--substeps"),
    (["simulate", "--speed", "1", "--trace", "/proc/x/t.npz"], "--trace"),
    (["sweep", "--speeds", "1:0:1", "--out", "/proc/x"], "--speeds"),
    (["leaderboard", "--quick", "--out", "/proc/x"], "--out"),
])
def test_cli_mistakes_end_with_one_line_and_status_2(argv, option, capsys):
    try:
        rc = main(argv)
    except SystemExit as exc:           # argparse's own errors
        rc = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert "Traceback" not in "\n".join(err)
    assert option in err[-1] and err[-1].startswith(("stepdamp", "usage"))


def test_a_simulated_move_measures_the_move(capsys):
    assert main(["simulate", "--speed", "2", "--move", "0.05", "--json"]) == 0
    import json

    out = json.loads(capsys.readouterr().out)
    assert out["window_start_s"] == 0.0 and out["rms_velocity_error_rad_s"] > 0.0


@pytest.mark.slow
def test_ctrl_c_ends_with_one_line_and_status_130(tmp_path):
    # A short sweep first: a fresh clone compiles the kernel (many seconds), and the
    # interrupt below must land inside the sweep, not inside numba's compiler.
    subprocess.run([sys.executable, "-m", "stepdamp_env.cli", "sweep", "--speeds", "1:1.02:0.02",
                    "--out", str(tmp_path / "warm"), "--workers", "2", "--no-progress"],
                   check=True, capture_output=True, env={**os.environ, "MPLBACKEND": "Agg"})
    script = textwrap.dedent(f"""
        import sys
        from stepdamp_env.cli import main
        sys.exit(main(["sweep", "--speeds", "0.3:3.0:0.0001", "--out", {str(tmp_path / 'o')!r},
                       "--workers", "2", "--no-progress"]))
    """)
    # Ctrl-C's default action even where this runs in the background (a shell
    # starts background jobs with SIGINT ignored, and children inherit that).
    proc = subprocess.Popen([sys.executable, "-c", script], stderr=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "MPLBACKEND": "Agg"},
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.default_int_handler))
    time.sleep(6.0)                     # inside the sweep (27001 runs, about a minute)
    assert proc.poll() is None
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert err.strip().splitlines() == [
        "stepdamp sweep: interrupted; earlier results are unchanged"]
    assert err.startswith("\n")        # never glued to a progress bar's line
    assert not (tmp_path / "o").exists()
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".")]
    assert sorted(os.listdir(tmp_path)) == ["warm"]


@pytest.mark.slow
def test_ctrl_c_twice_on_the_whole_process_group_neither_hangs_nor_prints_a_traceback(tmp_path):
    """A terminal's Ctrl-C reaches the workers too, and users press it twice: the
    second one used to land inside the pool's teardown and leave it waiting forever
    (reproduced during the leaderboard's identification, whose tasks are long)."""
    env = {**os.environ, "MPLBACKEND": "Agg", "STEPDAMP_CACHE_DIR": str(tmp_path / "cache")}
    subprocess.run([sys.executable, "-m", "stepdamp_env.cli", "sweep", "--speeds", "1:1.02:0.02",
                    "--out", str(tmp_path / "warm"), "--workers", "2", "--no-progress"],
                   check=True, capture_output=True, env=env)
    cmd = [sys.executable, "-m", "stepdamp_env.cli", "leaderboard", "--quick", "--no-plots",
           "--no-progress", "--workers", "2", "--out", str(tmp_path / "o")]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            env=env, preexec_fn=lambda: (os.setpgid(0, 0), signal.signal(
                                signal.SIGINT, signal.default_int_handler)))
    # Inside the pool (CI once sent it during the imports, where it was lost: the
    # next test): its workers are up, then a second for the tasks to start.
    deadline = time.monotonic() + (300.0 if _children(os.getpid()) is not None else 4.0)
    while len(_children(proc.pid) or []) < 2 and proc.poll() is None \
            and time.monotonic() < deadline:
        time.sleep(0.2)
    time.sleep(1.0)
    assert proc.poll() is None
    os.killpg(proc.pid, signal.SIGINT)         # the terminal's Ctrl-C, to every process
    os.kill(proc.pid, signal.SIGINT)           # and a second one to the impatient parent
    try:
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert err.strip().splitlines() == [
        "stepdamp leaderboard: interrupted; earlier results are unchanged (run the same "
        "command again to resume)"]


def _children(pid: int) -> list[int] | None:
    """The process's children (Linux's /proc), or None where the kernel does not
    list them."""
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as fh:
            return [int(x) for x in fh.read().split()]
    except OSError:
        return None


SWALLOWED = """
import os, signal, sys, weakref
from stepdamp_env.interrupts import interrupts_kept

class Thing:
    pass

def callback(ref):                  # Python ignores what a weakref callback raises
    os.kill(os.getpid(), signal.SIGINT)
    for _ in range(10000):
        pass

def swallow():
    thing = Thing()
    ref = weakref.ref(thing, callback)
    del thing
    print("went on", flush=True)

if sys.argv[1] == "kept":
    with interrupts_kept():
        swallow()
else:
    swallow()
print("finished", flush=True)
"""


@pytest.mark.parametrize("kept", [True, False])
def test_a_ctrl_c_swallowed_during_the_imports_still_interrupts(kept):
    """A Ctrl-C inside a weakref callback (the import system runs one) is ignored by
    Python; inside :func:`interrupts_kept` it interrupts at the block's end."""
    # Ctrl-C as a terminal's process has it (an xdist worker's children ignore it).
    out = subprocess.run([sys.executable, "-c", SWALLOWED, "kept" if kept else "plain"],
                         capture_output=True, text=True, timeout=120,
                         preexec_fn=lambda: signal.signal(signal.SIGINT,
                                                          signal.default_int_handler))
    assert "Exception ignored" in out.stderr and "KeyboardInterrupt" in out.stderr
    if kept:
        assert out.stdout.split() == ["went", "on"] and out.returncode != 0
        assert out.stderr.rstrip().endswith("KeyboardInterrupt")
    else:                               # the proof that the test could fail
        assert out.stdout.split() == ["went", "on", "finished"] and out.returncode == 0


AT_FORK = """
import os, signal, sys
from stepdamp_env.parallel import pool_map

def ctrl_c():                       # Python ignores what a fork callback raises
    os.kill(os.getpid(), signal.SIGINT)
    for _ in range(10000):
        pass

os.register_at_fork(before=ctrl_c)
try:
    if sys.argv[1] == "pool":
        pool_map(abs, list(range(8)), 2)
    else:
        if os.fork() == 0:
            os._exit(0)
        os.wait()
except KeyboardInterrupt:
    print("interrupted", flush=True)
    sys.exit(130)
print("finished", flush=True)
"""


@pytest.mark.parametrize("pool", [True, False])
def test_a_ctrl_c_while_the_pool_forks_still_interrupts(pool):
    """A Ctrl-C handled inside a fork callback (logging has one) is ignored by
    Python: CI once saw the leaderboard run on after a Ctrl-C that landed while a
    pool forked its workers. :func:`pool_map` hands it on after the fork."""
    out = subprocess.run([sys.executable, "-c", AT_FORK, "pool" if pool else "fork"],
                         capture_output=True, text=True, timeout=120,
                         preexec_fn=lambda: signal.signal(signal.SIGINT,
                                                          signal.default_int_handler))
    if pool:
        assert out.stdout.split() == ["interrupted"] and out.returncode == 130, out.stderr
        assert "Exception ignored" not in out.stderr
    else:                               # the proof that the test could fail
        assert "Exception ignored" in out.stderr and "KeyboardInterrupt" in out.stderr
        assert out.stdout.split() == ["finished"] and out.returncode == 0


def test_signals_deferred_hands_each_signal_once_to_the_handler_in_place():
    from stepdamp_env.interrupts import signals_deferred
    seen: list[int] = []
    previous = signal.signal(signal.SIGUSR1, lambda signum, frame: seen.append(signum))
    try:
        with signals_deferred((signal.SIGUSR1,)):
            os.kill(os.getpid(), signal.SIGUSR1)
            os.kill(os.getpid(), signal.SIGUSR1)
            for _ in range(1000):
                pass
            assert seen == []
        assert seen == [signal.SIGUSR1]
        os.kill(os.getpid(), signal.SIGUSR1)
        for _ in range(1000):
            pass
        assert seen == [signal.SIGUSR1] * 2
    finally:
        signal.signal(signal.SIGUSR1, previous)


# -- result files ------------------------------------------------------------------------
def test_a_failed_run_leaves_the_previous_results_whole(tmp_path):
    out = tmp_path / "res"
    with sio.staged_directory(out, ("a.json", "b.png")) as stage:
        sio.write_json(os.path.join(stage, "a.json"), {"run": 1})
        sio.write_text(os.path.join(stage, "b.png"), "old")
    (out / "mine.txt").write_text("keep")
    with pytest.raises(RuntimeError):
        with sio.staged_directory(out, ("a.json", "b.png")) as stage:
            sio.write_json(os.path.join(stage, "a.json"), {"run": 2})
            raise RuntimeError("killed before the figure")
    assert sio.json.loads((out / "a.json").read_text()) == {"run": 1}
    assert (out / "b.png").read_text() == "old"
    with sio.staged_directory(out, ("a.json", "b.png")) as stage:
        sio.write_json(os.path.join(stage, "a.json"), {"run": 3})
    # The new set replaces the old one whole (no stale b.png) and keeps foreign files.
    assert sorted(os.listdir(out)) == ["a.json", "mine.txt"]
    assert sorted(os.listdir(tmp_path)) == ["res"]


def test_leftovers_of_a_killed_run_are_removed(tmp_path):
    out = tmp_path / "res"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True).stdout.strip()
    leftover = tmp_path / f".res.staging-{dead}"
    leftover.mkdir()
    (leftover / ".a.json.tmp").write_text("half")
    with sio.staged_directory(out, ("a.json",)) as stage:
        sio.write_json(os.path.join(stage, "a.json"), {})
    assert sorted(os.listdir(tmp_path)) == ["res"]


def test_files_and_their_directory_are_fsynced(tmp_path, monkeypatch):
    synced = []
    real = os.fsync
    monkeypatch.setattr(sio.os, "fsync", lambda fd: (synced.append(os.readlink(
        f"/proc/self/fd/{fd}")), real(fd)))
    sio.write_text(tmp_path / "x.md", "text")
    assert any(p.startswith(str(tmp_path / ".x.")) for p in synced)     # the data
    assert str(tmp_path) in synced                                       # the rename


def test_pool_workers_die_with_their_parent(tmp_path):
    script = textwrap.dedent("""
        import time
        from stepdamp_env.parallel import pool_map
        def slow(x):
            time.sleep(60)
        pool_map(slow, list(range(8)), 2)
    """)
    parent = subprocess.Popen([sys.executable, "-c", script])
    deadline = time.time() + 30
    children: list[int] = []
    while time.time() < deadline and len(children) < 2:
        time.sleep(0.2)
        out = subprocess.run(["pgrep", "-P", str(parent.pid)], capture_output=True, text=True)
        children = [int(p) for p in out.stdout.split()]
    assert len(children) == 2
    parent.kill()
    parent.wait()
    time.sleep(1.0)
    alive = [p for p in children if os.path.exists(f"/proc/{p}")
             and open(f"/proc/{p}/stat").read().split()[2] != "Z"]
    assert alive == []
