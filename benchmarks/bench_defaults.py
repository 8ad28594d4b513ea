"""Do StepperDamp's defaults learn? SB3's PPO, SAC and TD3 with their library
defaults on ``make_vec_env(ENV, n_envs=8)``, several seeds, against the zero action.

Run: ``python benchmarks/bench_defaults.py [--env StepperDamp-v3] [--steps 100000]
[--seeds 1-5] [--algos ppo sac td3]``.

Each run trains ``--steps`` env steps (over all 8 envs) from the algorithm's
defaults (``Algo("MlpPolicy", env, seed=seed)``, nothing tuned), then plays the
mean action (also before training: "untrained") on ``--eval-episodes`` fixed episodes (seeds from 2,000,000: never a
training seed) and compares the return with the zero action's on the same
episodes (the base controller alone). It prints one line per run and, per
algorithm, how many seeds improved and the mean improvement with a 95 %
interval over seeds (t-distribution). Not a test: minutes per run.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
import warnings

import gymnasium as gym
import numpy as np

EVAL_SEED = 2_000_000


def episode_returns(env_id: str, episodes: int, act) -> np.ndarray:
    """Each fixed evaluation episode's return under ``act(obs batch) -> actions``."""
    env = gym.make_vec(env_id, num_envs=episodes, vectorization_mode="vector_entry_point")
    with warnings.catch_warnings():     # evaluation only: never trained on (v2 warns)
        warnings.filterwarnings("ignore", message=".*draw the motors stepdamp-bench scores")
        obs, _ = env.reset(seed=[EVAL_SEED + k for k in range(episodes)])
    total = np.zeros(episodes)
    done = np.zeros(episodes, dtype=bool)
    while not done.all():
        obs, reward, term, trunc, _ = env.step(act(obs))
        total += np.where(done, 0.0, reward)
        done |= term | trunc
    env.close()
    return total


def t_interval(values: list[float]) -> tuple[float, float, float]:
    """Mean and its 95 % interval (Student's t over the values)."""
    from scipy import stats

    m = statistics.fmean(values)
    if len(values) < 2:
        return m, math.nan, math.nan
    half = stats.t.ppf(0.975, len(values) - 1) * statistics.stdev(values) / math.sqrt(len(values))
    return m, m - half, m + half


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env", default="StepperDamp-v3")
    p.add_argument("--steps", type=int, default=100_000)
    p.add_argument("--seeds", default="1-5")
    p.add_argument("--algos", nargs="+", default=["ppo", "sac", "td3"])
    p.add_argument("--eval-episodes", type=int, default=32)
    p.add_argument("--env-kwargs", default="{}", help="a Python dict of env options")
    args = p.parse_args()
    import ast

    import stepdamp_env  # noqa: F401  (registers the envs)
    import torch
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.env_util import make_vec_env

    torch.set_num_threads(1)
    lo, _, hi = args.seeds.partition("-")
    seeds = list(range(int(lo), int(hi or lo) + 1))
    kwargs = ast.literal_eval(args.env_kwargs)
    env_id = args.env
    if kwargs:                          # an id of its own for these options
        env_id = f"Bench{args.env}"
        spec = gym.spec(args.env)
        gym.register(env_id, entry_point=spec.entry_point,
                     vector_entry_point=spec.vector_entry_point,
                     kwargs={**spec.kwargs, **kwargs})
    algos = {"ppo": PPO, "sac": SAC, "td3": TD3}
    probe = gym.make(env_id)
    zero = np.zeros((args.eval_episodes, *probe.action_space.shape), dtype=np.float32)
    probe.close()
    zero_returns = episode_returns(env_id, args.eval_episodes, lambda obs: zero)
    print(f"{env_id} {kwargs or ''}: zero action return {zero_returns.mean():.3f} "
          f"over {args.eval_episodes} episodes; {args.steps} env steps per run on 8 envs")
    for name in args.algos:
        gains = []
        for seed in seeds:
            t0 = time.perf_counter()
            env = make_vec_env(env_id, n_envs=8, seed=seed)
            model = algos[name]("MlpPolicy", env, seed=seed, device="cpu")
            start = episode_returns(env_id, args.eval_episodes,
                                    lambda obs: model.predict(obs, deterministic=True)[0])
            model.learn(args.steps)
            env.close()
            wall = time.perf_counter() - t0
            got = episode_returns(env_id, args.eval_episodes,
                                  lambda obs: model.predict(obs, deterministic=True)[0])
            gain = float(got.mean() - zero_returns.mean())
            gains.append(gain)
            print(f"  {name} seed {seed}: return {got.mean():9.3f} (zero action "
                  f"{zero_returns.mean():.3f}, untrained {start.mean():.3f}), gain "
                  f"{gain:+8.3f}, paired better on "
                  f"{int((got > zero_returns).sum())}/{args.eval_episodes} episodes; "
                  f"{wall:.0f} s, {args.steps / wall:,.0f} env-steps/s", flush=True)
        m, low, high = t_interval(gains)
        print(f"{name}: improved on {sum(g > 0 for g in gains)}/{len(gains)} seeds; "
              f"mean gain {m:+.3f} [{low:+.3f}, {high:+.3f}] (95 % over seeds)", flush=True)


if __name__ == "__main__":
    main()
