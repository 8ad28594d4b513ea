"""Install hygiene: numba's compiled cache lives in a per-user directory, never in the package."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from stepdamp_env.numba_cache import code_key


def _run(code: str, env: dict) -> str:
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, check=True,
                         capture_output=True, text=True)
    return out.stdout.strip()


def test_numba_cache_goes_to_the_user_cache_dir(tmp_path):
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "xdg")}
    env.pop("NUMBA_CACHE_DIR", None)
    module = tmp_path / "cached_mod.py"
    module.write_text("from numba import njit\n\n@njit(cache=True)\ndef f(x):\n    return x + 1\n")
    printed = _run(f"""
        import sys
        sys.path.insert(0, {str(tmp_path)!r})
        import stepdamp_env, numba
        import cached_mod
        assert cached_mod.f(1) == 2
        print(numba.config.CACHE_DIR)
        """, env)
    cache = tmp_path / "xdg" / "stepdamp" / "numba" / code_key()
    assert printed == str(cache)
    written = [f for _, _, files in os.walk(cache) for f in files]
    assert any(f.endswith(".nbi") for f in written)
    assert not (tmp_path / "__pycache__").exists() or \
        not any(f.endswith(".nbi") for f in os.listdir(tmp_path / "__pycache__"))


def test_numba_cache_dir_can_be_chosen(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "mine")}
    for k in ("_STEPDAMP_NUMBA_CACHE_DIR", "_STEPDAMP_NUMBA_CACHE_BASE"):
        env.pop(k, None)
    code = ("import os, subprocess, sys, stepdamp_env, numba; print(numba.config.CACHE_DIR); "
            "sys.stdout.flush(); subprocess.run([sys.executable, '-c', 'import stepdamp_env, "
            "numba; print(numba.config.CACHE_DIR)'])")
    mine = str(tmp_path / "mine" / f"stepdamp-{code_key()}")
    assert _run(code, env).splitlines() == [mine, mine]     # a child keeps the user's choice


def test_numba_imported_first_still_uses_the_user_cache_dir(tmp_path):
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "xdg")}
    env.pop("NUMBA_CACHE_DIR", None)
    assert _run("import numba, stepdamp_env; print(numba.config.CACHE_DIR)", env) == \
        str(tmp_path / "xdg" / "stepdamp" / "numba" / code_key())


def test_numba_cache_is_keyed_on_every_source_of_the_package(tmp_path):
    """numba re-checks a cached function against its own file only; env/compiled.py
    inlines the kernel, so the cache directory must change with any source file."""
    import shutil

    import stepdamp_env

    copy = tmp_path / "pkg"
    shutil.copytree(os.path.dirname(stepdamp_env.__file__), copy,
                    ignore=shutil.ignore_patterns("__pycache__"))
    assert code_key(str(copy)) == code_key()
    kernel = copy / "kernel" / "plant.py"
    data = bytearray(kernel.read_bytes())
    data[len(data) // 2] ^= 1
    kernel.write_bytes(bytes(data))
    assert code_key(str(copy)) != code_key()


def test_a_child_process_computes_its_own_cache_dir(tmp_path):
    """The directory this process chose is passed on in the environment; a child
    (perhaps of another checkout) still keys its own, unlike a user's choice."""
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "xdg"),
           "NUMBA_CACHE_DIR": str(tmp_path / "old"), "_STEPDAMP_NUMBA_CACHE_DIR": str(tmp_path / "old")}
    assert _run("import stepdamp_env, numba; print(numba.config.CACHE_DIR)", env) == \
        str(tmp_path / "xdg" / "stepdamp" / "numba" / code_key())


@pytest.mark.slow
def test_pytest_runs_from_any_directory(tmp_path):
    """The leaderboard tests once failed when pytest ran from outside the checkout."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          os.path.join(root, "tests", "test_leaderboard.py"),
                          "-k", "cli_writes or may_not_set"],
                         cwd=tmp_path, capture_output=True, text=True,
                         # CI's basetemp holds tmp_path: the inner run gets its own below it
                         env={**os.environ, "PYTEST_ADDOPTS": f"--basetemp='{tmp_path / 'inner'}'"})
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]


def test_version_is_defined_once_and_cited_alike():
    import re

    import stepdamp_env
    from stepdamp_env.version import __version__

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with open(os.path.join(root, "CITATION.cff"), encoding="utf-8") as fh:
        cited = re.search(r"^version: (\S+)$", fh.read(), re.M).group(1)
    assert stepdamp_env.__version__ == __version__ == cited


def test_every_package_folder_is_installed():
    """A regular (not editable) install ships only the packages pyproject.toml
    lists: every folder with an ``__init__.py`` must be among them."""
    import tomllib

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with open(os.path.join(root, "pyproject.toml"), "rb") as fh:
        tool = tomllib.load(fh)["tool"]["setuptools"]
    dirs = {name: path for name, path in tool["package-dir"].items()}
    found = set()
    for top in ("stepdamp_env", "stepdamp_baselines", "stepdamp_agents"):
        base = os.path.join(root, dirs.get(top, top))
        for here, _, files in os.walk(base):
            if "__init__.py" in files and "__pycache__" not in here:
                rel = os.path.relpath(here, base)
                found.add(top if rel == "." else top + "." + rel.replace(os.sep, "."))
    assert found == set(tool["packages"])


def test_call_with_frame_room_calls_through_and_reserves_a_large_frame():
    from stepdamp_env import numba_cache

    def deep(n, acc):
        return acc if n == 0 else deep(n - 1, acc + n)

    assert numba_cache.call_with_frame_room(deep, 500, 0) == sum(range(501))
    assert numba_cache.call_with_frame_room(dict) == {}
    # The frame's value stack is what makes CPython give it a chunk of its own.
    assert numba_cache._ROOMY.__code__.co_stacksize >= 1 << 17
