"""The training command's settings: :class:`Args` (one dataclass that also builds
the CLI, :mod:`.arguments`), their checks, and the hyperparameters read from
agents/hyperparams/<algo>.yml with the command line's overrides."""

from __future__ import annotations

import argparse
import math
import os
from dataclasses import dataclass
from typing import Any

from stepdamp_env.bench.protocol import TRAINING_SEED_LIMIT
from stepdamp_env.motorpool import MOTOR_POOLS as DATASHEET_POOLS
from stepdamp_env.params import ParameterError
from stepdamp_env.presets import preset_names

from . import arguments
from .arguments import check_ranges, option
from .family import TrainingFamily
from .selection import POOL_DEV_SENSORS, SELECTION_SPLITS
from .task import ENV_ID_V1, RESIDUAL_ENV_ID, SUITE_TASKS
from .train_gain_selector import FAMILY as GAIN_SELECTOR
from .train_per_step import FAMILY as PER_STEP

#: The agent families, by the env they train on (``--env``).
FAMILIES: dict[str, TrainingFamily] = {f.env_id: f for f in (PER_STEP, GAIN_SELECTOR)}

__all__ = ["FAMILIES", "ALGO_CHOICES", "Args", "ENV_IDS", "HYPERPARAMS_DIR", "MOTOR_POOLS",
           "POSITIVE_INT_KWARGS", "PRESETS", "add_arguments", "args_from_namespace", "check_args",
           "load_hyperparams", "parse_overrides", "parse_policy_kwargs", "parse_seeds",
           "split_hyperparams"]


HYPERPARAMS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "hyperparams")


PRESETS = tuple(preset_names())


ENV_IDS = tuple(FAMILIES)


ALGO_CHOICES = ("ars", "ppo", "ppo_lstm", "sac", "td3")


def parse_seeds(text: str) -> tuple[int, ...]:
    """``"1-5"``, ``"1,3,7"`` or ``"2"`` to a tuple of seeds."""
    out: list[int] = []
    try:
        for part in text.split(","):
            lo, sep, hi = part.strip().partition("-")
            out.extend(range(int(lo), int(hi) + 1) if sep else [int(lo)])
    except ValueError:
        raise ParameterError(f"--seeds {text!r}: expected a range like 1-5 or a list like "
                             "1,3,7") from None
    if not out or len(set(out)) != len(out):
        raise ParameterError(f"--seeds {text!r}: give each seed once, at least one")
    return tuple(out)


def parse_overrides(items: list[str]) -> dict[str, Any]:
    """``--hyperparam KEY=VALUE`` items to hyperparameter overrides (values parsed as YAML)."""
    import yaml

    extra = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ParameterError(f"--hyperparam {item!r}: expected KEY=VALUE")
        try:
            parsed = yaml.safe_load(value)
        except yaml.YAMLError:
            raise ParameterError(f"--hyperparam {item!r}: the value is not valid YAML") from None
        if isinstance(parsed, str):
            try:        # YAML 1.1 reads 1e-4 (no dot) as a string
                parsed = float(parsed)
            except ValueError:
                pass
        extra[key.strip()] = parsed
    return extra


def _int_or_text(text: str) -> int | str:
    """An option's integer, or its text as given (refused with its range by check_args)."""
    try:
        return int(text)
    except ValueError:
        return text


def _float_or_text(text: str) -> float | str:
    """An option's number, or its text as given (refused with its range by check_args)."""
    try:
        return float(text)
    except ValueError:
        return text


#: ``--eval-rng``: validations isolated from the training's generators, or drawing
#: torch's as before 0.18.0 (the committed models).
EVAL_RNG_CHOICES = ("isolated", "shared")
#: Where training motors come from (``--motor-pool``).
MOTOR_POOLS = ("presets", *DATASHEET_POOLS)


@dataclass
class Args:
    """All arguments of a training run; each field is its ``--name-with-dashes``
    option too (:mod:`stepdamp_agents.arguments`), with its help and range."""

    algo: str = option("ars", "algorithm (hyperparameters from agents/hyperparams/<algo>.yml; "
                       "ars and ppo_lstm on StepperDamp-v1 only)", choices=ALGO_CHOICES)
    seed: int = option(1, "torch/numpy seed; env seeds start at 1000*seed", low=0, high=999)
    seeds: tuple[int, ...] = option((), "train several seeds one after the other (e.g. 1-5 or "
                                    "1,3), each into DIR/seed<K>; replaces --seed",
                                    metavar="K-L", parse=parse_seeds, low=0, high=999)
    env: str = option(ENV_ID_V1, "StepperDamp-v1: per-step agents (default); "
                      "StepperDampResidual-v0: the v0 gain selector", choices=ENV_IDS)
    suite: str | None = option(None, "the stepdamp-bench suite trained for (StepperDamp-v1): "
                               "its mode, drive and speeds (agents/task.py SUITE_TASKS); the "
                               "model runs in that suite only. Default: the task as the YAML "
                               "and --hyperparam give it, run in every suite", choices=tuple(SUITE_TASKS))
    select_on: str = option("validation", "where best.zip is chosen: 'dev', v3's dev split "
                            "(v4's for moves) of the suite (attenuation dB, higher is better); 'validation', "
                            "motors drawn from the training distribution (v1's headline "
                            "ratio; the committed v1-era agents)", choices=SELECTION_SPLITS)
    out: str = option("runs/residual", "output directory (models, logs)", metavar="DIR")
    total_timesteps: int | None = option(None, "agent steps to train (default: n_timesteps of "
                                         "the YAML)", metavar="STEPS", low=1, high=1e12)
    hyperparams: str | None = option(None, "zoo YAML (default: agents/hyperparams/<algo>.yml)",
                                     metavar="FILE.yml")
    motors: tuple[str, ...] = option(PRESETS, "presets the training motors are drawn around",
                                     metavar="PRESET", many=True, flag="--presets")
    motor_pool: str = option("presets", "where the training motors come from: 'presets', "
                             "drawn around --presets; 'datasheets', real catalogue motors' "
                             "datasheets (stepdamp_env.motorpool: drawn from the pool's train "
                             "part, selected on its dev part; needs --select-on dev or "
                             "--eval-freq 0); 'datasheets-unrelated', the same without the "
                             "scored catalogue motors' relatives", choices=MOTOR_POOLS)
    pool_motors: int = option(32, "with a --motor-pool of datasheets: training motors drawn from "
                              "the pool (each its own drive model, --envs-per-preset drives "
                              "each)", metavar="N", low=1, high=1024)
    envs_per_motor: int | None = option(None, "vectorised drives per preset (default: n_envs "
                                        "of the YAML / presets)", metavar="N", low=1, high=4096,
                                        flag="--envs-per-preset")
    eval_freq: int = option(5_000, "agent steps between validations (0: never)",
                            metavar="STEPS", low=0, high=1e12)
    eval_rng: str = option("isolated", "what a validation may draw: 'isolated' (default), "
                           "nothing the training draws (torch's, numpy's and Python's global "
                           "generators are put back after it), so --eval-freq changes no "
                           "model; 'shared', as before 0.18.0: loading the model for a "
                           "validation draws torch's generator (how the committed models were "
                           "trained)", choices=EVAL_RNG_CHOICES)
    pool_dev_sensors: str = option("protocol", "with a --motor-pool of datasheets: the dev "
                                   "motors' sensors, 'protocol' (default: the board's, as "
                                   "--motors and the scored catalogue give them) or "
                                   "'motor-file' (no current noise: how the committed mid-band "
                                   "pool models were selected)", choices=POOL_DEV_SENSORS)
    val_seed: int = option(900_000, "seed of the validation motors' draw",
                           low=0, high=TRAINING_SEED_LIMIT - 1001)
    val_motors_per_preset: int = option(2, "validation motors drawn around each preset",
                                        metavar="N", low=1, high=1000)
    stop_at_db: float | None = option(None, "with --select-on dev: stop training at the "
                                      "first dev check during training whose attenuation "
                                      "reaches this many dB (its model is final.zip); "
                                      "default: train --total-timesteps",
                                      metavar="DB", parse=_float_or_text)
    checkpoint_freq: int = option(10_000, "agent steps between checkpoints (0: never)",
                                  metavar="STEPS", low=0, high=1e12)
    progress: bool = option(True, "no progress bar", negate="no-progress")
    tensorboard: bool = option(True, "no TensorBoard log", negate="no-tensorboard")
    name: str | None = option(None, 'policy name in the agent config (default: "<algo>-per-step" '
                              'on v1, "<algo>-gain-selector" on v0); on the leaderboard the '
                              "model shows as NAME@<file stem>, e.g. ars-per-step@best")
    extra: dict[str, Any] = option(None, "override one YAML hyperparameter (value parsed as "
                                   "YAML); repeatable", metavar="KEY=VALUE", flag="--hyperparam",
                                   repeat=True, parse=parse_overrides, default_factory=dict)
    num_threads: int | None = option(None, "numba threads that step the training drives, at "
                                     "most NUMBA_NUM_THREADS (default: all of them, one per "
                                     "core; 1 per seed with --backend ray); any count gives "
                                     "the same model", metavar="N", parse=_int_or_text)
    backend: str = option("local", "--seeds one after the other here, or as Ray tasks "
                          "(extra [ray])", choices=("local", "ray"))
    ray_address: str | None = option(None, "with --backend ray: a running cluster ('auto' or "
                                     "HOST:PORT); default: a local Ray on this machine's cores",
                                     metavar="ADDR")


# ---------------------------------------------------------------------------
# Configuration: the zoo YAML
# ---------------------------------------------------------------------------
def load_hyperparams(args: Args) -> dict[str, Any]:
    """The ``args.env`` entry of the algorithm's zoo YAML (a copy)."""
    import yaml

    path = args.hyperparams or os.path.join(HYPERPARAMS_DIR, f"{args.algo}.yml")
    try:
        with open(path, encoding="utf-8") as fh:
            data = yaml.safe_load(fh)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        first = (str(exc).strip().splitlines() or [""])[0]
        raise ParameterError(f"--hyperparams {path!r}: cannot read it as YAML: {first}") \
            from None
    if not isinstance(data, dict) or not isinstance(data.get(args.env), dict):
        raise ParameterError(f"--hyperparams {path!r}: no {args.env!r} mapping in it")
    hp = dict(data[args.env])
    hp.update(args.extra)
    return hp


def check_args(args: Args) -> None:
    """Every argument in its range, else a one-line ``ParameterError``."""
    # Ranges (env seeds 1000*seed + k stay below TRAINING_SEED_LIMIT) and choices.
    check_ranges(args)
    stop = args.stop_at_db
    if stop is not None and (isinstance(stop, (bool, str)) or not math.isfinite(stop)
                             or not -200.0 <= stop <= 200.0):
        raise ParameterError(f"--stop-at-db {args.stop_at_db!r} is outside its allowed range "
                             "[-200, 200] (dB)")
    if stop is not None and (args.select_on != "dev" or args.eval_freq <= 0):
        raise ParameterError("--stop-at-db needs --select-on dev and --eval-freq above 0")
    if stop is not None and args.algo == "ars":
        # sb3-contrib's ARS runs its updates to the end whatever a callback returns.
        raise ParameterError("--stop-at-db is not supported with --algo ars (its updates "
                             "run to --total-timesteps); use ppo, ppo_lstm, sac or td3")
    if args.ray_address is not None and args.backend != "ray":
        raise ParameterError("--ray-address needs --backend ray")
    import numba

    top = int(numba.config.NUMBA_NUM_THREADS)
    if args.num_threads is not None and (isinstance(args.num_threads, bool) or not isinstance(
            args.num_threads, int) or not 1 <= args.num_threads <= top):
        raise ParameterError(f"--num-threads {args.num_threads!r}: allowed are the integers in "
                             f"[1, {top}] ({top} = numba's threads, NUMBA_NUM_THREADS)")
    if isinstance(args.extra.get("env_kwargs"), dict) and "num_threads" in args.extra["env_kwargs"]:
        raise ParameterError("env_kwargs: num_threads is not an env option here; use "
                             "--num-threads N")
    algos = FAMILIES[args.env].algos
    if args.algo not in algos:
        raise ParameterError(f"--algo {args.algo!r} is not one of {list(algos)} "
                             f"(for --env {args.env})")
    if args.suite == "moves" and args.select_on != "dev" and args.eval_freq > 0:
        # The validation motors are run at constant speeds: not what moves score.
        raise ParameterError("--suite moves selects on --select-on dev (v4's dev split of "
                             "the moves suite) or on nothing (--eval-freq 0)")
    if args.env != ENV_ID_V1 and (args.suite is not None or args.select_on != "validation"):
        raise ParameterError(f"--suite and --select-on dev need --env {ENV_ID_V1}")
    given = args.extra.get("env_kwargs") or {}
    if args.suite is not None and isinstance(given, dict):
        clash = sorted(k for k in given if k in SUITE_TASKS[args.suite] and
                       (k != "overrides" or set(given[k] or {}) & {"drive_mode"}))
        if clash:
            raise ParameterError(f"--hyperparam env_kwargs {clash}: --suite {args.suite} sets them "
                                 "(agents/task.py SUITE_TASKS); leave them out or drop --suite")
    pool = args.motor_pool != "presets"
    if pool and (args.env != ENV_ID_V1 or (args.select_on != "dev" and args.eval_freq > 0)):
        raise ParameterError(f"--motor-pool {args.motor_pool} needs --env {ENV_ID_V1} and "
                             "--select-on dev (the pool's dev motors) or --eval-freq 0")
    if pool and tuple(args.motors) != PRESETS:
        raise ParameterError(f"--presets does not apply with --motor-pool {args.motor_pool} (its "
                             "motors are drawn from the pool); leave it out")
    if not pool and args.pool_dev_sensors != "protocol":
        raise ParameterError(f"--pool-dev-sensors needs --motor-pool one of "
                             f"{list(DATASHEET_POOLS)}")
    if not pool and args.pool_motors != 32:
        raise ParameterError(f"--pool-motors needs --motor-pool one of {list(DATASHEET_POOLS)}")
    unknown = sorted(set(args.motors) - set(PRESETS))
    if unknown or not args.motors:
        raise ParameterError(f"--presets {list(args.motors)}: choose presets from {list(PRESETS)}")


#: Algorithm settings that must be positive integers (SB3 fails late, or not at all, otherwise).
POSITIVE_INT_KWARGS = ("n_steps", "batch_size", "n_epochs", "buffer_size", "learning_starts",
                       "train_freq", "gradient_steps", "policy_delay", "n_delta", "n_top",
                       "n_eval_episodes")


def check_algo_kwargs(kwargs: dict[str, Any]) -> None:
    for key in POSITIVE_INT_KWARGS:
        value = kwargs.get(key)
        if value is None or key in ("learning_starts", "train_freq") and isinstance(value, tuple):
            continue
        low = 0 if key == "learning_starts" else 1
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ParameterError(f"hyperparameter {key}={value!r} is outside its allowed range "
                                 f"[{low}, inf) (integer)")
    lr = kwargs.get("learning_rate")
    if lr is not None and not callable(lr) and (
            isinstance(lr, bool) or not isinstance(lr, (int, float)) or not math.isfinite(lr)
            or lr <= 0):
        raise ParameterError(f"hyperparameter learning_rate={lr!r} must be a positive number")


def parse_policy_kwargs(text: str) -> dict[str, Any]:
    """The zoo's ``policy_kwargs`` string, e.g. ``"dict(net_arch=[64, 64], log_std_init=-1.5,
    activation_fn=nn.Tanh)"``, parsed without running it: literals, ``dict(...)``
    with keywords, and torch.nn module classes named ``nn.X`` or ``th.nn.X``."""
    import ast

    import torch

    def bad(node: ast.AST) -> ValueError:
        return ValueError(f"policy_kwargs: {ast.unparse(node)!r} is not allowed; use literals, "
                          "dict(...) and torch.nn classes (nn.ReLU, nn.Tanh, ...)")

    def value(node: ast.AST) -> Any:
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                and node.func.id == "dict" and not node.args:
            return {kw.arg: value(kw.value) for kw in node.keywords if kw.arg is not None}
        if isinstance(node, ast.Attribute):
            path = ast.unparse(node)
            for prefix in ("th.nn.", "torch.nn.", "nn."):
                if path.startswith(prefix) and "." not in path[len(prefix):]:
                    cls = getattr(torch.nn, path[len(prefix):], None)
                    if isinstance(cls, type) and issubclass(cls, torch.nn.Module):
                        return cls
            raise bad(node)
        if isinstance(node, ast.Dict):
            return {value(k): value(v) for k, v in zip(node.keys, node.values) if k is not None}
        if isinstance(node, (ast.List, ast.Tuple)):
            items = [value(x) for x in node.elts]
            return items if isinstance(node, ast.List) else tuple(items)
        try:
            return ast.literal_eval(node)
        except ValueError:
            raise bad(node) from None

    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise ValueError(f"policy_kwargs: cannot parse {text!r}: {exc.msg}") from None
    out = value(tree.body)
    if not isinstance(out, dict):
        raise ValueError(f"policy_kwargs must be a dict, got {text!r}")
    return out


def split_hyperparams(hp: dict[str, Any], env_id: str = RESIDUAL_ENV_ID) -> dict[str, Any]:
    """Zoo keys to (n_envs, n_timesteps, env kwargs, wrapper kwargs, algo kwargs).

    The env and wrapper kwargs are the family's reference task updated by the
    YAML's ``env_kwargs`` (:meth:`TrainingFamily.task_kwargs`).
    """
    hp = dict(hp)
    n_envs = int(hp.pop("n_envs", 16))
    n_timesteps = int(float(hp.pop("n_timesteps", 1e5)))
    if "env_wrapper" in hp:
        raise ParameterError(f"hyperparameter env_wrapper: {env_id} is the residual "
                             "task already; set its kwargs under env_kwargs")
    env_kwargs, wrapper_kwargs = FAMILIES[env_id].task_kwargs(hp.pop("env_kwargs", None))
    policy = hp.pop("policy", "LinearPolicy" if "n_delta" in hp else "ResidualMlpPolicy")
    if isinstance(hp.get("policy_kwargs"), str):
        hp["policy_kwargs"] = parse_policy_kwargs(hp["policy_kwargs"])   # zoo's convention
    for key in ("train_freq",):
        if isinstance(hp.get(key), list):
            hp[key] = tuple(hp[key])
    if "noise_type" in hp:                   # zoo: TD3's action noise by name
        kind = hp.pop("noise_type")
        std = float(hp.pop("noise_std", 0.1))
        if kind != "normal":
            raise ValueError(f"noise_type {kind!r}: only 'normal' is supported here")
        hp["action_noise"] = ("normal", std)     # made in train(), once the action size is known
    hp.pop("normalize", None)
    return {"n_envs": n_envs, "n_timesteps": n_timesteps, "env_kwargs": env_kwargs,
            "wrapper_kwargs": wrapper_kwargs, "policy": policy, "algo_kwargs": hp}


# ---------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------
def add_arguments(p: argparse.ArgumentParser) -> None:
    """One option per field of :class:`Args` (``stepdamp train`` uses these too)."""
    arguments.add_arguments(p, Args)


def args_from_namespace(ns: argparse.Namespace) -> Args:
    return arguments.from_namespace(Args, ns)
