"""Scale: leaderboard throughput against the kernel, and SB3 training throughput.

Run: ``PYTHONPATH=. python benchmarks/bench_scale.py [--workers 2] [--skip-board]
[--skip-training]``.

Everything is measured in this run, on this machine:

* the single-core kernel rate (``benchmarks/bench_sim.py``'s measurement: the
  patent preset in open loop, 20 kHz PWM, simulated s per wall s);
* the full stepdamp-bench v1 leaderboard, every baseline and every reference
  agent (every training seed), three ways: *before*, the scalar runner
  (``runner="scalar"``: each run alone, as up to 0.7.0) without the
  identification cache; *after, cold*, the batched runner with an empty
  identification cache; *after, warm*, the batched runner once the cache is
  filled. Each prints the board's ``wall_seconds`` (identification and runs,
  no imports or figures), ``simulated_seconds`` and the efficiency: simulated
  seconds per wall second over (workers x the kernel rate). Targets on 2 cores:
  efficiency >= 0.3, full board < 300 s, model-based baselines alone < 60 s;
* training throughput: SB3 on the native vector env (one process: numba steps
  the drives, torch updates the network on ``--workers`` threads), env-steps
  per wall second: each algorithm as ``stepdamp train`` runs it with its
  committed settings (StepperDamp-v1 at 100 Hz; a short run, no validation),
  then PPO with throughput settings (512 drives, 32-step rollouts, one epoch
  of 8192-sample batches) on StepperDamp-v1 at 100 Hz and 1 kHz and on
  StepperDamp-v0 (1 kHz). Target: PPO at least 100,000 env-steps/s.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def kernel_rate() -> float:
    """bench_sim.py's single-core kernel rate (median of 3, simulated s per wall s)."""
    spec = importlib.util.spec_from_file_location(
        "bench_sim", os.path.join(ROOT, "benchmarks", "bench_sim.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return float(module.measure(10.0, 3, 1.0, "patent")["median"])


def board(policies, runner: str, workers: int, cache: str) -> dict:
    from stepdamp_env.bench import full_protocol_v1, run_leaderboard

    os.environ["STEPDAMP_CACHE_DIR"] = cache
    return run_leaderboard(full_protocol_v1(), policies, workers=workers, progress=False,
                           runner=runner)


def bench_boards(workers: int, rate: float) -> None:
    from stepdamp_baselines import BASELINE_NAMES
    from stepdamp_env.bench import default_policy_names

    every = list(default_policy_names())
    baselines = [n for n in every if n in BASELINE_NAMES]
    with tempfile.TemporaryDirectory() as tmp:
        cache = os.path.join(tmp, "cache")
        runs = [("before: scalar runner, no cache", every, "scalar", "off", 300.0),
                ("after: batched, cold cache", every, "batched", cache, 300.0),
                ("after: batched, warm cache", every, "batched", cache, 300.0),
                ("after: baselines only, warm", baselines, "batched", cache, 60.0)]
        boards = {}
        for label, policies, runner, where, target in runs:
            b = board(policies, runner, workers, where)
            wall, sim = b["wall_seconds"], b["simulated_seconds"]
            eff = sim / wall / (workers * rate)
            status = "ok" if wall < target and eff >= 0.3 else "BELOW TARGET"
            print(f"{label:34s}: wall {wall:6.1f} s (target < {target:.0f}), simulated "
                  f"{sim:7.0f} s, {sim / wall:5.0f} sim s/s, efficiency {eff:.2f} "
                  f"(target >= 0.30) {status}", flush=True)
            boards[label] = b
        same = all(boards[k]["entries"] == boards["before: scalar runner, no cache"]["entries"]
                   for k in ("after: batched, cold cache", "after: batched, warm cache"))
        print(f"batched boards equal the scalar board: {same}")


def bench_training(threads: int) -> None:
    """Env-steps per wall second of SB3 training on the native vector env."""
    import dataclasses

    import torch
    from stable_baselines3 import PPO

    from stepdamp_agents.train import Args, train
    from stepdamp_env.sb3 import make_sb3_vec_env, make_sb3_vec_env_v1

    torch.set_num_threads(threads)
    # 1. Each algorithm as `stepdamp train` runs it (the committed YAML settings,
    # StepperDamp-v1 at 100 Hz), a short run without validation or checkpoints.
    budgets = {"ars": 240_000, "ppo": 64_000, "td3": 16_000, "sac": 16_000}
    with tempfile.TemporaryDirectory() as tmp:
        for algo, steps in budgets.items():
            args = Args(algo=algo, out=os.path.join(tmp, algo), total_timesteps=steps,
                        eval_freq=0, checkpoint_freq=0, progress=False, tensorboard=False)
            if algo in ("sac", "td3"):       # learn from the first step (the YAML waits 32k)
                args = dataclasses.replace(args, extra={"learning_starts": 0})
            log = train(args)
            rate = steps / log["train_wall_s"]
            print(f"train {algo} (committed settings, v1 at 100 Hz, {log['n_envs']} drives): "
                  f"{rate:9.0f} env-steps/s", flush=True)
    # 2. PPO with throughput settings: 512 drives per compiled call, 32 steps per
    # rollout, one epoch of batches of 8192.
    envs = {"StepperDamp-v1, 100 Hz": lambda: make_sb3_vec_env_v1(num_envs=512, agent_hz=100.0),
            "StepperDamp-v1, 1 kHz": lambda: make_sb3_vec_env_v1(num_envs=512,
                                                                  agent_hz=1000.0),
            "StepperDamp-v0, 1 kHz": lambda: make_sb3_vec_env(num_envs=512,
                                                              action_mode="harmonic")}
    for label, make in envs.items():
        venv = make()
        model = PPO("MlpPolicy", venv, n_steps=32, batch_size=8192, n_epochs=1, seed=0,
                    verbose=0, device="cpu")
        model.learn(512 * 32)                                  # warm-up (compiles)
        steps = 512 * 32 * 12
        t0 = time.perf_counter()
        model.learn(steps, reset_num_timesteps=False)
        rate = steps / (time.perf_counter() - t0)
        print(f"train ppo (throughput settings, {label}, 512 drives): {rate:9.0f} env-steps/s "
              f"(target >= 100,000)", flush=True)
        venv.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--skip-board", action="store_true")
    parser.add_argument("--skip-training", action="store_true")
    args = parser.parse_args()
    sys.path.insert(0, ROOT)
    import stepdamp_agents
    import stepdamp_baselines

    stepdamp_baselines.register_policies()
    stepdamp_agents.register_policies()
    rate = kernel_rate()
    print(f"kernel: {rate:.0f} x real time on one core (patent preset, open loop, 20 kHz PWM); "
          f"workers {args.workers}: 0.3 x workers x kernel = {0.3 * args.workers * rate:.0f} "
          "simulated s per wall s", flush=True)
    if not args.skip_board:
        bench_boards(args.workers, rate)
    if not args.skip_training:
        bench_training(args.workers)


if __name__ == "__main__":
    main()
