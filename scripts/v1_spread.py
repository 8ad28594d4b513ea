"""StepperDamp-v1 in numbers: the observation entries' spread and the per-step reward range.

Run: ``python scripts/v1_spread.py [--num-envs 64]`` (about a minute on one core).

64 randomised motors (training seeds 0..63), each at one of its three predicted
resonances (``resonance_prob=1``), one 0.4 s episode at 1 kHz each:

* the spread (standard deviation, 5th and 95th percentile) of every
  observation entry under the base controller (ff-delay-comp), over the held
  part of the episodes (after the ramp) and over whole episodes;
* the per-step reward (5th, 50th, 95th percentile, held part) of ``none``, the
  base controller and the base controller plus a constant velocity-feedback
  gain ``kv`` tuned on these training motors (a grid; the best mean reward).
"""

from __future__ import annotations

import argparse

import numpy as np

from stepdamp_env.env import StepperDampV1VectorEnv, observation_names_v1

OPTIONS = {"randomize": True, "resonance_prob": 1.0, "context": "visible", "history": 1}
KV_GRID = (0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0)


def rollout(n: int, kv: float = 0.0, **options):
    """(observations (T, n, d), rewards (T, n), held mask (T, n)) of one episode per drive."""
    env = StepperDampV1VectorEnv(n, **{**OPTIONS, **options})
    obs, info = env.reset(seed=0)
    ramp_steps = np.ceil(info["speed_rps"] / env.options.accel_rps2 / env.task.seconds_per_step)
    a = np.zeros((n, env.task.act_dim), np.float32)
    a[:, 0] = kv
    seen, rewards, held = [], [], []
    for t in range(env.task.max_episode_steps):
        obs, r, term, trunc, _ = env.step(a)
        seen.append(obs)
        rewards.append(r)
        held.append(t >= ramp_steps)
        if term.any():
            raise SystemExit(f"a drive terminated at step {t} (kv={kv}, {options})")
    return np.array(seen), np.array(rewards), np.array(held)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--num-envs", type=int, default=64)
    n = ap.parse_args().num_envs
    obs, rew_base, held = rollout(n)
    names = observation_names_v1("damping-gains", 1, "visible")
    print(f"Observation entries, base controller ff-delay-comp, {n} randomised motors at "
          "resonances:\n")
    print("| entry | std (held) | p5 .. p95 (held) | std (whole episode) |")
    print("|---|---|---|---|")
    for j, name in enumerate(names):
        if name.startswith("last_action"):
            continue
        x = obs[:, :, j][held]
        whole = obs[:, :, j].ravel()
        print(f"| {name} | {x.std():.3g} | {np.percentile(x, 5):.3g} .. "
              f"{np.percentile(x, 95):.3g} | {whole.std():.3g} |")
    means = {kv: rollout(n, kv)[1][held].mean() for kv in KV_GRID}
    best = max(means, key=means.get)
    print("\nmean held reward of the base controller plus a constant kv: "
          + ", ".join(f"kv={k}: {v:.4f}" for k, v in means.items()) + f" (base {rew_base[held].mean():.4f})")
    rows = {"none": rollout(n, base_controller="none")[1], "ff-delay-comp (base)": rew_base,
            f"ff-delay-comp + kv={best} (tuned)": rollout(n, best)[1]}
    print("\n| controller | reward p5 | median | p95 | mean (held) |")
    print("|---|---|---|---|---|")
    for label, r in rows.items():
        x = r[held]
        print(f"| {label} | {np.percentile(x, 5):.3g} | {np.median(x):.3g} | "
              f"{np.percentile(x, 95):.3g} | {x.mean():.3g} |")


if __name__ == "__main__":
    main()
