"""The house rules (docs/architecture.md), read from the source.

* A floor imports only floors below it (or modules of its own floor).
* Only the CLI, the composition root, imports the baselines and the agents.
* No module imports another module's private (``_name``) objects, and no code
  reads another object's private attributes (``x._name`` with x not self/cls).
"""

from __future__ import annotations

import ast
import os

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# Module (or package prefix) -> floor; longest prefix wins.
FLOORS = {
    "stepdamp_env.version": 0, "stepdamp_env.params": 0, "stepdamp_env.presets": 0,
    "stepdamp_env.io": 0, "stepdamp_env.parallel": 0, "stepdamp_env.kernel": 0,
    "stepdamp_env.estimators": 0, "stepdamp_env.numba_cache": 0, "stepdamp_env.fixedmath": 0,
    "stepdamp_env.simulation": 1, "stepdamp_env.response": 1,
    "stepdamp_env.identify": 2, "stepdamp_env.sweep": 2, "stepdamp_env.plots": 2,
    "stepdamp_env.analysis": 2,
    "stepdamp_env": 3,                       # the package root exports the env floor
    "stepdamp_env.env": 3, "stepdamp_env.envs": 3, "stepdamp_env.sb3": 3,
    "stepdamp_env.bench": 4, "stepdamp_env.leaderboard": 4,
    "stepdamp_baselines": 5, "stepdamp_agents": 5,
    "stepdamp_env.cli": 6,
}
SOURCES = {"stepdamp_env": "stepdamp_env", "stepdamp_baselines": "baselines",
           "stepdamp_agents": "agents"}
# Public API of namedtuples, not private state.
NAMEDTUPLE_API = {"_exit",  # os._exit: a documented public function
                  "_fields", "_asdict", "_replace", "_make"}


def _modules() -> dict[str, str]:
    out = {}
    for package, folder in SOURCES.items():
        for dirpath, _, files in os.walk(os.path.join(ROOT, folder)):
            for f in files:
                if f.endswith(".py"):
                    rel = os.path.relpath(os.path.join(dirpath, f), os.path.join(ROOT, folder))
                    parts = [package] + rel[:-3].split(os.sep)
                    if parts[-1] == "__init__":
                        parts = parts[:-1]
                    out[".".join(parts)] = os.path.join(dirpath, f)
    return out


MODULES = _modules()


def test_benchmarks_read_no_private_attributes():
    for name in sorted(os.listdir(os.path.join(ROOT, "benchmarks"))):
        if not name.endswith(".py"):
            continue
        tree = ast.parse(open(os.path.join(ROOT, "benchmarks", name), encoding="utf-8").read())
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr.startswith("_") \
                    and not node.attr.startswith("__"):
                assert False, f"benchmarks/{name}:{node.lineno} reads {ast.unparse(node)}"


def _floor(module: str) -> int:
    best = max((p for p in FLOORS if module == p or module.startswith(p + ".")), key=len)
    return FLOORS[best]


def _imports(module: str, path: str) -> list[tuple[str, str | None, int]]:
    """(imported module, imported name or None, line) of every project import."""
    is_package = path.endswith("__init__.py")
    package = module if is_package else module.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(open(path, encoding="utf-8").read())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                out.append((sub, None, node.lineno) if sub in MODULES
                           else (target, alias.name, node.lineno))
        elif isinstance(node, ast.Import):
            out += [(alias.name, None, node.lineno) for alias in node.names]
    return [x for x in out if x[0].split(".")[0] in SOURCES or
            x[0].split(".")[0] in ("baselines", "agents")]


@pytest.mark.parametrize("module", sorted(MODULES))
def test_floors_only_look_down(module):
    own = _floor(module)
    for target, _, line in _imports(module, MODULES[module]):
        assert target.split(".")[0] not in ("baselines", "agents"), \
            f"{module}:{line} imports {target}: use the installed names stepdamp_baselines/agents"
        assert _floor(target) <= own, f"{module}:{line} (floor {own}) imports {target} " \
                                      f"(floor {_floor(target)})"


def test_only_the_cli_imports_baselines_and_agents():
    for module, path in MODULES.items():
        if not module.startswith("stepdamp_env") or module == "stepdamp_env.cli":
            continue
        for target, _, line in _imports(module, path):
            assert not target.startswith(("stepdamp_baselines", "stepdamp_agents")), \
                f"{module}:{line} imports {target}"


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_private_names_cross_modules(module):
    path = MODULES[module]
    for target, name, line in _imports(module, path):
        if name is not None:
            assert not (name.startswith("_") and not name.startswith("__")), \
                f"{module}:{line} imports the private {target}.{name}"
    for node in ast.walk(ast.parse(open(path, encoding="utf-8").read())):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") \
                and not node.attr.startswith("__") and node.attr not in NAMEDTUPLE_API:
            v = node.value
            own = isinstance(v, ast.Name) and v.id in ("self", "cls") or \
                isinstance(v, ast.Call) and isinstance(v.func, ast.Name) and v.func.id == "super"
            assert own, f"{module}:{node.lineno} reads {ast.unparse(node)}"


def test_compatibility_entry_points_of_v0_still_work():
    """v0's registered entry points and module paths keep working."""
    import gymnasium as gym

    import stepdamp_env
    from stepdamp_env.envs import StepperDampEnv, StepperDampVectorEnv
    from stepdamp_env.leaderboard import full_protocol, run_leaderboard  # noqa: F401

    env = gym.make("StepperDamp-v0")
    assert isinstance(env.unwrapped, StepperDampEnv)
    assert stepdamp_env.StepperDampVectorEnv is StepperDampVectorEnv
    assert full_protocol().version == "v0"


def test_installed_import_names_do_not_clash():
    """baselines/ and agents/ install as stepdamp_baselines and stepdamp_agents."""
    import importlib.util

    import stepdamp_agents
    import stepdamp_baselines

    assert os.path.dirname(stepdamp_baselines.__file__).endswith("baselines")
    assert os.path.dirname(stepdamp_agents.__file__).endswith("agents")
    from stepdamp_env.bench import default_policy_names

    names = default_policy_names()
    assert names[:5] == ("none", "patent-ff-oracle", "patent-ff-identified", "ff-delay-comp",
                         "adaptive-ff") and "ppo-gain-selector" in names
    # The wheel must not ship top-level packages named baselines or agents.
    with open(os.path.join(ROOT, "pyproject.toml"), encoding="utf-8") as fh:
        text = fh.read()
    assert '"baselines*"' not in text and '"agents*"' not in text
    assert importlib.util.find_spec("stepdamp_baselines.harmonic") is not None
