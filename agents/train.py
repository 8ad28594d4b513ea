"""Train residual agents (ARS, PPO, SAC, TD3) on StepperDamp drives: one readable script.

Every setting is a field of :class:`Args`; hyperparameters of the algorithm come
from ``agents/hyperparams/<algo>.yml`` (rl-baselines3-zoo format, keyed by the
env id: ``StepperDamp-v1`` for the per-step agents, the default, whose task is
:data:`stepdamp_agents.per_step.REFERENCE_TASK`; ``StepperDampResidual-v0`` for
the v0 gain selector, :mod:`stepdamp_agents.task`), so the zoo and this script
train the same thing::

    stepdamp train --algo ars --seeds 1-5 --out runs/ars     # runs/ars/seed<K>/
    stepdamp train --algo ppo --env StepperDampResidual-v0 --seed 1 --out runs/gain
    python -m stepdamp_agents.train --algo td3 --total-timesteps 20000 --out runs/smoke

The loop below is the same for every agent family; what a family brings (its
env, its policy file's config, how a saved model acts, its validation's
settling) is one module each: :mod:`stepdamp_agents.train_per_step` and
:mod:`stepdamp_agents.train_gain_selector` (:class:`~.family.TrainingFamily`),
picked by ``--env``.

What it does, in order, for each seed:

1. builds the training env: ``envs_per_motor`` native vectorised drives around
   each preset (``randomize=True``, the env's generator seeded below
   ``TRAINING_SEED_LIMIT`` = 1_000_000;
   the protocol's drawn motors are never used), the protocol's sensors
   (0.01 A current noise, 4000 counts/rev); on v1 the residual is the env's own
   (a zero action is ff-delay-comp), and ARS meets the same episodes with all
   candidates of an update (:class:`stepdamp_agents.per_step.SameEpisodes`); on
   v0 it is wrapped as residuals on top of the base controller
   (:class:`stepdamp_agents.residual.ResidualVecEnv`);
2. builds the algorithm with a zero-residual policy and zero-residual warm-up
   (:mod:`stepdamp_agents.residual`); torch on one thread;
3. trains with a progress bar, TensorBoard and CSV logs, checkpoints and a
   periodic evaluation on the leaderboard's metrics (headline: mean RMS ripple
   at the three resonant speeds over that of ``none``, IQM) on validation
   motors drawn around the presets with seed ``val_seed`` and noise seeds
   below the limit, with the exact feedforward model (v1: the settling of
   stepdamp-bench v1);
4. writes ``final.zip`` and ``best.zip`` (best validation headline), each with its
   ``.agent.json`` (the config the leaderboard policy needs), and ``train_log.json``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import sys
import time
from typing import Any, Iterator

import numpy as np

from stepdamp_env.bench.protocol import TRAINING_SEED_LIMIT
from stepdamp_env.io import write_json
from stepdamp_env.params import ParameterError

from .selection import POOL_DEV_DRAW, DevValidator
# The settings live in .settings; the command's names are kept here too.
from .settings import (ALGO_CHOICES, FAMILIES, Args, add_arguments, args_from_namespace,
                       check_algo_kwargs, check_args, load_hyperparams, parse_policy_kwargs,
                       parse_seeds, split_hyperparams)
from .task import suite_task

__all__ = ["Validator", "set_start_action", "save_agent", "train", "training_threads",
           "write_training_record", "train_seeds", "main", "Args", "ALGO_CHOICES",
           "add_arguments", "args_from_namespace", "load_hyperparams", "parse_policy_kwargs",
           "parse_seeds", "split_hyperparams"]


# ---------------------------------------------------------------------------
# Validation on the leaderboard's metrics
# ---------------------------------------------------------------------------
class Validator:
    """The leaderboard's runner and scores on training-side validation motors.

    Motors drawn around the training presets with ``val_seed`` (below
    ``TRAINING_SEED_LIMIT``, never the protocol's), the resonant speeds of each,
    open loop, the protocol's ramp, window and failure ratio; the exact model
    stands in for the identified one (identification per validation motor
    would cost more than the validation itself).
    """

    def __init__(self, args: Args, env_kwargs: dict[str, Any]) -> None:
        from stepdamp_env.bench import (
            MotorKnowledge,
            ProtocolMotor,
            full_protocol,
            speed_grid,
        )
        from stepdamp_env.env import StepperDampEnv
        from stepdamp_env.params import FeedforwardModel

        if not 0 <= args.val_seed < TRAINING_SEED_LIMIT - 1000:
            raise ParameterError(f"val_seed must stay below {TRAINING_SEED_LIMIT - 1000}")
        overrides = env_kwargs.get("overrides") or {}
        self.env_id = args.env
        self.protocol = dataclasses.replace(full_protocol(), off_resonance=())
        motors, k = [], 0
        for preset in args.motors:
            env = StepperDampEnv(motor=preset, overrides=overrides, randomize=True)
            for j in range(args.val_motors_per_preset):
                env.reset(seed=args.val_seed + k)
                k += 1
                system = env.system.replace(name=f"{preset}~val{j}")
                speeds, labels = speed_grid(system, self.protocol)
                motors.append(ProtocolMotor(system.name, system, env.sampler.nominal, speeds,
                                            labels))
        self.motors = tuple(motors)
        # The family's settling (per-step: each motor's own, as stepdamp-bench v1).
        settle = FAMILIES[args.env].validation_settle()
        self.settle = [settle(m.system) for m in motors]
        self.seed = args.val_seed
        self.knowledge = []
        for m in motors:
            exact = FeedforwardModel.from_motor(m.system.motor)
            self.knowledge.append(MotorKnowledge(nominal=m.nominal, identified=exact,
                                                 exact=exact))
        self._reference: dict | None = None

    def _runs(self, make_policy) -> list[dict]:
        from stepdamp_env.bench import run_episode

        p = self.protocol
        runs = []
        for m, knowledge, settle in zip(self.motors, self.knowledge, self.settle):
            for speed, label in zip(m.speeds_rps, m.speed_labels):
                result = run_episode(make_policy(), knowledge, m.system, mode="open-loop",
                                     speed_rps=speed, seed=self.seed, accel_rps2=p.accel_rps2,
                                     window_s=p.window_s, settle_s=settle)
                runs.append(result.record(m.name, self.seed, speed, label))
        return runs

    @staticmethod
    def better(new: dict[str, Any], best: dict[str, Any] | None) -> bool:
        """Lower headline ratio is better; a non-finite one is never kept."""
        value = new["headline_iqm"]
        return math.isfinite(value) and (best is None or value < best["headline_iqm"])

    def score(self, path: str) -> dict[str, Any]:
        """The model saved in ``path`` on the validation motors."""
        from stepdamp_env.bench import iqm, reference_index, score_runs
        from stepdamp_env.bench.policy import reference_policy

        if self._reference is None:
            self._reference = reference_index(self._runs(reference_policy))
        agent = FAMILIES[self.env_id].load_agent(path)
        runs = self._runs(lambda: agent)
        scores = score_runs(runs, self._reference, self.protocol.failure_ratio)
        heads = [s["headline"] for s in scores]
        return {"headline_iqm": iqm(heads), "headline_mean": float(np.mean(heads)),
                "per_motor": {s["motor"]: s["headline"] for s in scores},
                "step_losses": int(sum(r["failed"] for r in runs))}


def training_motors(args: Args) -> tuple[Any, ...]:
    """The motors the drives are built around: preset names, or datasheet mappings
    drawn from the pool's train part with seed ``1000 * seed`` (``--motor-pool``)."""
    if args.motor_pool != "presets":
        from stepdamp_env.motorpool import draw_datasheets

        return draw_datasheets(1000 * args.seed, args.pool_motors, "train",
                               motor_pool=args.motor_pool)
    return tuple(args.motors)


def _agent_config(args: Args, sp: dict[str, Any], motors: tuple[Any, ...]) -> dict[str, Any]:
    family = FAMILIES[args.env]
    pool = args.motor_pool != "presets"
    training = {"seed": args.seed, "env_seed": 1000 * args.seed, "motors": list(motors),
                "env_kwargs": sp["env_kwargs"],
                # What the run saw: motors drawn below TRAINING_SEED_LIMIT (or from the
                # datasheet pool's train part), and where best.zip was chosen
                # (stepdamp_agents.selection); never a scored split.
                **({"suite": args.suite} if args.suite is not None else {}),
                **({"motor_pool": args.motor_pool, "pool_draw": _pool_draw(),
                    "pool_dev": {**POOL_DEV_DRAW, "sensors": args.pool_dev_sensors}}
                   if pool else {}),
                "splits": {"motors": "pool-train" if pool else "train",
                           "selection": ("pool-dev" if pool else args.select_on)
                           if args.eval_freq > 0 else "none"},
                "hyperparams": args.hyperparams or f"agents/hyperparams/{args.algo}.yml"}
    return family.agent_config(args.name or f"{args.algo}-{family.kind}", args.algo,
                               sp["env_kwargs"], sp["wrapper_kwargs"], training)


def _pool_draw() -> dict[str, Any]:
    from stepdamp_env.motorpool import PoolDraw, as_json

    return as_json(PoolDraw())


def set_start_action(model: Any, action: Any, algo: str) -> None:
    """ARS with a linear policy with bias: start from the constant action
    ``action`` (its bias; weights stay zero) instead of zero, e.g. a constant
    law tuned on training motors. Hyperparameter ``start_action``."""
    import torch

    policy = getattr(model, "policy", None)
    layers = [m for m in getattr(policy, "action_net", []) if isinstance(m, torch.nn.Linear)]
    k = int(np.prod(model.action_space.shape))
    if algo != "ars" or len(layers) != 1 or layers[0].bias is None:
        raise ParameterError("hyperparameter start_action needs --algo ars with a LinearPolicy "
                             "with_bias=True")
    a = np.asarray(action, dtype=float) if isinstance(action, (list, tuple)) else None
    if a is None or a.shape != (k,) or not np.all(np.isfinite(a)) or np.abs(a).max() > 1.0:
        raise ParameterError(f"hyperparameter start_action={action!r} must be a list of {k} "
                             "numbers in [-1, 1]")
    with torch.no_grad():
        layers[0].bias.copy_(torch.as_tensor(a, dtype=layers[0].bias.dtype))
    model.weights = torch.nn.utils.parameters_to_vector(policy.parameters()).detach()


def save_agent(model: Any, path_zip: str, config: dict[str, Any]) -> None:
    model.save(path_zip)
    with open(os.path.splitext(path_zip)[0] + ".agent.json", "w", encoding="utf-8") as fh:
        json.dump(config, fh, indent=2, default=str)
        fh.write("\n")


# ---------------------------------------------------------------------------
# Training
# ---------------------------------------------------------------------------
def train(args: Args) -> dict[str, Any]:
    import torch
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.logger import configure

    from .per_step import ALGOS

    check_args(args)
    torch.set_num_threads(1)
    family = FAMILIES[args.env]
    sp = split_hyperparams(load_hyperparams(args), args.env)
    motors = training_motors(args)
    if args.envs_per_motor is None and len(motors) > sp["n_envs"]:
        raise ParameterError(f"--pool-motors {len(motors)} is more than the {sp['n_envs']} "
                             "drives (n_envs); allowed: at most n_envs, or give "
                             "--envs-per-preset")
    per_motor = args.envs_per_motor or max(1, sp["n_envs"] // len(motors))
    total = int(args.total_timesteps or sp["n_timesteps"])
    wk = sp["wrapper_kwargs"]
    if args.suite is not None:
        sp["env_kwargs"] = suite_task(sp["env_kwargs"], args.suite)
    env_kwargs = dict(sp["env_kwargs"])
    env_kwargs.pop("motor", None)
    algo_kwargs = dict(sp["algo_kwargs"])
    check_algo_kwargs(algo_kwargs)
    threads = training_threads(args)
    env = family.make_env(motors, per_motor, 1000 * args.seed, env_kwargs, wk, args.algo,
                          algo_kwargs, threads)
    os.makedirs(args.out, exist_ok=True)
    config = _agent_config(args, sp, motors)
    start_action = algo_kwargs.pop("start_action", None)
    if isinstance(algo_kwargs.get("action_noise"), tuple):
        from stable_baselines3.common.noise import NormalActionNoise

        k = env.action_space.shape[0]
        algo_kwargs["action_noise"] = NormalActionNoise(np.zeros(k),
                                                        algo_kwargs["action_noise"][1] * np.ones(k))
    try:
        model = ALGOS[args.algo](sp["policy"], env, seed=args.seed, device="cpu", verbose=0,
                                 **algo_kwargs)
    except (TypeError, ValueError, AssertionError) as exc:
        first = (str(exc).strip().splitlines() or [""])[0]
        raise ParameterError(f"hyperparameters (YAML or --hyperparam) refused by {args.algo}: "
                             f"{first}") from None
    if start_action is not None:
        set_start_action(model, start_action, args.algo)
    family.after_build(env, 1000 * args.seed)
    formats = ["csv"]
    if args.tensorboard:
        try:
            import tensorboard  # noqa: F401

            formats.append("tensorboard")
        except ImportError:
            print("tensorboard is not installed: CSV logs only (pip install tensorboard)")
    model.set_logger(configure(os.path.join(args.out, "logs"), formats))
    validator: Any = None
    if args.eval_freq > 0:
        validator = DevValidator(args.suite or "open-loop", args.motor_pool,
                                 args.pool_dev_sensors) \
            if args.select_on == "dev" else \
            Validator(args, env_kwargs)
    log: dict[str, Any] = {"args": dataclasses.asdict(args), "config": config,
                           "n_envs": env.num_envs, "total_timesteps": total, "evaluations": []}
    best: dict[str, Any] = {}
    checks_s = [0.0]                    # wall seconds spent in dev checks so far
    t0 = time.time()

    def evaluate(tag: str) -> dict[str, Any]:
        start = time.time()
        path = os.path.join(args.out, "_eval.zip")
        save_agent(model, path, config)
        with kept_generators(args.eval_rng == "isolated"):
            res = validator.score(path)
        # learn_s: the wall time up to this check without the checks before it.
        res.update(step=int(model.num_timesteps), wall_s=round(time.time() - t0, 1), tag=tag,
                   learn_s=round(start - t0 - checks_s[0], 2))
        log["evaluations"].append(res)
        head = f"[{res['wall_s']:7.1f} s] step {res['step']:>8d}  "
        if args.select_on == "dev":
            model.logger.record("eval/attenuation_db", res["attenuation_db"])
            msg = (f"{head}dev attenuation IQM {res['attenuation_db']:.2f} dB  gap closed "
                   f"{res['gap_closed']:.3f}  step losses {res['step_losses']}")
        else:
            model.logger.record("eval/headline_iqm", res["headline_iqm"])
            model.logger.record("eval/headline_mean", res["headline_mean"])
            msg = (f"{head}validation headline IQM {res['headline_iqm']:.4f}  mean "
                   f"{res['headline_mean']:.4f}  step losses {res['step_losses']}")
        print(msg, flush=True)
        if validator.better(res, best or None):
            best.clear()
            best.update(res)
            save_agent(model, os.path.join(args.out, "best.zip"), config)
        spent = time.time() - start                         # scoring, saving, logging
        res["check_s"] = round(spent, 2)
        checks_s[0] += spent
        return res

    class Loop(BaseCallback):
        def _on_training_start(self) -> None:
            self.bar = None
            if args.progress:
                from tqdm.auto import tqdm

                self.bar = tqdm(total=total, unit="step", mininterval=2.0,
                                desc=f"{args.algo} seed {args.seed}")
            self.last_eval = self.last_ckpt = 0

        def _on_step(self) -> bool:
            n = self.model.num_timesteps
            if self.bar is not None:
                self.bar.update(n - self.bar.n)
            if validator is not None and n - self.last_eval >= args.eval_freq:
                self.last_eval = n
                res = evaluate("periodic")
                if args.stop_at_db is not None and res["attenuation_db"] >= args.stop_at_db:
                    log["stopped_at_db"] = args.stop_at_db
                    return False
            if args.checkpoint_freq and n - self.last_ckpt >= args.checkpoint_freq:
                self.last_ckpt = n
                os.makedirs(os.path.join(args.out, "checkpoints"), exist_ok=True)
                save_agent(self.model, os.path.join(args.out, "checkpoints",
                                                    f"step_{n}.zip"), config)
            return True

        def _on_training_end(self) -> None:
            if self.bar is not None:
                self.bar.close()

    if validator is not None:
        evaluate("initial (zero residual = base controller)")
    model.learn(total_timesteps=total, callback=Loop())
    train_s = time.time() - t0
    save_agent(model, os.path.join(args.out, "final.zip"), config)
    if validator is not None and "stopped_at_db" not in log:
        evaluate("final")
    log["train_wall_s"] = round(train_s, 1)
    log["wall_s"] = round(time.time() - t0, 1)
    write_training_record(args.out, int(model.num_timesteps), family.seconds_per_step(env),
                          train_s, threads)
    log["best"] = {k: v for k, v in best.items() if k not in ("per_motor", "per_motor_db")} \
        if validator else None
    with open(os.path.join(args.out, "train_log.json"), "w", encoding="utf-8") as fh:
        json.dump(log, fh, indent=2, default=str)
        fh.write("\n")
    print(f"trained {int(model.num_timesteps)} steps in {train_s:.1f} s (wall incl. validation "
          f"{log['wall_s']:.1f} s); wrote {args.out}/final.zip"
          + (", best.zip" if validator else "") + ", train_log.json", flush=True)
    env.close()
    return log


@contextlib.contextmanager
def kept_generators(keep: bool = True) -> Iterator[None]:
    """Put torch's, numpy's and Python's global generators back as they were
    (``keep``): a validation loads the model, whose construction draws torch's
    generator, which the training's next update draws too."""
    if not keep:
        yield
        return
    import random

    import torch

    states = torch.get_rng_state(), np.random.get_state(), random.getstate()
    try:
        yield
    finally:
        torch.set_rng_state(states[0])
        np.random.set_state(states[1])
        random.setstate(states[2])


def training_threads(args: Args) -> int:
    """``args.num_threads``, or all of numba's threads."""
    import numba

    return int(numba.config.NUMBA_NUM_THREADS) if args.num_threads is None \
        else int(args.num_threads)


def write_training_record(out: str, env_steps: int, seconds_per_step: float, wall_s: float,
                          threads: int) -> dict[str, Any]:
    """``training.json`` in ``out``: what the training simulated and how long it took
    (``wall_seconds``: ``model.learn`` with its updates and dev checks)."""
    record = {"env_steps": env_steps, "seconds_per_env_step": seconds_per_step,
              "simulated_seconds": env_steps * seconds_per_step,
              "wall_seconds": round(wall_s, 3), "num_threads": threads,
              "simulated_seconds_per_wall_second": env_steps * seconds_per_step / wall_s
              if wall_s > 0 else None}
    write_json(os.path.join(out, "training.json"), record)
    return record


def train_seeds(args: Args) -> list[dict[str, Any]]:
    """:func:`train` for each of ``args.seeds`` (into ``out/seed<K>``), one after the
    other, or for ``args.seed`` alone into ``out``; prints one line per seed."""
    if not args.seeds:
        return [train(args)]
    check_args(args)
    # Absolute for Ray: a task writes where the driver means (on a cluster: a shared path).
    out = os.path.abspath(args.out) if args.backend == "ray" else args.out
    # A Ray task has one CPU: its drives step on one thread unless told otherwise.
    threads = args.num_threads if args.num_threads is not None or args.backend == "local" else 1
    runs = [dataclasses.replace(args, seed=k, seeds=(), out=os.path.join(out, f"seed{k}"),
                                progress=args.progress and args.backend == "local",
                                num_threads=threads)
            for k in args.seeds]
    if args.backend == "local":
        logs = [train(run) for run in runs]
    else:           # each seed a Ray task (one CPU each); the models are those of local runs
        from stepdamp_env.parallel import default_workers
        from stepdamp_env.ray_backend import backend_map

        # A local Ray gets this machine's cores; each seed is a task of one CPU.
        logs = backend_map(args.backend, args.ray_address)(train, runs, default_workers(),
                                                           max_chunk=1)
    key, label = (("attenuation_db", "best dev dB") if args.select_on == "dev" else
                  ("headline_iqm", "best validation IQM"))
    print(f"{'seed':>4} {'train s':>8} {label:>20}")
    for k, log in zip(args.seeds, logs):
        best = (log.get("best") or {}).get(key, math.nan)
        print(f"{k:>4} {log['train_wall_s']:8.1f} {best:20.4f}")
    return logs


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m stepdamp_agents.train", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    train_seeds(args_from_namespace(p.parse_args(argv)))
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
