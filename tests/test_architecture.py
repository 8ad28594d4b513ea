"""The house rules (docs/architecture.md), read from the source.

* A floor imports only floors below it (or modules of its own floor).
* Only the CLI, the composition root, imports the baselines and the agents.
* No module imports another module's private (``_name``) objects, and no code
  reads another object's private attributes (``x._name`` with x not self/cls).
* No import circles, even through an import inside a function (only
  ``if TYPE_CHECKING:`` imports, which never run, are left out).
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
    "stepdamp_env.limits": 0, "stepdamp_env.errors": 0, "stepdamp_env.interrupts": 0,
    "stepdamp_env.lanes": 0,
    "stepdamp_env.estimators": 0, "stepdamp_env.numba_cache": 0, "stepdamp_env.fixedmath": 0,
    "stepdamp_env.fixednet": 0, "stepdamp_env.stability": 0,
    "stepdamp_env.simulation": 1, "stepdamp_env.response": 1, "stepdamp_env.metrics": 1,
    "stepdamp_env.identify": 2, "stepdamp_env.sweep": 2, "stepdamp_env.plots": 2,
    "stepdamp_env.analysis": 2, "stepdamp_env.drivelog": 2, "stepdamp_env.logfit": 2,
    "stepdamp_env.logstats": 2, "stepdamp_env.logplan": 2,
    "stepdamp_env": 3,                       # the package root exports the env floor
    "stepdamp_env.env": 3, "stepdamp_env.sb3": 3, "stepdamp_env.fields": 0,
    "stepdamp_env.motorfile": 0, "stepdamp_env.motorpool": 0,
    "stepdamp_env.bench": 4,
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
        if not module.startswith("stepdamp_env") or module == "stepdamp_env.cli" \
                or module.startswith("stepdamp_env.cli."):
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


def test_v0_and_v1_still_make_and_step_and_the_shims_are_gone():
    import importlib.util

    import gymnasium as gym
    import numpy as np

    for env_id in ("StepperDamp-v0", "StepperDamp-v1"):
        env = gym.make(env_id)
        env.reset(seed=0)
        env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    for gone in ("stepdamp_env.envs", "stepdamp_env.leaderboard", "stepdamp_env.bench.protocol_v1"):
        assert importlib.util.find_spec(gone) is None, gone
    import stepdamp_env.params as params

    assert not hasattr(params, "__getattr__")


def _module_trees():
    for module, path in sorted(MODULES.items()):
        yield module, path, ast.parse(open(path, encoding="utf-8").read())


def test_no_protocol_unions_and_versions_told_apart_only_by_the_protocols():
    """A protocol is one object: outside bench/protocols/ nothing compares version
    strings or checks a protocol's class (House v2: at most 2 such places)."""
    found = []
    for module, path, tree in _module_trees():
        if module.startswith("stepdamp_env.bench.protocols"):
            continue
        src = open(path, encoding="utf-8").read()
        assert "Protocol |" not in src and "| Protocol" not in src, module
        for node in ast.walk(tree):
            if isinstance(node, ast.Compare) and any(
                    isinstance(c, ast.Constant) and isinstance(c.value, str)
                    and c.value[:1] == "v" and c.value[1:].isdigit()
                    for c in [node.left, *node.comparators]):
                found.append(f"{module}:{node.lineno}")
            if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "isinstance" \
                    and "Protocol" in ast.unparse(node.args[1]) \
                    and "TypingProtocol" not in ast.unparse(node.args[1]):
                found.append(f"{module}:{node.lineno}")
    assert len(found) <= 2, found


#: libm's (and numpy's) transcendental functions differ in the last bit between
#: CPUs (glibc picks FMA variants at run time): the package uses fixedmath's.
_LIBM = {"sin", "cos", "tan", "exp", "log", "log10", "log2", "log1p", "expm1", "atan",
         "atan2", "asin", "acos", "sinh", "cosh", "tanh", "pow", "hypot", "arctan",
         "arctan2", "arcsin", "arccos", "power", "cbrt", "exp2", "sincos"}


def test_no_code_calls_libm_transcendentals():
    """An S-curve move's math.sin/cos in the kernel gave other numbers under the
    emulated x86-64-v2 CPU (38 rows of the v4 quick board's moves suite)."""
    found = []
    for module, path, tree in _module_trees():
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) \
                    and isinstance(node.func.value, ast.Name) \
                    and node.func.value.id in ("math", "np", "numpy", "cmath") \
                    and node.func.attr in _LIBM:
                found.append(f"{module}:{node.lineno} {node.func.value.id}.{node.func.attr}")
    assert found == []


def test_no_version_is_built_on_another_versions_class():
    """What versions share lives in shared modules (protocols/drawn.py,
    decibels.py): editing a frozen version's module cannot change a later one."""
    from stepdamp_env.bench.protocols import protocol_class, protocol_versions

    classes = {v: protocol_class(v) for v in protocol_versions()}
    for version, cls in classes.items():
        borrowed = [c.__name__ for c in cls.__mro__[1:] if c in classes.values()]
        assert not borrowed, (version, borrowed)
        assert cls.__module__.endswith("." + version), (version, cls.__module__)


def test_layouts_are_declared_not_numbered():
    """At most 12 module-level integer constants in the packages: packed vectors
    are declared once as named layouts (stepdamp_env.fields)."""
    import importlib

    found = []
    for module, path, tree in _module_trees():
        names = set()
        for node in tree.body:
            targets = node.targets if isinstance(node, ast.Assign) else \
                [node.target] if isinstance(node, ast.AnnAssign) and node.value else []
            for t in targets:
                names |= {n.id for n in ast.walk(t) if isinstance(n, ast.Name)}
        if not names:
            continue
        values = vars(importlib.import_module(module))
        found += [f"{module}.{n}" for n in sorted(names) if type(values.get(n)) is int]
    assert len(found) <= 12, found


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


def _run_time_imports(module: str, path: str) -> set[str]:
    """The project modules ``module`` imports when it runs (at the top or in a
    function), without those under ``if TYPE_CHECKING:``."""
    tree = ast.parse(open(path, encoding="utf-8").read())
    typing_only = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If)
                   and "TYPE_CHECKING" in ast.unparse(node.test)
                   for stmt in node.body for n in ast.walk(stmt)}
    lines = {n.lineno for n in ast.walk(tree)
             if isinstance(n, (ast.Import, ast.ImportFrom)) and id(n) not in typing_only}
    return {t for t, _, line in _imports(module, path) if line in lines and t in MODULES
            and t != module}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected parts of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            part = []
            while True:
                w = stack.pop()
                part.append(w)
                if w == v:
                    break
            if len(part) > 1:
                found.append(sorted(part))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_cycle_finder_finds_a_circle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_circles():
    graph = {m: _run_time_imports(m, p) for m, p in MODULES.items()}
    assert _cycles(graph) == []


MAX_MODULE_LINES = 600


def test_no_module_is_over_600_lines():
    over = sorted(f"{m} ({n})" for m, p in MODULES.items()
                  if (n := sum(1 for _ in open(p, encoding="utf-8"))) > MAX_MODULE_LINES)
    assert over == [], f"over {MAX_MODULE_LINES} lines: {over}"
