"""Performance: the kernel's rate, and the board's and PPO's share of it, in one run.

Run: ``PYTHONPATH=. python benchmarks/bench_performance.py [--cores 2] [--skip-board]
[--skip-ppo] [--skip-lanes] [--ttq-seeds 21-25] [--ttq-suites open-loop moves]``.

Everything is measured in this run, one thing after the other:

* **kernel**: ``benchmarks/bench_sim.py``'s single-core rate, in a process pinned
  to one core (the patent preset in open loop at 1 rev/s, 20 kHz PWM, RK4, no
  trace): simulated seconds per wall second, median of 3.
* **board**: ``stepdamp leaderboard`` (the default protocol, full) with
  ``--workers cores``, caches warm (a first run fills them). Efficiency =
  ``simulated_seconds / wall_seconds / (cores x kernel)``; ``wall_seconds`` is the
  board's own (motors, identification, runs, scores; no imports or figures), and
  the end-to-end time is printed beside it. Target: >= 0.5.
* **lanes**: ``benchmarks/bench_simd.py``'s rates per drive variant (64 drives,
  one pinned core), the kernel's and the SIMD lanes', and whether their bits agree.
* **PPO**: SB3's PPO on ``StepperDamp-v1`` at 100 Hz (0.01 s simulated per env
  step), throughput settings (512 drives, 32-step rollouts, one epoch of batches
  of 8192; torch on one thread), updates included, with the drives on one of
  numba's threads (as before 0.15.0) and on ``cores``, without and with SIMD lanes
  (``simd``, 0.16.0). Then ``stepdamp train
  --algo ppo --num-threads N`` with the committed settings (32 drives, 100-step
  rollouts, ten epochs of 400), whose ``training.json`` gives the same ratio. Efficiency =
  ``env-steps/s x 0.01 s / (cores x kernel)``. Target: >= 0.5.
* **time to quality** (``--ttq-seeds``, ``--ttq-suites``): ``benchmarks/time_to_quality.py``,
  PPO's training wall time until a dev check reaches `tuned-constant-gain`'s dev
  attenuation in the open-loop suite (the committed config against a faster
  one) and in the moves suite (`ppo-moves`'s config against the same with the
  open-loop entry's collection and updates).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
KERNEL = ("import os, importlib.util, json, sys; os.sched_setaffinity(0, {int(sys.argv[1])}); "
          "spec = importlib.util.spec_from_file_location('bench_sim', sys.argv[2]); "
          "m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m); "
          "print(json.dumps(m.measure(10.0, 3, 1.0, 'patent')))")


def _env() -> dict[str, str]:
    return {**os.environ, "MPLBACKEND": "Agg",
            "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}


def kernel_rate() -> float:
    """Single-core kernel rate (simulated s per wall s), in a pinned child process."""
    core = sorted(os.sched_getaffinity(0))[0]
    out = subprocess.run([sys.executable, "-c", KERNEL, str(core),
                          os.path.join(ROOT, "benchmarks", "bench_sim.py")],
                         check=True, capture_output=True, text=True, env=_env(), cwd=ROOT)
    return float(json.loads(out.stdout.strip().splitlines()[-1])["median"])


def lanes_rates(periods: int = 10000) -> dict:
    """``benchmarks/bench_simd.py``'s kernel and lanes rates (x real time) per drive
    variant, 64 drives on one pinned core, numba compiling for this CPU."""
    out = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "bench_simd.py"),
                          "--child", "--periods", str(periods)],
                         check=True, stdout=subprocess.PIPE, text=True, env=_env(), cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


def time_to_quality(seeds: str, configs: list[str] | None, suite: str = "open-loop") -> list[str]:
    """``benchmarks/time_to_quality.py``'s summary lines (PPO to tuned-constant-gain's
    dev attenuation in ``suite``, the configs interleaved seed by seed; None: the
    suite's every config)."""
    out = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "time_to_quality.py"),
                          "--suite", suite, "--seeds", seeds,
                          *(["--configs", *configs] if configs else [])],
                         check=True, stdout=subprocess.PIPE, text=True, env=_env(), cwd=ROOT)
    lines = out.stdout.strip().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("config "))
    return [lines[0]] + lines[start:-1]


def board(cores: int, out: str) -> tuple[float, dict]:
    """One full default board, end to end: (wall s, leaderboard.json)."""
    cmd = [sys.executable, "-m", "stepdamp_env.cli", "leaderboard", "--out", out,
           "--no-progress", "--workers", str(cores)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=ROOT, env=_env(), stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    with open(os.path.join(out, "leaderboard.json"), encoding="utf-8") as fh:
        return wall, json.load(fh)


def ppo_throughput(threads: int, simd: bool, drives: int = 512, updates: int = 12) -> float:
    """Env-steps per wall second of PPO (throughput settings, updates included)."""
    import torch
    from stable_baselines3 import PPO

    from stepdamp_env.sb3 import make_sb3_vec_env_v1

    torch.set_num_threads(1)
    venv = make_sb3_vec_env_v1(num_envs=drives, agent_hz=100.0, num_threads=threads, simd=simd)
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=8192, n_epochs=1, seed=0,
                verbose=0, device="cpu")
    model.learn(drives * 32)                                  # warm-up (compiles)
    steps = drives * 32 * updates
    t0 = time.perf_counter()
    model.learn(steps, reset_num_timesteps=False)
    rate = steps / (time.perf_counter() - t0)
    venv.close()
    return rate


def ppo_split(threads: int, updates: int = 30) -> tuple[float, float]:
    """Wall seconds in collecting rollouts and in SB3's updates, PPO with the shape of
    the committed v1 settings (32 drives, 100-step rollouts, ten epochs of 400,
    64x64 net; torch on one thread)."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback

    from stepdamp_env.sb3 import make_sb3_vec_env_v1

    class Clock(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.collect = 0.0
            self.t0 = 0.0

        def _on_rollout_start(self) -> None:
            self.t0 = time.perf_counter()

        def _on_rollout_end(self) -> None:
            self.collect += time.perf_counter() - self.t0

        def _on_step(self) -> bool:
            return True

    torch.set_num_threads(1)
    venv = make_sb3_vec_env_v1(num_envs=32, agent_hz=100.0, num_threads=threads)
    model = PPO("MlpPolicy", venv, n_steps=100, batch_size=400, n_epochs=10, seed=0, verbose=0,
                device="cpu", policy_kwargs={"net_arch": [64, 64]})
    model.learn(3200)                                         # warm-up
    clock = Clock()
    t0 = time.perf_counter()
    model.learn(3200 * updates, reset_num_timesteps=False, callback=clock)
    total = time.perf_counter() - t0
    venv.close()
    return clock.collect, total - clock.collect


def ppo_committed(threads: int, steps: int, out: str) -> dict:
    """``stepdamp train --algo ppo`` (committed settings, no dev checks): its training.json."""
    cmd = [sys.executable, "-m", "stepdamp_env.cli", "train", "--algo", "ppo",
           "--total-timesteps", str(steps), "--eval-freq", "0", "--checkpoint-freq", "0",
           "--no-progress", "--no-tensorboard", "--num-threads", str(threads), "--out", out]
    subprocess.run(cmd, check=True, cwd=ROOT, env=_env(), stdout=subprocess.DEVNULL)
    with open(os.path.join(out, "training.json"), encoding="utf-8") as fh:
        return json.load(fh)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--cores", type=int, default=len(os.sched_getaffinity(0)))
    p.add_argument("--skip-board", action="store_true")
    p.add_argument("--skip-ppo", action="store_true")
    p.add_argument("--ppo-steps", type=int, default=96_000,
                   help="env steps of the committed-settings PPO run")
    p.add_argument("--skip-lanes", action="store_true")
    p.add_argument("--ttq-seeds", default=None, metavar="K-L",
                   help="also time PPO to quality with these seeds (benchmarks/"
                        "time_to_quality.py; about 5 minutes per seed and config here)")
    p.add_argument("--ttq-suites", nargs="+", default=["open-loop"],
                   choices=["open-loop", "moves"])
    p.add_argument("--ttq-configs", nargs="+", default=None,
                   help="default: open loop committed and lanes-5-epochs; moves committed "
                        "and reference-collection")
    args = p.parse_args()
    sys.path.insert(0, ROOT)
    rate = kernel_rate()
    ceiling = args.cores * rate
    print(f"kernel: {rate:.1f} simulated s per s on one core; ceiling on {args.cores} cores "
          f"{ceiling:.0f} (100 Hz: {ceiling * 100:,.0f} env-steps/s)", flush=True)
    if not args.skip_lanes:
        for variant, r in lanes_rates().items():
            print(f"lanes, {variant:9s} (64 drives, one core): kernel {r['kernel']:6.1f} x, "
                  f"lanes {r['lanes']:6.1f} x real time, {r['lanes'] / r['kernel']:.2f} of the "
                  f"kernel, {'the same bits' if r['same_bits'] else 'BITS DIFFER'}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        if not args.skip_board:
            board(args.cores, os.path.join(tmp, "b0"))                  # fills the caches
            wall, b = board(args.cores, os.path.join(tmp, "b1"))
            sim, own = b["simulated_seconds"], b["wall_seconds"]
            print(f"board (stepdamp-bench {b['protocol']['version']}, full, {args.cores} "
                  f"workers): {own:.1f} s ({wall:.1f} s end to end), simulated {sim:.0f} s, "
                  f"{sim / own:.0f} per s; "
                  f"efficiency {sim / own / ceiling:.2f} (end to end "
                  f"{sim / wall / ceiling:.2f}; target >= 0.5)", flush=True)
        if not args.skip_ppo:
            for simd in (False, True):
                for threads in (1, args.cores):
                    r = ppo_throughput(threads, simd)
                    print(f"ppo, v1 100 Hz, throughput settings, drives on {threads} thread(s)"
                          f"{', in SIMD lanes' if simd else ''}: {r:,.0f} env-steps/s, "
                          f"efficiency {r * 0.01 / ceiling:.2f} (target >= 0.5)", flush=True)
            collect, update = ppo_split(args.cores)
            print(f"ppo, committed settings' shape, drives on {args.cores} thread(s): collecting "
                  f"{collect:.1f} s, updates {update:.1f} s ({update / (collect + update):.0%} "
                  "of the time)", flush=True)
            for threads in (1, args.cores):
                t = ppo_committed(threads, args.ppo_steps, os.path.join(tmp, f"ppo{threads}"))
                print(f"ppo, committed settings (stepdamp train, v1 100 Hz), drives on "
                      f"{threads} thread(s): {t['env_steps'] / t['wall_seconds']:,.0f} "
                      f"env-steps/s, efficiency "
                      f"{t['simulated_seconds_per_wall_second'] / ceiling:.2f}", flush=True)
    if args.ttq_seeds:
        for suite in args.ttq_suites:
            configs = args.ttq_configs or (["committed", "lanes-5-epochs"]
                                           if suite == "open-loop" else None)
            for line in time_to_quality(args.ttq_seeds, configs, suite):
                print(f"time to quality: {line}", flush=True)


if __name__ == "__main__":
    main()
