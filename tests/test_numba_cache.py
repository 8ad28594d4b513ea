"""numba's cache: a damaged one is compiled again, an unusable one costs only the
compile, a shared one is not loaded (its pickles are code), and importing
compiles nothing (docs/caches.md). Each case runs in a fresh process with its
own cache root."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import textwrap

import pytest

# fm.dot is the smallest cached function (about 0.5 s to compile).
CALL = """
import numpy as np
from stepdamp_env import fixedmath as fm
print(fm.dot(np.arange(5.0), np.full(5, 0.5)))
"""
# The console script beside this Python (the venv's), else the CLI's module.
_SCRIPT = os.path.join(os.path.dirname(sys.executable), "stepdamp")
STEPDAMP = [_SCRIPT] if os.path.exists(_SCRIPT) else [sys.executable, "-m", "stepdamp_env.cli"]


def _env(xdg) -> dict:
    env = {k: v for k, v in os.environ.items()
           if k != "NUMBA_CACHE_DIR" and not k.startswith("_STEPDAMP_NUMBA_CACHE_")}
    env["XDG_CACHE_HOME"] = str(xdg)
    return env


def _run(code: str | tuple, env: dict, args=None, cwd=None) -> subprocess.CompletedProcess:
    """Runs ``code`` (parts dedented one by one) or ``args``; no failure, no traceback."""
    parts = code if isinstance(code, tuple) else (code,)
    cmd = args or [sys.executable, "-c", "\n".join(textwrap.dedent(p) for p in parts)]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300, cwd=cwd)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "Traceback" not in out.stderr, out.stderr
    return out


def _cache_files(root, ext: str) -> list[str]:
    return [os.path.join(d, f) for d, _, files in os.walk(root) for f in files
            if f.endswith(ext)]


def _note_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("stepdamp:")]


def test_importing_compiles_nothing(tmp_path):
    out = _run("""
        import sys
        import numba
        import stepdamp_env, stepdamp_env.analysis, stepdamp_env.cli
        from numba.core.registry import CPUDispatcher
        compiled = [f"{m}.{k}" for m, mod in list(sys.modules.items())
                    if m.startswith("stepdamp_env") and mod is not None
                    for k, v in vars(mod).items()
                    if isinstance(v, CPUDispatcher) and v.signatures]
        print(compiled)
        """, _env(tmp_path))
    assert out.stdout.strip() == "[]"
    assert _cache_files(tmp_path, ".nbi") == [] and _cache_files(tmp_path, ".nbc") == []
    assert _note_lines(out.stderr) == []


def test_the_cache_folders_are_private(tmp_path):
    out = _run("from stepdamp_env import numba_cache as nc; print(nc.active_cache_dir())",
               _env(tmp_path))
    leaf = out.stdout.strip()
    assert leaf.startswith(str(tmp_path / "stepdamp" / "numba"))
    for folder in (tmp_path / "stepdamp", tmp_path / "stepdamp" / "numba", leaf):
        assert stat.S_IMODE(os.stat(folder).st_mode) == 0o700, folder


def test_a_chosen_numba_cache_dir_keeps_its_mode(tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir(mode=0o755)
    os.chmod(mine, 0o755)
    env = {**_env(tmp_path), "NUMBA_CACHE_DIR": str(mine)}
    leaf = _run("from stepdamp_env import numba_cache as nc; print(nc.active_cache_dir())",
                env).stdout.strip()
    assert os.path.dirname(leaf) == str(mine)
    assert stat.S_IMODE(os.stat(mine).st_mode) == 0o755
    assert stat.S_IMODE(os.stat(leaf).st_mode) == 0o700


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["empty index", "cut index", "garbage data"])
def test_a_damaged_cache_is_compiled_again(tmp_path, damage):
    env = _env(tmp_path)
    first = _run(CALL, env)
    assert _note_lines(first.stderr) == []
    index, data = _cache_files(tmp_path, ".nbi"), _cache_files(tmp_path, ".nbc")
    assert index and data
    for path in (data if damage == "garbage data" else index):
        with open(path, "r+b") as fh:
            whole = fh.read()
            fh.seek(0)
            fh.truncate()
            if damage == "cut index":
                fh.write(whole[:len(whole) // 2])
            elif damage == "garbage data":
                fh.write(b"\x80\x05not a pickle at all" * 7)
    second = _run(CALL, env)
    assert second.stdout == first.stdout
    notes = _note_lines(second.stderr)
    assert len(notes) == 1 and "discarded a damaged numba cache entry" in notes[0], second.stderr
    assert str(tmp_path) in notes[0]
    third = _run(CALL, env)               # compiled again and written back: a clean hit
    assert third.stdout == first.stdout and _note_lines(third.stderr) == []


@pytest.mark.slow
def test_an_unusable_cache_root_costs_only_the_compile(tmp_path):
    root = tmp_path / "a-file"            # makedirs fails under a file, even as root
    root.write_text("")
    env = _env(root)
    version = _run("", env, args=[*STEPDAMP, "--version"])
    assert version.stdout.startswith("stepdamp ")
    out = _run(CALL, env)
    assert out.stdout.strip() == "5.0"
    notes = _note_lines(out.stderr)
    assert len(notes) == 1 and str(root) in notes[0] and "temporary folder" in notes[0]


def test_a_failed_cache_write_costs_only_the_compile(tmp_path):
    """A full disk: numba's write of its index fails after the compile."""
    out = _run(("""
        import errno, os
        import stepdamp_env

        def full(*args, **kwargs):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        os.replace = full
        """, CALL), _env(tmp_path))
    assert out.stdout.strip() == "5.0"
    notes = _note_lines(out.stderr)
    assert len(notes) == 1 and "cannot write numba's cache" in notes[0]
    assert "No space left on device" in notes[0]


def test_without_any_cache_folder_nothing_is_cached_and_it_still_runs(tmp_path):
    root = tmp_path / "a-file"
    root.write_text("")
    out = _run(("""
        import tempfile

        def no_room(*args, **kwargs):
            raise OSError(28, "No space left on device")

        tempfile.mkdtemp = no_room
        import stepdamp_env
        from stepdamp_env import numba_cache
        assert numba_cache.active_cache_dir() == ""
        """, CALL, "print(fm.dot.stats.cache_path)"), _env(root))
    assert out.stdout.splitlines() == ["5.0", "None"]       # numba's NullCache
    notes = _note_lines(out.stderr)
    assert len(notes) == 1 and "compiling without a cache" in notes[0]
    import stepdamp_env

    package = os.path.dirname(stepdamp_env.__file__)
    pycache = os.path.join(package, "__pycache__")
    assert not os.path.isdir(pycache) or not any(
        f.startswith("fixedmath.dot-") for f in os.listdir(pycache)), "cached into the package"


@pytest.mark.parametrize("why", ["world-writable", "group-writable", "another user's"])
def test_a_shared_cache_folder_is_not_loaded(tmp_path, why):
    env = _env(tmp_path)
    leaf = _run("from stepdamp_env import numba_cache as nc; print(nc.active_cache_dir())",
                env).stdout.strip()
    if why == "another user's":
        if os.getuid() != 0:
            pytest.skip("needs root to give the folder away")
        os.chown(leaf, 65534, -1)
    else:
        os.chmod(leaf, 0o777 if why == "world-writable" else 0o770)
    out = _run((CALL, """
        import os
        from stepdamp_env import numba_cache as nc
        print(nc.active_cache_dir(), oct(os.stat(nc.active_cache_dir()).st_mode & 0o777))
        """), env)
    value, used_mode = out.stdout.splitlines()
    used, mode = used_mode.rsplit(" ", 1)
    assert value == "5.0" and mode == "0o700" and not used.startswith(str(tmp_path))
    notes = _note_lines(out.stderr)
    assert len(notes) == 1 and leaf in notes[0] and "not using numba's cache folder" in notes[0]
    assert _cache_files(leaf, ".nbi") == []          # nothing written into the shared folder
    assert not os.path.exists(used)                  # the temporary folder is removed at exit


def test_a_child_reuses_its_parents_temporary_folder_quietly(tmp_path):
    root = tmp_path / "a-file"
    root.write_text("")
    out = _run("""
        import subprocess, sys
        from stepdamp_env import numba_cache as nc
        print(nc.active_cache_dir(), flush=True)
        subprocess.run([sys.executable, "-c", "from stepdamp_env import numba_cache as nc; "
                        "print(nc.active_cache_dir())"], check=True)
        """, _env(root))
    parent, child = out.stdout.splitlines()
    assert parent == child
    assert len(_note_lines(out.stderr)) == 1


def test_two_installs_of_the_same_code_share_one_compile(tmp_path):
    """``pip install .`` and ``pip install -e .`` put the same code at two paths;
    numba's own locator keys its cache on the path, so each compiled anew. Here
    two copies of the package: the second loads what the first compiled."""
    import shutil

    import stepdamp_env

    source = os.path.dirname(os.path.abspath(stepdamp_env.__file__))
    stats = """
        s = fm.dot.stats
        print(fm.__file__, sum(s.cache_hits.values()), sum(s.cache_misses.values()),
              s.cache_path, sep="\\n")
        """
    seen = []
    for name in ("site-packages", "checkout"):
        shutil.copytree(source, tmp_path / name / "stepdamp_env",
                        ignore=shutil.ignore_patterns("__pycache__"))
        for d, _, files in os.walk(tmp_path / name):      # installed at another time
            for f in files:
                os.utime(os.path.join(d, f), (1e9 + len(seen), 1e9 + len(seen)))
        env = {**_env(tmp_path / "cache"), "PYTHONPATH": str(tmp_path / name)}
        # Not from the working directory (python -c puts it first on the path).
        out = _run((CALL, stats), env, cwd=tmp_path)
        where, hits, misses, path = out.stdout.splitlines()[-4:]     # paths with spaces
        assert where == str(tmp_path / name / "stepdamp_env" / "fixedmath.py")
        seen.append((int(hits), int(misses), path))
        assert _note_lines(out.stderr) == []
    assert seen[0][:2] == (0, 1) and seen[1][:2] == (1, 0), seen     # compiled, then loaded
    assert seen[0][2] == seen[1][2] and seen[0][2].endswith(os.sep + "stepdamp_env")
