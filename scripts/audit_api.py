"""Audit of the Python API, the vector env over time, and killed runs.

    python scripts/audit_api.py probes              # about 700 hand-made API mistakes
    python scripts/audit_api.py soak --seconds 330  # the native vector env, random actions
    python scripts/audit_api.py kills --count 35    # kill -9 during sweeps and leaderboards

``probes``: every field of ``SystemParams`` and every option of ``StepperDamp-v0``
and of ``simulate`` (``SpeedProfile``, ``RunSettings``) gets bad values (None, a
word, a bool, NaN, +-inf, a 400-digit integer, a list, just outside each end of its
range), numpy scalars of a good value, and the env gets bad actions and reset
arguments; copies (pickle, deepcopy) of the scalar env must have the same future
as the original. A probe is ``clean`` when a mistake raises ``ParameterError`` (a
``ValueError``: bad actions raise ``ValueError`` as Gymnasium spaces do) or one of
Gymnasium's errors (``ResetNeeded``, a bad seed) with a one-line message, or a good value is
accepted and three env steps (or a short run) give finite numbers; anything else
(another exception, several lines, NaN, a frozen copy) is counted by class.

``soak``: 64 drives of the native vector env, random actions, randomised motors,
for ``--seconds``; counts steps and non-finite numbers, and the resident memory
after 10 % of the time and at the end.

``kills``: a first run writes results into a directory; then each round starts
``stepdamp sweep`` (two thirds) or ``stepdamp leaderboard --quick`` into the same
directory, kills the main process with SIGKILL at a random time, and checks
that the result files are all the old ones or all new ones (inodes), that every
JSON file parses, that the pool workers are gone within 2 s, and, after one more
complete run, that no staging directory or temporary file is left.
"""

from __future__ import annotations

import argparse
import copy
import glob
import json
import math
import os
import pickle
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import fields
from typing import Any, Callable

import numpy as np

# ---------------------------------------------------------------------------
# probes
# ---------------------------------------------------------------------------
BAD_COMMON = [None, "1.0", True, float("nan"), float("inf"), -float("inf"), 10 ** 400, [1.0],
              {"x": 1}]


def _classify(run: Callable[[], Any], mistake: bool) -> tuple[str, str]:
    import gymnasium as gym

    from stepdamp_env.params import ParameterError

    try:
        out = run()
    except (ParameterError, ValueError, gym.error.Error) as exc:
        text = str(exc)
        if "\n" in text.strip() or not text.strip():
            return "several lines", text[:160]
        return ("clean" if mistake else "refused a good value"), text[:160]
    except Exception as exc:       # noqa: BLE001 - counting what escapes is the point
        return f"raises {type(exc).__name__}", str(exc)[:160]
    if out is False:
        return "non-finite result", ""
    return ("accepted a mistake" if mistake else "clean"), ""


def _finite(*arrays: Any) -> bool:
    return all(np.all(np.isfinite(np.asarray(a, dtype=np.float64))) for a in arrays)


def _env_steps(**options: Any) -> bool:
    from stepdamp_env.env import StepperDampEnv

    env = StepperDampEnv(**options)
    obs, _ = env.reset(seed=0)
    ok = _finite(obs)
    for _ in range(3):
        obs, r, term, trunc, info = env.step(env.action_space.sample() * 0)
        ok &= _finite(obs, r, [v for v in info.values() if not isinstance(v, bool)])
        if term:
            break
    return ok


def _outside(a: Any) -> list[float]:
    vals = []
    if math.isfinite(a.low):
        vals.append(a.low - max(1.0, abs(a.low)) * 1e-3 if not a.low_open else a.low)
    if math.isfinite(a.high):
        vals.append(a.high + max(1.0, abs(a.high)) * 1e-3 if not a.high_open else a.high)
    if a.integer:
        lo = a.low if math.isfinite(a.low) else 0.0
        vals.append(lo + 0.5)
    return vals


def probes() -> Counter:
    import gymnasium as gym

    import stepdamp_env  # noqa: F401  (registers the env)
    from stepdamp_env.env import EnvOptions, StepperDampEnv
    from stepdamp_env.params import SystemParams
    from stepdamp_env.presets import get_preset
    from stepdamp_env.simulation import RunSettings, SpeedProfile, simulate

    cases: list[tuple[str, Callable[[], Any], bool]] = []
    base = get_preset("patent")
    d0 = base.to_dict()

    def system_case(name: str, value: Any, mistake: bool) -> Callable[[], Any]:
        def run() -> Any:
            s = SystemParams.from_dict({**d0, name: value})
            r = simulate(s, speed_rps=1.0, settings=RunSettings(settle_s=0.0, window_s=0.01),
                         duration_s=0.05)
            return _finite(list(r.metrics.to_dict()["harmonic_amplitude_rad_s"].values()),
                           r.final_state, r.metrics.rms_velocity_error_rad_s)
        return run

    # 1. every SystemParams field
    for cls in (type(base.motor), type(base.drive)):
        for f in fields(cls):
            a = f.metadata.get("allowed")
            if a is None:
                continue
            good = d0[f.name]
            optional = good is None
            for v in BAD_COMMON + _outside(a):
                if v is None and optional:
                    continue
                cases.append((f"system {f.name}={v!r:.30}", system_case(f.name, v, True), True))
            if good is not None:
                for v in (np.float32(good) if not a.integer else np.int64(good),
                          np.float64(good)):
                    if a.integer and isinstance(v, np.floating):
                        v = np.float64(int(good))
                    cases.append((f"system {f.name}={type(v).__name__}",
                                  system_case(f.name, v, False), False))

    # 2. every env option
    bad_opts: dict[str, list[Any]] = {
        "motor": [None, 3, "no-such-motor", [], "/"],
        "overrides": ["J=1", [1], {"J": None}, {"J": "x"}, {"nope": 1}, {"J": float("nan")}],
        "randomize": ["yes", 1.5, {"J": (1, 2, 3)}, {"J": (2.0, 1.0)}, {"nope": (0.9, 1.1)}],
        "mode": [None, "closed", 1],
        "base_controller": [None, "pid", 1],
        "estimate": [None, "guess", 1],
        "speed_rps": ["1", True, float("nan"), float("inf"), 0.0, 1e-9, 1e9, -1e9],
        "speed_range_rps": [None, (1.0,), (2.0, 1.0), (0.0, 1.0), (1.0, float("nan")),
                            (1.0, 1e9), "0.5:1"],
        "resonance_prob": [None, -0.1, 1.1, float("nan"), "0.5"],
        "resonance_spread": [None, -0.1, float("inf"), "x"],
        "accel_rps2": [None, 0.0, -1.0, float("nan"), float("inf"), 1e6, "50"],
        "action_mode": [None, "torque", 2],
        "agent_hz": [None, 0.0, -1.0, 0.5, float("nan"), 1e12, "1000"],
        "harmonic_scale_nm": [0.0, -1.0, float("nan"), float("inf"), "x"],
        "current_scale_a": [0.0, -1.0, float("nan"), float("inf"), "x"],
        "current_penalty": [None, -1.0, float("nan"), float("inf"), "x"],
        "termination_penalty": [None, -1.0, float("nan"), float("inf"), "x"],
        "current_limit_factor": [None, 0.0, -1.0, float("nan"), float("inf"), "x"],
        "privileged": [None, "yes", 2, 1.0],
        "substeps": [None, 0, -1, 1.5, 10 ** 6, float("nan"), "2", True],
        "velocity_estimator": [None, "magic", 3],
        "measure_from_s": [-1.0, float("nan"), float("inf"), "x", True],
    }
    names = {f.name for f in fields(EnvOptions)}
    assert set(bad_opts) == names, names ^ set(bad_opts)
    for name, values in bad_opts.items():
        for v in values:
            cases.append((f"env {name}={v!r:.30}",
                          (lambda n=name, v=v: _env_steps(**{n: v})), True))
    good_opts = {"speed_rps": [np.float32(1.0), np.int64(2)], "agent_hz": [np.int64(2000)],
                 "substeps": [np.int64(2)], "resonance_prob": [np.float32(0.25)],
                 "privileged": [np.bool_(True)], "accel_rps2": [np.float32(100.0), 1e-300],
                 "overrides": [{"J": np.float32(d0["J"])}, {"encoder_cpr": np.int64(4000)}]}
    for name, values in good_opts.items():
        for v in values:
            cases.append((f"env {name}={type(v).__name__}",
                          (lambda n=name, v=v: _env_steps(**{n: v})), False))
    cases.append(("env unknown option", lambda: _env_steps(nope=1), True))
    cases.append(("gym.make unknown option", lambda: gym.make("StepperDamp-v0", nope=1), True))

    # 3. actions and reset arguments
    def stepped(action: Any, mode: str = "harmonic") -> Callable[[], Any]:
        def run() -> Any:
            env = StepperDampEnv(action_mode=mode)
            env.reset(seed=0)
            return _finite(env.step(action)[0])
        return run

    for mode, k in (("harmonic", 6), ("current", 1), ("harmonic+current", 7)):
        for a in ([np.nan] * k, [np.inf] * k, [-np.inf] * k, [0.0] * (k + 1), [[0.0] * k] * 2,
                  "zero", None, [1e300] * k, np.full(k, np.nan, np.float32), np.full(k, 2.0),
                  {"a": 1}, [None] * k, [0.0] * (k - 1) if k > 1 else []):
            cases.append((f"step {mode} {str(a)[:30]}", stepped(a, mode), True))
        for a in (np.zeros(k, np.float32), np.ones(k), [0.5] * k, -np.ones(k, np.float64)):
            cases.append((f"step {mode} good {str(a)[:30]}", stepped(a, mode), False))

    def never_reset() -> Any:
        env = StepperDampEnv()
        env.step(np.zeros(6, np.float32))

    def after_termination() -> Any:
        env = StepperDampEnv(speed_rps=1.0, overrides={"load_torque": 5.0})
        env.reset(seed=0)
        for _ in range(300):
            if env.step(np.zeros(6, np.float32))[2]:
                break
        env.step(np.zeros(6, np.float32))

    cases += [("step before reset", never_reset, True),
              ("step after termination", after_termination, True)]
    for seed in (-1, 1.5, "1", float("nan")):
        cases.append((f"reset seed={seed!r}",
                      (lambda s=seed: StepperDampEnv().reset(seed=s)), True))
    for seed in (0, 2 ** 80, None):
        cases.append((f"reset seed={seed!r}",
                      (lambda s=seed: _finite(StepperDampEnv().reset(seed=s)[0])), False))

    # 4. simulate: SpeedProfile and RunSettings
    def sim(profile: dict[str, Any] | None = None, settings: dict[str, Any] | None = None,
            duration: Any = 0.3) -> Callable[[], Any]:
        def run() -> Any:
            p = SpeedProfile(**{"speed_rps": 1.0, **(profile or {})})
            s = RunSettings(**{"settle_s": 0.0, "window_s": 0.01, **(settings or {})})
            r = simulate(base, profile=p, settings=s, duration_s=duration)
            return _finite(r.final_state, r.metrics.rms_velocity_error_rad_s)
        return run

    for key, values in {"speed_rps": [None, "1", float("nan"), float("inf"), 1e-9, 1e9, True],
                        "accel_rps2": [0.0, -1.0, float("nan"), float("inf"), "x", None],
                        "kind": ["jump", None, 1],
                        "distance_rev": [float("nan"), float("inf"), "x"]}.items():
        for v in values:
            cases.append((f"SpeedProfile {key}={v!r:.30}", sim(profile={key: v}), True))
    for key, values in {"mode": ["x", None], "base_controller": ["x", None, 1],
                        "substeps": [0, -1, 1.5, 10 ** 6, "1", None, True],
                        "settle_s": [-1.0, float("nan"), float("inf"), "x"],
                        "window_s": [0.0, -1.0, float("nan"), float("inf"), "x", None],
                        "estimate": ["x", 1, "guess"],
                        "velocity_estimator": ["x", None],
                        "noise_seed": [-1, 1.5, "x", 2 ** 80, None, float("nan")]}.items():
        for v in values:
            cases.append((f"RunSettings {key}={v!r:.30}", sim(settings={key: v}), True))
    for v in (0.0, -1.0, float("nan"), float("inf"), "x", 1e-6):
        cases.append((f"simulate duration_s={v!r}", sim(duration=v), True))
    cases.append(("simulate motor name unknown",
                  lambda: simulate("no-such-motor", speed_rps=1.0), True))

    # 5. copies have the same future
    def copies(how: Callable[[Any], Any]) -> Callable[[], Any]:
        def run() -> Any:
            env = StepperDampEnv(randomize=True)
            env.reset(seed=3)
            twin = how(env)
            rng = np.random.default_rng(0)
            for _ in range(20):
                a = rng.uniform(-1, 1, 6).astype(np.float32)
                o1, r1, *_ = env.step(a)
                o2, r2, *_ = twin.step(a)
                if not (np.array_equal(o1, o2) and r1 == r2):
                    return False
            return True
        return run

    cases.append(("pickle scalar env", copies(lambda e: pickle.loads(pickle.dumps(e))), False))
    cases.append(("deepcopy scalar env", copies(copy.deepcopy), False))

    counts: Counter = Counter()
    for label, run, mistake in cases:
        cls, msg = _classify(run, mistake)
        counts[cls] += 1
        if cls != "clean":
            print(f"{label}: {cls}: {msg}")
    print(f"api probes: {len(cases)} cases, " + ", ".join(f"{n} {k}" for k, n in
                                                          counts.most_common()))
    return counts


# ---------------------------------------------------------------------------
# soak
# ---------------------------------------------------------------------------
def _rss_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def soak(seconds: float) -> None:
    from stepdamp_env.env import StepperDampVectorEnv

    env = StepperDampVectorEnv(64, randomize=True, action_mode="harmonic+current")
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    steps = bad = episodes = 0
    t0 = time.perf_counter()
    rss_early = None
    while (elapsed := time.perf_counter() - t0) < seconds:
        a = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
        obs, r, term, trunc, info = env.step(a)
        steps += env.num_envs
        episodes += int(np.sum(term | trunc))
        bad += int(np.sum(~np.isfinite(obs))) + int(np.sum(~np.isfinite(r)))
        if rss_early is None and elapsed > 0.1 * seconds:
            rss_early = _rss_mb()
    if rss_early is None:
        rss_early = _rss_mb()
    print(f"soak: {seconds:.0f} s, {steps / 1e6:.1f}M env steps, {episodes} episodes ended, "
          f"{bad} non-finite numbers, RSS {rss_early:.1f} MB at 10 % -> {_rss_mb():.1f} MB "
          "at the end")


# ---------------------------------------------------------------------------
# kills
# ---------------------------------------------------------------------------
SWEEP = ["sweep", "--speeds", "0.3:3:0.02", "--base-controller", "none", "patent-ff", "--no-progress",
         "--workers", "2"]
BOARD = ["leaderboard", "--quick", "--no-progress", "--workers", "2"]


def _results(out: str) -> dict[str, int]:
    return {os.path.basename(p): os.stat(p).st_ino for p in glob.glob(os.path.join(out, "*"))
            if os.path.isfile(p) and not os.path.basename(p).startswith(".")}


def _children_alive(pgid: int) -> int:
    alive = 0
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/stat") as fh:
                stat = fh.read().rsplit(")", 1)[1].split()
            if int(stat[2]) == pgid and stat[0] != "Z":
                alive += 1
        except (OSError, IndexError, ValueError):
            pass
    return alive


def kills(count: int, seed: int) -> None:
    rnd = random.Random(seed)
    work = tempfile.mkdtemp(prefix="stepdamp-kills-")
    env = dict(os.environ, MPLBACKEND="Agg")
    cli = [sys.executable, "-m", "stepdamp_env.cli"]
    dirs = {"sweep": os.path.join(work, "sweep"), "leaderboard": os.path.join(work, "board")}
    for kind, argv in (("sweep", SWEEP), ("leaderboard", BOARD)):
        subprocess.run(cli + argv + ["--out", dirs[kind]], env=env, check=True,
                       stdout=subprocess.DEVNULL)
    tally: Counter = Counter()
    try:
        for k in range(count):
            kind = "sweep" if k % 3 else "leaderboard"
            argv, out = (SWEEP if kind == "sweep" else BOARD), dirs[kind]
            before = _results(out)
            proc = subprocess.Popen(cli + argv + ["--out", out], env=env, start_new_session=True,
                                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            time.sleep(rnd.uniform(0.5, 6.0 if kind == "sweep" else 30.0))
            os.kill(proc.pid, signal.SIGKILL)         # the main process only
            proc.wait()
            time.sleep(2.0)
            orphans = _children_alive(proc.pid)
            after = _results(out)
            same = sum(after.get(n) == i for n, i in before.items())
            whole = set(after) == set(before) and same in (0, len(before))
            parses = True
            for name in after:
                if name.endswith(".json"):
                    try:
                        with open(os.path.join(out, name)) as fh:
                            json.load(fh)
                    except (OSError, ValueError):
                        parses = False
            state = "old" if same == len(before) else "new" if same == 0 else "mixed"
            tally["kills"] += 1
            tally[f"results {state}"] += 1
            tally["orphan workers"] += int(orphans > 0)
            tally["unparsable json"] += int(not parses)
            tally["not a whole set"] += int(not whole)
            if orphans:
                os.killpg(proc.pid, signal.SIGKILL)
            print(f"kill {k + 1:2d} {kind:11s}: results {state}, {orphans} workers alive after 2 s")
        for kind, argv in (("sweep", SWEEP), ("leaderboard", BOARD)):
            subprocess.run(cli + argv + ["--out", dirs[kind]], env=env, check=True,
                           stdout=subprocess.DEVNULL)
        left = [p for p in glob.glob(os.path.join(work, "**", ".*"), recursive=True)
                + glob.glob(os.path.join(work, "**", "*.tmp*"), recursive=True)]
        tally["left over after the next run"] = len(left)
        print("left over:", left or "nothing")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print("kills: " + ", ".join(f"{k} {v}" for k, v in tally.items()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    sub.add_parser("probes", help="hand-made API mistakes")
    p = sub.add_parser("soak", help="the native vector env over time")
    p.add_argument("--seconds", type=float, default=330.0)
    p = sub.add_parser("kills", help="kill -9 during sweeps and leaderboards")
    p.add_argument("--count", type=int, default=35)
    p.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.what == "probes":
        probes()
    elif args.what == "soak":
        soak(args.seconds)
    else:
        kills(args.count, args.seed)


if __name__ == "__main__":
    main()
