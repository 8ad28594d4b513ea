"""Throughput of StepperDamp-v0: scalar env steps/s and vector env-steps/s.

Run: ``PYTHONPATH=. python benchmarks/bench_env.py [--num-envs 64] [--seconds 3]``.
One process, one core (numba runs the batch serially), 1 kHz decisions, so every
env step simulates 20 PWM periods of 50 us. Targets: 20,000 scalar steps/s and
300,000 vector env-steps/s at N = 64. Compilation and the first reset are not timed.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import stepdamp_env  # noqa: F401  (registers StepperDamp-v0)
from stepdamp_env.env import StepperDampEnv, StepperDampVectorEnv


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


def bench_vector(env, seconds: float) -> float:
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(100,) + env.action_space.shape).astype(np.float32)
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
    settings = RunSettings(damping="patent-ff")
    c = np.stack([build_config(system, SpeedProfile(speed_rps=float(v)), settings,
                               window_start_s=math.inf)
                  for system, v in zip(venv.systems, venv.speeds_rps)])
    s = np.stack([initial_state(row) for row in c])
    acc = new_accumulators(num_envs)
    u = np.zeros((num_envs, K.N_INPUT))
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
    args = ap.parse_args()
    raw = StepperDampEnv()
    print(f"scalar env (raw class)          : {bench_scalar(raw, args.seconds):>10,.0f} steps/s")
    made = gym.make("StepperDamp-v0")
    print(f"scalar env (gym.make, wrappers) : {bench_scalar(made, args.seconds):>10,.0f} steps/s")
    for mode in ("harmonic", "current"):
        venv = StepperDampVectorEnv(num_envs=args.num_envs, action_mode=mode)
        rate = bench_vector(venv, args.seconds)
        print(f"vector env N={args.num_envs} ({mode:8s})      : {rate:>10,.0f} env-steps/s")
    rate = bench_kernel_only(args.num_envs, args.seconds)
    print(f"kernel.run_batch alone N={args.num_envs}  : {rate:>10,.0f} env-steps/s (ceiling)")
    venv = gym.make_vec("StepperDamp-v0", num_envs=args.num_envs)
    rate = bench_vector(venv, args.seconds)
    print(f"vector env N={args.num_envs} (gym.make_vec)   : {rate:>10,.0f} env-steps/s")


if __name__ == "__main__":
    main()
