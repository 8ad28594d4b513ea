"""PPO on StepperDamp-v3 in one file: read it top to bottom, change what you like.

A clipped-surrogate PPO with a Gaussian policy and generalised advantage
estimation, on the native vector env, in torch alone (no SB3). StepperDamp-v3's
defaults are the per-step agents' task with a two-number action: the gain and
phase of a velocity-feedback damping law, set every 10 ms on top of the drive's
model-based feedforward, on motors drawn around the presets. A zero action is
the feedforward alone, so the number to beat is the zero action's return on the
same evaluation episodes; the script prints both. ``--env-id StepperDamp-v2``
trains on the eight gains of the full law instead.

    python examples/ppo_stepperdamp.py --total-steps 200000
    python examples/ppo_stepperdamp.py --help

Every option is a field of :class:`Args` (defaults documented there). The
evaluation episodes use seeds from 900,000 up: motors of the training
distribution that no training seed here draws, and below the 1,000,000 from
which the benchmark's protocols draw their scored motors.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch
from torch import nn

import stepdamp_env  # noqa: F401  (registers StepperDamp-v3)

EVAL_SEED = 900_000


@dataclass
class Args:
    """The run's settings; each is also a ``--flag`` of the command line."""

    env_id: str = "StepperDamp-v3"
    seed: int = 1
    num_envs: int = 8                   # drives stepped together (one native vector env)
    total_steps: int = 200_000          # env steps over all drives
    rollout_steps: int = 256            # steps per drive between updates
    epochs: int = 10
    minibatches: int = 8
    learning_rate: float = 3e-4
    gamma: float = 0.9                  # on v2, 0.99 made the mean policy worse than zero
    gae_lambda: float = 0.95
    clip: float = 0.2
    entropy_coef: float = 0.0
    value_coef: float = 0.5
    max_grad_norm: float = 0.5
    init_log_std: float = -1.0          # exploration noise in action units at the start
    eval_episodes: int = 16
    eval_every: int = 5                 # updates between evaluations
    torch_threads: int = 1              # one thread: the same sums, the same model

    def __post_init__(self) -> None:
        if self.rollout_steps * self.num_envs < 2 * self.minibatches:
            raise SystemExit(f"--rollout-steps {self.rollout_steps} x --num-envs {self.num_envs} "
                             f"must be at least 2 x --minibatches {self.minibatches}")

    @classmethod
    def from_cli(cls, argv: list[str] | None = None) -> "Args":
        p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
        for f in dataclasses.fields(cls):
            p.add_argument("--" + f.name.replace("_", "-"), type=type(f.default),
                           default=f.default, help=f"(default: {f.default})")
        return cls(**vars(p.parse_args(argv)))


def layer(n_in: int, n_out: int, gain: float) -> nn.Linear:
    """A linear layer with orthogonal weights of ``gain`` and zero bias."""
    out = nn.Linear(n_in, n_out)
    nn.init.orthogonal_(out.weight, gain)
    nn.init.zeros_(out.bias)
    return out


class Agent(nn.Module):
    """Two tanh MLPs: the value, and the mean of a Gaussian over actions (its
    last layer small, so the first policy is close to the zero action)."""

    def __init__(self, n_obs: int, n_act: int, init_log_std: float) -> None:
        super().__init__()
        self.value = nn.Sequential(layer(n_obs, 64, 2 ** 0.5), nn.Tanh(),
                                   layer(64, 64, 2 ** 0.5), nn.Tanh(), layer(64, 1, 1.0))
        self.mean = nn.Sequential(layer(n_obs, 64, 2 ** 0.5), nn.Tanh(),
                                  layer(64, 64, 2 ** 0.5), nn.Tanh(), layer(64, n_act, 0.01))
        self.log_std = nn.Parameter(torch.full((n_act,), init_log_std))

    def dist(self, obs: torch.Tensor) -> torch.distributions.Normal:
        return torch.distributions.Normal(self.mean(obs), self.log_std.exp())


def evaluate(args: Args, agent: Agent | None) -> float:
    """Mean return over ``eval_episodes`` fixed episodes of the policy's mean
    action (None: the zero action)."""
    env = gym.make_vec(args.env_id, num_envs=args.eval_episodes,
                       vectorization_mode="vector_entry_point")
    obs, _ = env.reset(seed=[EVAL_SEED + k for k in range(args.eval_episodes)])
    total = np.zeros(args.eval_episodes)
    done = np.zeros(args.eval_episodes, dtype=bool)
    while not done.all():
        if agent is None:
            act = np.zeros(env.action_space.shape, dtype=np.float32)
        else:
            with torch.no_grad():
                act = agent.mean(torch.as_tensor(obs)).numpy()
        obs, reward, term, trunc, _ = env.step(np.clip(act, -1.0, 1.0))
        total += np.where(done, 0.0, reward)
        done |= term | trunc
    env.close()
    return float(total.mean())


def main(args: Args) -> list[dict[str, float]]:
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.torch_threads)
    env = gym.make_vec(args.env_id, num_envs=args.num_envs,
                       vectorization_mode="vector_entry_point")
    n_obs = env.single_observation_space.shape[0]
    n_act = env.single_action_space.shape[0]
    agent = Agent(n_obs, n_act, args.init_log_std)
    optim = torch.optim.Adam(agent.parameters(), lr=args.learning_rate, eps=1e-5)

    T, N = args.rollout_steps, args.num_envs
    obs_buf = torch.zeros((T, N, n_obs))
    act_buf = torch.zeros((T, N, n_act))
    logp_buf = torch.zeros((T, N))
    rew_buf = torch.zeros((T, N))
    term_buf = torch.zeros((T, N))      # the episode terminated at this step
    done_buf = torch.zeros((T, N))      # it ended (terminated or truncated at 1 s)
    val_buf = torch.zeros((T, N))

    zero_return = evaluate(args, None)
    print(f"zero action (the feedforward alone): return {zero_return:.2f}")
    obs, _ = env.reset(seed=args.seed)
    obs = torch.as_tensor(obs)
    # The native env resets an ended drive on the next step (NEXT_STEP): that
    # step's reward is 0 and belongs to no episode, so it is masked out.
    restart = torch.zeros(N)
    history, steps, start = [], 0, time.perf_counter()
    updates = max(1, args.total_steps // (T * N))
    for update in range(1, updates + 1):
        valid = torch.ones((T, N))
        for t in range(T):
            with torch.no_grad():
                d = agent.dist(obs)
                action = d.sample()
                val_buf[t] = agent.value(obs).squeeze(-1)
            obs_buf[t], act_buf[t] = obs, action
            logp_buf[t] = d.log_prob(action).sum(-1)
            valid[t] = 1.0 - restart
            nxt, reward, term, trunc, _ = env.step(action.clamp(-1.0, 1.0).numpy())
            rew_buf[t] = torch.as_tensor(reward, dtype=torch.float32)
            term_buf[t] = torch.as_tensor(term, dtype=torch.float32)
            done_buf[t] = torch.as_tensor(term | trunc, dtype=torch.float32)
            restart = done_buf[t].clone()
            obs = torch.as_tensor(nxt)
            steps += N

        # Advantages by GAE, backwards. The step after an episode's end holds its
        # final observation (NEXT_STEP), so a truncated episode (the 1 s limit)
        # bootstraps from that state's value; a terminated one from nothing.
        with torch.no_grad():
            next_value = agent.value(obs).squeeze(-1)
        adv = torch.zeros((T, N))
        last = torch.zeros(N)
        for t in reversed(range(T)):
            v_next = next_value if t == T - 1 else val_buf[t + 1]
            delta = rew_buf[t] + args.gamma * v_next * (1.0 - term_buf[t]) - val_buf[t]
            last = delta + args.gamma * args.gae_lambda * (1.0 - done_buf[t]) * last
            adv[t] = last
        ret = adv + val_buf

        mask = valid.reshape(-1).bool()
        b_obs, b_act = obs_buf.reshape(-1, n_obs)[mask], act_buf.reshape(-1, n_act)[mask]
        b_logp, b_adv, b_ret = logp_buf.reshape(-1)[mask], adv.reshape(-1)[mask], ret.reshape(-1)[mask]
        size = len(b_obs)
        gen = torch.Generator().manual_seed(args.seed * 100_003 + update)
        for _ in range(args.epochs):
            # Equal minibatches, two samples or more each (Args checks it).
            for idx in torch.tensor_split(torch.randperm(size, generator=gen), args.minibatches):
                d = agent.dist(b_obs[idx])
                ratio = (d.log_prob(b_act[idx]).sum(-1) - b_logp[idx]).exp()
                a = b_adv[idx]
                a = (a - a.mean()) / (a.std() + 1e-8)
                policy_loss = torch.max(-a * ratio,
                                        -a * ratio.clamp(1 - args.clip, 1 + args.clip)).mean()
                value_loss = 0.5 * (agent.value(b_obs[idx]).squeeze(-1) - b_ret[idx]).pow(2).mean()
                loss = (policy_loss + args.value_coef * value_loss
                        - args.entropy_coef * d.entropy().sum(-1).mean())
                optim.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optim.step()

        if update % args.eval_every == 0 or update == updates:
            got = evaluate(args, agent)
            wall = time.perf_counter() - start
            history.append({"env_steps": steps, "wall_s": wall, "return": got,
                            "zero_action_return": zero_return})
            print(f"update {update:4d}  env steps {steps:8d}  wall {wall:7.1f} s  "
                  f"{steps / wall:8.0f} env-steps/s  return {got:8.2f} "
                  f"(zero action {zero_return:.2f})", flush=True)
    env.close()
    return history


if __name__ == "__main__":
    main(Args.from_cli())
