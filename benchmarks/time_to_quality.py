"""Time to quality: how long PPO trains before it damps as well as `tuned-constant-gain`.

Run: ``PYTHONPATH=. python benchmarks/time_to_quality.py [--suite open-loop]
[--seeds 21-25] [--configs committed lanes-5-epochs] [--eval-freq 25000]
[--budget 1200000] [--out DIR]``.

The quality is `tuned-constant-gain`'s attenuation on the dev split of the
suite (IQM over the dev motors, dB): stepdamp-bench v3's for ``open-loop``,
v4's for ``moves`` (v3 has no moves), measured in this run by the same dev
board that ``stepdamp train --select-on dev`` checks a model on.
Each config trains PPO for the open-loop suite with ``--stop-at-db`` at that
value, one seed after the other, the configs interleaved seed by seed (so that
the machine's drift falls on both). Dev checks every ``--eval-freq`` decisions;
never a scored split. For each run it prints the decisions and the wall seconds
to the first dev check during training at or above the quality: ``training``
seconds without the dev checks (``learn_s`` of ``train_log.json``), ``with dev
checks`` (what a user waits for, given that check interval), and the process's
time end to end. A run that does not reach it within
``--budget`` decisions counts as not reached (its time is a lower bound).

Configs (:data:`CONFIGS`): ``committed`` is `ppo-open-loop`'s training
(agents/hyperparams/ppo.yml at 25 Hz: 32 drives, 8 per preset, 100-step
rollouts, ten epochs of minibatches of 400). The others collect about the same
rollout (3,072 decisions) from 256 drives of 12 steps, 64 per preset: two
groups of 32 SIMD lanes per preset, one per numba thread (below 32 drives a
preset's env steps in the scalar kernel), and do five epochs:
``lanes-5-epochs`` of minibatches of 384, ``lanes-big-batch`` of 768 at twice
the learning rate. For ``moves``: ``committed`` is `ppo-moves`'s training
(256 drives of 12 steps, five epochs of 384, 25 Hz, gamma 0.98), and
``reference-collection`` the same with `ppo-open-loop`'s collection and
updates (32 drives, 100-step rollouts, ten epochs of 400).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: The open-loop suite's training configs: ``stepdamp train`` options beyond the common ones.
CONFIGS: dict[str, list[str]] = {
    "committed": ["--hyperparam", "env_kwargs={agent_hz: 25.0}"],
    "lanes-5-epochs": ["--hyperparam", "env_kwargs={agent_hz: 25.0}",
                       "--hyperparam", "n_envs=256", "--hyperparam", "n_steps=12",
                       "--hyperparam", "batch_size=384", "--hyperparam", "n_epochs=5"],
    "lanes-big-batch": ["--hyperparam", "env_kwargs={agent_hz: 25.0}",
                        "--hyperparam", "n_envs=256", "--hyperparam", "n_steps=12",
                        "--hyperparam", "batch_size=768", "--hyperparam", "n_epochs=5",
                        "--hyperparam", "learning_rate=0.0006"],
}
_MOVES = ["--hyperparam", "env_kwargs={agent_hz: 25.0}", "--hyperparam", "gamma=0.98"]

#: Per suite: (the protocol whose dev split sets the quality, its training configs).
SUITES: dict[str, tuple[str, dict[str, list[str]]]] = {
    "open-loop": ("v3", CONFIGS),
    "moves": ("v4", {
        "committed": [*_MOVES, "--hyperparam", "n_envs=256", "--hyperparam", "n_steps=12",
                      "--hyperparam", "batch_size=384", "--hyperparam", "n_epochs=5"],
        "reference-collection": _MOVES,
    }),
}


def _env() -> dict[str, str]:
    return {**os.environ, "MPLBACKEND": "Agg",
            "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}


def quality_db(out: str, entry: str = "tuned-constant-gain", suite: str = "open-loop") -> float:
    """``entry``'s IQM attenuation (dB) on the dev split of ``suite`` (:data:`SUITES`)."""
    _run([sys.executable, "-m", "stepdamp_env.cli", "leaderboard", "--protocol", SUITES[suite][0],
          "--split", "dev", "--suite", suite, "--entries", entry, "--out", out,
          "--no-plots", "--no-progress", "--workers", "1"])
    with open(os.path.join(out, "leaderboard.json"), encoding="utf-8") as fh:
        board = json.load(fh)
    return float(next(e for e in board["entries"]
                      if e["name"] == entry)["attenuation_db"]["iqm"])


def _run(cmd: list[str]) -> None:
    """Run a child; if it fails, its stderr's last lines and exit status 1."""
    out = subprocess.run(cmd, capture_output=True, text=True, env=_env(), cwd=ROOT)
    if out.returncode != 0:
        sys.stderr.write("\n".join(out.stderr.strip().splitlines()[-20:]) + "\n")
        sys.exit(f"failed ({out.returncode}): {' '.join(cmd)}")


def train_until(config: str, seed: int, target_db: float, eval_freq: int, budget: int,
                out: str, suite: str = "open-loop") -> dict:
    """One ``stepdamp train`` run stopped at ``target_db``; what it took."""
    cmd = [sys.executable, "-m", "stepdamp_env.cli", "train", "--algo", "ppo",
           "--suite", suite, "--select-on", "dev", "--seed", str(seed), "--out", out,
           "--eval-freq", str(eval_freq), "--total-timesteps", str(budget),
           "--stop-at-db", repr(target_db), "--checkpoint-freq", "0", "--no-progress",
           "--no-tensorboard", *SUITES[suite][1][config]]
    t0 = time.perf_counter()
    _run(cmd)
    end_to_end = time.perf_counter() - t0
    with open(os.path.join(out, "train_log.json"), encoding="utf-8") as fh:
        log = json.load(fh)
    evaluations = log["evaluations"]             # the initial check, then in training order
    hit = next((k for k, e in enumerate(evaluations)
                if k > 0 and e["attenuation_db"] >= target_db), None)
    if hit is not None:
        decisions, learn_s = evaluations[hit]["step"], evaluations[hit]["learn_s"]
        checks_s = sum(e["check_s"] for e in evaluations[:hit + 1])
    else:                                         # a lower bound: the whole budget
        during = [e for e in evaluations if e["tag"] != "final"]
        checks_s = sum(e["check_s"] for e in during)
        decisions, learn_s = evaluations[-1]["step"], log["train_wall_s"] - checks_s
    return {"config": config, "seed": seed, "reached": hit is not None,
            "decisions": decisions, "learn_s": learn_s, "wall_s": learn_s + checks_s,
            "end_to_end_s": end_to_end,
            "best_db": max(e["attenuation_db"] for e in evaluations[1:]),
            "curve": [(e["step"], e["learn_s"], e["attenuation_db"]) for e in evaluations]}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", default="21-25", help="training seeds (fresh: the committed "
                   "ppo-open-loop used 11-15)")
    p.add_argument("--suite", default="open-loop", choices=list(SUITES))
    p.add_argument("--configs", nargs="+", default=None,
                   choices=sorted({c for _, cs in SUITES.values() for c in cs}),
                   help="default: every config of the suite")
    p.add_argument("--eval-freq", type=int, default=25_000, help="decisions between dev checks")
    p.add_argument("--budget", type=int, default=1_200_000, help="decisions at most per run")
    p.add_argument("--out", default=None, help="keep the runs here (default: a temporary dir)")
    a = p.parse_args()
    from stepdamp_agents.settings import parse_seeds
    from stepdamp_env.params import ParameterError

    try:
        seeds = parse_seeds(a.seeds)
    except ParameterError as exc:
        sys.exit(str(exc))
    configs = SUITES[a.suite][1]
    a.configs = a.configs or list(configs)
    unknown = [c for c in a.configs if c not in configs]
    if unknown:
        sys.exit(f"--configs: {', '.join(unknown)} not a config of --suite {a.suite} "
                 f"(allowed: {', '.join(configs)})")
    out = a.out or tempfile.mkdtemp(prefix="ttq-")       # kept: the runs and their logs
    target = quality_db(os.path.join(out, "quality"), suite=a.suite)
    print(f"quality: tuned-constant-gain on {SUITES[a.suite][0]} dev, {a.suite}: {target:.2f} dB "
          f"(dev checks every {a.eval_freq} decisions, at most {a.budget})", flush=True)
    rows = []
    for seed in seeds:
        for config in a.configs:
            r = train_until(config, seed, target, a.eval_freq, a.budget,
                            os.path.join(out, config, f"seed{seed}"), a.suite)
            rows.append(r)
            print(f"{config:20s} seed {seed:3d}: "
                  f"{'reached' if r['reached'] else 'NOT reached'} at {r['decisions']:>9,d} "
                  f"decisions, training {r['learn_s']:7.1f} s, with dev checks "
                  f"{r['wall_s']:7.1f} s, end to end {r['end_to_end_s']:7.1f} s "
                  f"(best dev {r['best_db']:.2f} dB)", flush=True)
    print(f"\n{'config':20s}  reached  decisions (median)  training s (median, range)  "
          "with dev checks s (median)")
    medians = {}
    for config in a.configs:
        rs = [r for r in rows if r["config"] == config]
        tr = [r["learn_s"] for r in rs]
        medians[config] = statistics.median(tr)
        print(f"{config:20s}  {sum(r['reached'] for r in rs)}/{len(rs)}     "
              f"{statistics.median(r['decisions'] for r in rs):>12,.0f}    "
              f"{medians[config]:7.1f} [{min(tr):.1f}, {max(tr):.1f}]        "
              f"{statistics.median(r['wall_s'] for r in rs):7.1f}")
    if "committed" in medians:
        for config, m in medians.items():
            if config != "committed":
                print(f"{config} / committed, median training s: "
                      f"{m / medians['committed']:.2f}")
    with open(os.path.join(out, "time_to_quality.json"), "w", encoding="utf-8") as fh:
        json.dump({"suite": a.suite, "quality_db": target, "eval_freq": a.eval_freq,
                   "budget": a.budget, "runs": rows}, fh, indent=1)
    print(f"wrote {os.path.join(out, 'time_to_quality.json')}")


if __name__ == "__main__":
    main()
