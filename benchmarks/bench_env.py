"""Throughput of StepperDamp-v0 and -v1: scalar env steps/s and vector env-steps/s.

Run: ``PYTHONPATH=. python benchmarks/bench_env.py [--num-envs 64] [--seconds 3]``.
One process, one core (numba runs the batch serially), 1 kHz decisions, so every
env step simulates 20 PWM periods of 50 us. Targets: 20,000 scalar steps/s and
300,000 vector env-steps/s at N = 64 (v1: in every action mode, damping-gains with
every gain non-zero). Each rate is also given as a ratio to ``kernel.run_batch``
alone on the same drives, measured in the same run (the machines are noisy).
Compilation and the first reset are not timed.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import stepdamp_env  # noqa: F401  (registers StepperDamp-v0)
from stepdamp_env.env import StepperDampEnv, StepperDampV1VectorEnv, StepperDampVectorEnv


def bench_scalar(env, seconds: float) -> float:
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(1000,) + env.action_space.shape).astype(np.float32)
    env.reset(seed=0)
    for k in range(50):                             # warm-up (compiles)
        env.step(actions[k])
    steps = 0
    t0 = time.perf_counter()
    while True:
        for k in range(1000):
            _, _, term, trunc, _ = env.step(actions[k])
            if term or trunc:
                env.reset()
        steps += 1000
        dt = time.perf_counter() - t0
        if dt >= seconds:
            return steps / dt


def bench_vector(env, seconds: float, scale: float = 1.0) -> float:
    """Env-steps/s under random actions in [-scale, scale] (v1 gains at 0.2: episodes
    stay healthy, so resets cost what they cost in training)."""
    rng = np.random.default_rng(0)
    actions = rng.uniform(-scale, scale, size=(100,) + env.action_space.shape).astype(np.float32)
    env.reset(seed=0)
    for k in range(5):
        env.step(actions[k])
    steps = 0
    t0 = time.perf_counter()
    while True:
        for k in range(100):
            env.step(actions[k])
        steps += 100 * env.num_envs
        dt = time.perf_counter() - t0
        if dt >= seconds:
            return steps / dt


def bench_kernel_only(num_envs: int, seconds: float) -> float:
    """kernel.run_batch alone on the env's drives: the ceiling of the vector env."""
    import math

    from stepdamp_env import kernel as K
    from stepdamp_env.simulation import (RunSettings, SpeedProfile, build_config, initial_state,
                                         new_accumulators)

    venv = StepperDampVectorEnv(num_envs=num_envs)
    venv.reset(seed=0)
    # The same drives and speeds as the env's episodes, as plain kernel arrays.
    settings = RunSettings(base_controller="patent-ff")
    c = np.stack([build_config(system, SpeedProfile(speed_rps=float(v)), settings,
                               window_start_s=math.inf)
                  for system, v in zip(venv.systems, venv.speeds_rps)])
    s = np.stack([initial_state(row) for row in c])
    acc = new_accumulators(num_envs)
    u = np.zeros((num_envs, len(K.INPUT)))
    n = venv.sampler.n_periods
    K.run_batch(c, s, acc, u, n)
    steps = 0
    t0 = time.perf_counter()
    while True:
        for _ in range(100):
            K.run_batch(c, s, acc, u, n)
        steps += 100 * num_envs
        dt = time.perf_counter() - t0
        if dt >= seconds:
            return steps / dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--num-envs", type=int, default=64)
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--v1-only", action="store_true", help="measure the kernel and v1 only")
    args = ap.parse_args()
    n = args.num_envs
    ceiling = bench_kernel_only(n, args.seconds)
    print(f"kernel.run_batch alone N={n}  : {ceiling:>10,.0f} env-steps/s (ceiling, 1.00)")

    def show(label: str, rate: float) -> None:
        print(f"{label:32s}: {rate:>10,.0f} env-steps/s ({rate / ceiling:.2f} of the kernel)")

    if not args.v1_only:
        show("v0 scalar env (raw class)", bench_scalar(StepperDampEnv(), args.seconds))
        show("v0 scalar env (gym.make)", bench_scalar(gym.make("StepperDamp-v0"), args.seconds))
        for mode in ("harmonic", "current"):
            show(f"v0 vector N={n} ({mode})",
                 bench_vector(StepperDampVectorEnv(num_envs=n, action_mode=mode), args.seconds))
        show(f"v0 vector N={n} (gym.make_vec)",
             bench_vector(gym.make_vec("StepperDamp-v0", num_envs=n), args.seconds))
    for mode in ("damping-gains", "harmonic", "current", "harmonic+current"):
        venv = StepperDampV1VectorEnv(num_envs=n, action_mode=mode)
        show(f"v1 vector N={n} ({mode})", bench_vector(venv, args.seconds, 0.2))
    venv = StepperDampV1VectorEnv(num_envs=n, history=8, context="visible")
    show(f"v1 vector N={n} (gains, h=8, ctx)", bench_vector(venv, args.seconds, 0.2))
    # Randomised motors: every reset draws and validates a new motor (about 1 ms).
    venv = StepperDampV1VectorEnv(num_envs=n, randomize=True)
    show(f"v1 vector N={n} (gains, randomize)", bench_vector(venv, args.seconds, 0.2))
    show(f"v1 vector N={n} (gym.make_vec)",
         bench_vector(gym.make_vec("StepperDamp-v1", num_envs=n), args.seconds, 0.2))
    # v2 decides at 100 Hz: a step is 10 ms of drive time (200 PWM periods), so its
    # rate is given as env-steps/s and as simulated seconds per second (x real time).
    for simd in (False, True):
        venv = gym.make_vec("StepperDamp-v2", num_envs=n, simd=simd)
        rate = bench_vector(venv, args.seconds, 0.2)
        lanes = ", SIMD lanes" if simd else ""
        print(f"v2 vector N={n} (defaults{lanes}): {rate:>10,.0f} env-steps/s = "
              f"{rate * 0.01:,.0f} x real time on one core")


if __name__ == "__main__":
    main()
