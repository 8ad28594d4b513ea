"""Is StepperDamp-v1 learnable? PPO on ``damping-gains`` for a few minutes, with a learning curve.

Run: ``python scripts/v1_learn.py [--minutes 4.5] [--seed 1] [--out curve.json]``.

Training: randomised motors (training seeds below ``TRAINING_SEED_LIMIT``), each
episode at one of its predicted resonances, the base controller ff-delay-comp,
the visible context, decisions at 100 Hz (the law runs at 20 kHz); PPO with
SB3's defaults but for the settings in :class:`Args`; no observation or reward
normalisation (v1's units are meant to need none).

Evaluation, every ``eval_every_s`` of training time: the four preset motors at
their three predicted resonances (12 runs, one episode each, the policy's
mean action), the RMS velocity error over the held part (after the ramp) as a
ratio to the base controller alone on the same run; the geometric mean over
the 12 runs. A constant velocity-feedback gain tuned on training motors
(``scripts/v1_spread.py``: kv = 0.5) is measured on the same runs for reference.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import asdict, dataclass, fields

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback

from stepdamp_env.bench.protocol import TRAINING_SEED_LIMIT
from stepdamp_env.env import StepperDampV1VectorEnv
from stepdamp_env.io import write_json
from stepdamp_env.presets import preset_names
from stepdamp_env.sb3 import make_sb3_vec_env_v1


@dataclass
class Args:
    minutes: float = 4.5          # training wall time (the learning curve's end)
    seed: int = 1                 # PPO's seed; the envs draw motors from seed*num_envs on
    num_envs: int = 32
    agent_hz: float = 100.0
    n_steps: int = 40             # one 0.4 s episode per drive per update
    batch_size: int = 320
    n_epochs: int = 10
    learning_rate: float = 1e-3
    gamma: float = 0.9
    log_std_init: float = -1.0
    eval_every_s: float = 30.0
    tuned_kv: float = 0.5         # the constant gain tuned on training motors
    out: str = ""                 # write the curve as JSON here


TASK = {"action_mode": "damping-gains", "base_controller": "ff-delay-comp", "context": "visible"}


def parse_args() -> Args:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for f in fields(Args):
        ap.add_argument("--" + f.name.replace("_", "-"), type=type(f.default), default=f.default)
    return Args(**vars(ap.parse_args()))


def evaluation_runs(agent_hz: float) -> list[tuple[str, float]]:
    """(preset, speed in rev/s) of the 12 evaluation runs."""
    runs = []
    for name in preset_names():
        env = StepperDampV1VectorEnv(1, motor=name, agent_hz=agent_hz, **TASK)
        for h, f in env.task.nominal.predicted_resonances_rps().items():
            runs.append((name, float(f)))
    return runs


def held_ripple(runs, agent_hz: float, act) -> np.ndarray:
    """RMS velocity error (rad/s) over the held part of each run under ``act(obs)``."""
    out = []
    for name, speed in runs:
        env = StepperDampV1VectorEnv(1, motor=name, speed_rps=speed, agent_hz=agent_hz, **TASK)
        obs, _ = env.reset(seed=TRAINING_SEED_LIMIT)      # the sensor noise of an unseen seed
        ramp = speed / env.options.accel_rps2
        sq, n = 0.0, 0
        for t in range(env.task.max_episode_steps):
            obs, _, term, _, info = env.step(act(obs))
            if term[0]:
                return np.full(len(runs), math.inf)
            if (t + 1) * env.task.seconds_per_step > ramp:
                sq += info["velocity_error_rms_rad_s"][0] ** 2
                n += 1
        out.append(math.sqrt(sq / n))
    return np.array(out)


def main() -> None:
    args = parse_args()
    torch.set_num_threads(1)
    runs = evaluation_runs(args.agent_hz)
    zero = np.zeros((1, 8), np.float32)
    base = held_ripple(runs, args.agent_hz, lambda obs: zero)
    kv = zero.copy()
    kv[0, 0] = args.tuned_kv
    tuned = held_ripple(runs, args.agent_hz, lambda obs: kv)

    def score(ripple: np.ndarray) -> float:
        return float(np.exp(np.mean(np.log(ripple / base))))

    print(f"{len(runs)} evaluation runs; base ff-delay-comp ripple (rad/s): "
          + " ".join(f"{x:.3g}" for x in base))
    print(f"constant kv={args.tuned_kv} (tuned on training motors): ratio {score(tuned):.3f}")

    venv = make_sb3_vec_env_v1(args.num_envs, randomize=True, resonance_prob=1.0,
                               agent_hz=args.agent_hz, **TASK)
    # Training motors only: drive i of the first reset draws from seed*num_envs + i.
    assert (args.seed + 1) * args.num_envs <= TRAINING_SEED_LIMIT
    venv.seed(args.seed * args.num_envs)
    model = PPO("MlpPolicy", venv, n_steps=args.n_steps, batch_size=args.batch_size,
                n_epochs=args.n_epochs, learning_rate=args.learning_rate, gamma=args.gamma,
                policy_kwargs={"log_std_init": args.log_std_init, "net_arch": [64, 64]},
                seed=args.seed, device="cpu", verbose=0)

    def policy(obs):
        return model.predict(obs, deterministic=True)[0]

    curve = [{"train_s": 0.0, "env_steps": 0, "ratio": score(held_ripple(runs, args.agent_hz,
                                                                            policy))}]
    print(f"{'train s':>8} {'env steps':>10} {'ripple / base':>14}")
    print(f"{0.0:8.0f} {0:10d} {curve[0]['ratio']:14.3f}")

    class Clock(BaseCallback):
        """Evaluates every eval_every_s of training time; stops at the budget."""

        def _on_training_start(self) -> None:
            self.spent, self.mark, self.next_eval = 0.0, time.perf_counter(), args.eval_every_s

        def _on_step(self) -> bool:
            now = time.perf_counter()
            self.spent += now - self.mark
            self.mark = now
            if self.spent >= self.next_eval or self.spent >= 60.0 * args.minutes:
                self.next_eval += args.eval_every_s
                ratio = score(held_ripple(runs, args.agent_hz, policy))
                curve.append({"train_s": round(self.spent, 1), "env_steps": self.num_timesteps,
                              "ratio": ratio})
                print(f"{self.spent:8.0f} {self.num_timesteps:10d} {ratio:14.3f}", flush=True)
                self.mark = time.perf_counter()          # evaluation time is not training time
            return self.spent < 60.0 * args.minutes

    model.learn(total_timesteps=10 ** 9, callback=Clock())
    final = held_ripple(runs, args.agent_hz, policy)
    print("per run (preset, rev/s, base, kv, PPO ripple rad/s):")
    for (name, speed), b, k, p in zip(runs, base, tuned, final):
        print(f"  {name:20s} {speed:6.3f} {b:8.4f} {k:8.4f} {p:8.4f}")
    if args.out:
        write_json(args.out, {"args": asdict(args), "curve": curve,
                                     "tuned_kv_ratio": score(tuned),
                                     "runs": [list(r) for r in runs]})


if __name__ == "__main__":
    main()
