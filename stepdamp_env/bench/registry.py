"""Which policies exist, and how a policy spec becomes fresh policy instances.

Baselines and agents fill the registry themselves: each package registers its
policies with :func:`register_policy` (and file loaders with
:func:`register_loader`) in a function published under the entry-point group
``stepdamp.policies``; :func:`load_plugins` calls those once. The leaderboard
names no baseline and no agent: it asks the registry.

A policy spec (``stepdamp leaderboard --policy SPEC``) is one of:

* a registered name (:func:`default_policy_names` lists the default ones);
* ``package.module:attr`` or ``path/to/file.py:attr``: a Policy class or factory
  (called without arguments for every run) or a Policy instance (deep-copied
  for every run). **This imports and runs code: use trusted sources only.**
* a model file that a registered loader accepts (for example a ``.zip`` that
  ``stepdamp train`` wrote, with its ``.agent.json`` beside it), else a bare
  stable-baselines3 ``.zip`` (:class:`SB3Policy`). **SB3 files unpickle Python
  objects: load only files you trust.**
"""

from __future__ import annotations

import copy
import hashlib
import importlib
import importlib.metadata
import importlib.util
import os
import sys
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..io import file_digest, parse_json, read_json, related_files, tree_digest
from ..params import ParameterError
from ..ray_backend import BY_VALUE
from .network import predict_rows
from .policy import (MotorKnowledge, Policy, PolicyContext, check_policy, reference_policy,
                     resolve_estimate)
from .protocol import REFERENCE_POLICY

__all__ = ["ENTRY_POINT_GROUP", "PolicySource", "RegisteredPolicy", "register_policy",
           "register_loader", "registered_policies", "default_policy_names", "load_plugins",
           "resolve_policy", "SB3Policy"]

ENTRY_POINT_GROUP = "stepdamp.policies"


@dataclass(frozen=True)
class RegisteredPolicy:
    """A named policy: its factory, its kind and whether the leaderboard runs it by default."""

    name: str
    make: Callable[[], Policy]
    kind: str = "baseline"           # "baseline" or "agent"
    default: bool = True
    description: str = ""
    training_seeds: Mapping[int, Callable[[], Policy]] | None = None


@dataclass
class PolicySource:
    """Makes fresh policy instances for one leaderboard entry.

    ``training_seeds`` (learned entries): a factory per training seed; the
    v1 protocol runs and pools every one. ``make`` is the entry's single
    model (the one v0 runs).
    """

    spec: str
    name: str
    make: Callable[[], Any]
    training_seeds: Mapping[int, Callable[[], Any]] | None = None
    origin: str | None = None          # the module a policy instance's class comes from

    def factories(self, pooled: bool) -> dict[int | None, Callable[[], Any]]:
        """Training seed -> factory: every seed if ``pooled`` and known, else
        ``{None: make}`` (one model, its seed not recorded)."""
        if pooled and self.training_seeds:
            return dict(sorted(self.training_seeds.items()))
        return {None: self.make}

    def fingerprint(self, exclude: Sequence[str] = ()) -> str:
        """sha256 of what this entry stands for, read now: its spec, the files
        the spec names (a model with its side files, a directory of models, a
        policy file with its side files) and the code its factories come from
        (a package's whole tree: code and committed models; a single-module
        file alone). ``exclude``: paths left out of directory trees (the
        leaderboard's own output directory). No part is cached, so a file
        changed since the last call changes the key."""
        h = hashlib.sha256(self.spec.encode())
        files: set[str] = set()
        trees: set[str] = set()
        path = self.spec.rpartition(":")[0] if ":" in self.spec and \
            not os.path.exists(self.spec) else self.spec
        if os.path.isfile(path):
            files.update(related_files(path))
        elif os.path.isdir(path):
            trees.add(os.path.abspath(path))
        factories = [self.make, *(self.training_seeds or {}).values()]
        modules = {getattr(f, "__module__", None) for f in factories} | {self.origin}
        for module in sorted(modules - {None}):
            top = sys.modules.get(str(module).split(".")[0])
            where = getattr(top, "__file__", None)
            if not where:
                continue
            if hasattr(top, "__path__"):       # a package: its whole folder
                trees.add(os.path.dirname(os.path.abspath(where)))
            else:                              # a module file (a policy file): itself
                files.update(related_files(where))
        for root in sorted(trees):
            h.update(b"tree\0" + root.encode("utf-8", "surrogateescape") + b"\0")
            h.update(tree_digest(root, exclude=exclude).encode())
        for f in sorted(files):
            h.update(b"file\0" + f.encode("utf-8", "surrogateescape") + b"\0")
            h.update(file_digest(f).encode())
        return h.hexdigest()


_REGISTRY: dict[str, RegisteredPolicy] = {}
# (loader name, accepts(path) -> bool, load(path) -> PolicySource), tried in order.
_LOADERS: list[tuple[str, Callable[[str], bool], Callable[[str], PolicySource]]] = []
_PLUGINS_LOADED = False


def register_policy(name: str, make: Callable[[], Policy], *, kind: str = "baseline",
                    default: bool = True, description: str = "",
                    training_seeds: Mapping[int, Callable[[], Policy]] | None = None) -> None:
    """Make ``name`` resolvable. Registering the same name again with another
    factory is an error (names never collide silently); the same factory again
    is a no-op. ``training_seeds``: a learned entry's model per training seed
    (pooled by stepdamp-bench v1; ``make`` is the one v0 runs)."""
    old = _REGISTRY.get(name)
    if old is not None:
        if old.make is make:
            return
        raise ParameterError(f"policy name {name!r} is registered twice "
                             f"({old.description or old.kind} and {description or kind})")
    if kind not in ("baseline", "agent"):
        raise ValueError(f"kind={kind!r} is not one of ['baseline', 'agent']")
    _REGISTRY[name] = RegisteredPolicy(name, make, kind, default, description,
                                       dict(training_seeds) if training_seeds else None)


def register_loader(name: str, accepts: Callable[[str], bool],
                    load: Callable[[str], PolicySource]) -> None:
    """A loader for policy files: ``accepts(path)`` says whether it reads it."""
    if all(n != name for n, _, _ in _LOADERS):
        _LOADERS.append((name, accepts, load))


def load_plugins() -> None:
    """Call every ``stepdamp.policies`` entry point once (in name order); a plugin
    that fails is an error naming it, never skipped in silence."""
    global _PLUGINS_LOADED
    if _PLUGINS_LOADED:
        return
    for ep in sorted(importlib.metadata.entry_points(group=ENTRY_POINT_GROUP),
                     key=lambda e: e.name):
        try:
            ep.load()()
        except Exception as exc:  # noqa: BLE001 - named and re-raised as one line
            raise ParameterError(f"policy plugin {ep.name!r} ({ep.value}) failed to load: "
                                 f"{type(exc).__name__}: {exc}") from None
    _PLUGINS_LOADED = True


def registered_policies() -> dict[str, RegisteredPolicy]:
    """Every registered policy by name, in registration order (a copy)."""
    load_plugins()
    return dict(_REGISTRY)


def default_policy_names() -> tuple[str, ...]:
    """What a leaderboard runs by default: every registered default policy."""
    return tuple(n for n, p in registered_policies().items() if p.default)


class SB3Policy:
    """A bare stable-baselines3 model as a :class:`~.policy.Policy`: deterministic predict.

    Env options: the JSON file beside the model with the same stem if present
    (``estimate`` may be "exact", "identified" or "nominal"), else harmonic
    residuals on top of the patent feedforward with the identified model.
    """

    DEFAULT_OPTIONS = {"base_controller": "patent-ff", "estimate": "identified",
                       "action_mode": "harmonic"}

    def __init__(self, name: str, model: Any, options: Mapping[str, Any] | None) -> None:
        self.name = name
        self.model = model
        self.options = dict(options) if options else dict(self.DEFAULT_OPTIONS)

    def env_options(self, knowledge: MotorKnowledge) -> dict[str, Any]:
        out = dict(self.options)
        if isinstance(out.get("estimate"), str):
            out["estimate"] = resolve_estimate(out["estimate"], knowledge)
        return out

    def reset(self, context: PolicyContext) -> None:
        pass

    def act(self, observation: np.ndarray) -> np.ndarray:
        # SB3's deterministic predict, through the CPU-independent network.
        return np.asarray(predict_rows(self.model, np.asarray(observation, dtype=np.float32)[None])
                          [0], dtype=np.float32)


def _sb3_algo_class(path: str) -> list[Any]:
    """The SB3 algorithm class of a saved model, from the policy class in its metadata."""
    import zipfile

    import stable_baselines3 as sb3

    module = ""
    try:
        with zipfile.ZipFile(path) as zf:
            data = parse_json(zf.read("data").decode("utf-8"), f"SB3 model {path!r}")
        module = str(data.get("policy_class", {}).get("__module__", ""))
    except (KeyError, ValueError, zipfile.BadZipFile, AttributeError):
        pass
    for key, algo in ((".sac.", "SAC"), (".td3.", "TD3"), (".ddpg.", "DDPG"),
                      (".dqn.", "DQN"), (".ppo.", "PPO"), (".a2c.", "A2C")):
        if key in module + ".":
            return [getattr(sb3, algo)]
    # ActorCriticPolicy lives in common.policies (PPO and A2C); else try them all.
    return [sb3.PPO, sb3.SAC, sb3.TD3, sb3.A2C]


def _load_sb3_zip(spec: str) -> PolicySource:
    path = os.path.abspath(spec)
    side = os.path.splitext(path)[0] + ".json"
    options = None
    if os.path.isfile(side):
        options = read_json(side, "env options")
        if not isinstance(options, dict):
            raise ParameterError(f"{side!r} must hold a JSON object of env options")
    errors = []
    model = None
    for algo in _sb3_algo_class(path):
        try:
            model = algo.load(path, device="cpu")
            break
        except Exception as exc:  # noqa: BLE001 - try the next algorithm
            errors.append(f"{algo.__name__}: {exc}")
    if model is None:
        raise ParameterError(f"cannot load SB3 model {spec!r}: {'; '.join(errors)}")
    _check_observations(spec, model, options or SB3Policy.DEFAULT_OPTIONS, side)
    name = os.path.splitext(os.path.basename(path))[0]
    return PolicySource(spec, name, lambda: SB3Policy(name, model, options))


def _check_observations(spec: str, model: Any, options: Mapping[str, Any], side: str) -> None:
    """A one-line error if the model does not take the observations of
    StepperDamp-v0 with ``options`` (a model saved without its env options)."""
    from ..env.options import EnvOptions
    from ..env.scalar import EpisodeSampler

    probe = {k: v for k, v in options.items() if k != "estimate"}   # no effect on the shape
    want = tuple(EpisodeSampler(EnvOptions.from_kwargs(probe)).observation_space().shape)
    got = tuple(getattr(model.observation_space, "shape", ()) or ())
    if got != want:
        raise ParameterError(
            f"SB3 model {spec!r} takes observations of shape {got}, but StepperDamp-v0 with "
            f"{'its' if os.path.isfile(side) else 'the default'} env options {dict(options)} "
            f"gives {want}; keep its .agent.json beside it (a `stepdamp train` model) or write "
            f"the env options it was trained with to {side!r}")


def _import_attr(spec: str) -> Any:
    target, _, attr = spec.rpartition(":")
    try:
        if target.endswith(".py"):
            path = os.path.abspath(target)
            if not os.path.isfile(path):
                raise ImportError(f"no file {target!r}")
            module_name = "stepdamp_user_policy_" + \
                os.path.splitext(os.path.basename(path))[0].replace("-", "_")
            module_spec = importlib.util.spec_from_file_location(module_name, path)
            if module_spec is None or module_spec.loader is None:
                raise ImportError(f"cannot import {target!r}")
            module = importlib.util.module_from_spec(module_spec)
            sys.modules[module_name] = module    # forked workers and pickling find it
            setattr(module, BY_VALUE, True)      # Ray's workers cannot import it by name
            module_spec.loader.exec_module(module)
        else:
            module = importlib.import_module(target)
        return getattr(module, attr)
    except (ImportError, AttributeError, SyntaxError) as exc:
        raise ParameterError(f"policy {spec!r}: {exc}") from None


def resolve_policy(spec: str) -> PolicySource:
    """A registered name, ``module:attr``, ``file.py:attr`` or a model file
    (see the module docstring). Whatever goes wrong while loading it is a
    one-line ``ParameterError`` naming the spec."""
    try:
        source = _resolve(spec)
        source.make()                   # a file that cannot become a policy fails here
        return source
    except ParameterError:
        raise
    except Exception as exc:        # the user's code or file: any error is theirs
        first = (str(exc).strip().splitlines() or [""])[0]
        raise ParameterError(f"policy {spec!r} cannot be loaded: {type(exc).__name__}: "
                             f"{first}") from exc


def _resolve(spec: str) -> PolicySource:
    registry = registered_policies()
    if spec in registry:
        return PolicySource(spec, spec, registry[spec].make, registry[spec].training_seeds)
    if os.path.exists(spec):
        for _, accepts, load in _LOADERS:
            if accepts(spec):
                return load(spec)
        if spec.endswith(".zip") and os.path.isfile(spec):
            return _load_sb3_zip(spec)
    elif spec.endswith(".zip"):
        raise ParameterError(f"policy file {spec!r} does not exist")
    if ":" in spec:
        obj = _import_attr(spec)
        if isinstance(obj, type) or (callable(obj) and not hasattr(obj, "act")):
            probe = obj()
            check_policy(probe, spec)
            return PolicySource(spec, str(probe.name), obj)
        check_policy(obj, spec)
        return PolicySource(spec, str(obj.name), lambda: copy.deepcopy(obj),
                            origin=type(obj).__module__)
    raise ParameterError(f"policy {spec!r} is not a registered policy {list(registry)}, "
                         "a 'package.module:attr' or 'file.py:attr' path or a model file")


# The protocol's reference (every score is a ratio to it) is always registered.
register_policy(REFERENCE_POLICY, reference_policy, kind="baseline",
                description="no damping: the base controller without feedforward (reference)")
