"""Where numba keeps its compiled cache: a per-user directory, never the package,
one sub-directory per version of this package's code.

numba re-checks a cached function against its own source file only (modified
time and size), not against the files it calls into: ``env/compiled.py``
inlines ``kernel.py``, so a changed kernel would leave its compiled steps
stale. The sub-directory is named by a hash of every Python source of the
package and the numba and llvmlite versions (:func:`code_key`), so changed
code never meets an old cache.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import os
import sys

__all__ = ["use_user_cache_dir", "user_cache_dir", "code_key", "call_with_frame_room"]


def code_key(root: str | None = None) -> str:
    """16 hex digits of sha256 over the ``.py`` files under ``root`` (default:
    this package; names and bytes, read now) and the numba and llvmlite versions."""
    here = root or os.path.dirname(os.path.abspath(__file__))
    h = hashlib.sha256()
    for d, dirs, files in os.walk(here):
        dirs[:] = sorted(x for x in dirs if not x.startswith(".") and x != "__pycache__")
        for f in sorted(x for x in files if x.endswith(".py")):
            h.update(os.path.relpath(os.path.join(d, f), here).encode() + b"\0")
            with open(os.path.join(d, f), "rb") as fh:
                h.update(hashlib.sha256(fh.read()).digest())
    for dist in ("numba", "llvmlite"):
        try:
            h.update(importlib.metadata.version(dist).encode() + b"\0")
        except importlib.metadata.PackageNotFoundError:
            h.update(b"-\0")
    return h.hexdigest()[:16]


def user_cache_dir() -> str:
    """``$XDG_CACHE_HOME/stepdamp/numba/<code_key>`` (``~/.cache/...``;
    ``%LOCALAPPDATA%`` on Windows); under a ``$NUMBA_CACHE_DIR`` the user chose,
    ``$NUMBA_CACHE_DIR/stepdamp-<code_key>`` (the process's other numba code
    caches there too: numba has one cache directory per process)."""
    base = _user_base()
    if base:
        return os.path.join(base, f"stepdamp-{code_key()}")
    if sys.platform == "win32":
        root = os.environ.get("LOCALAPPDATA") or os.path.expanduser("~")
    else:
        root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"),
                                                                 ".cache")
    return os.path.join(root, "stepdamp", "numba", code_key())


def _user_base() -> str:
    """The user's own ``$NUMBA_CACHE_DIR``, or "" (one this package set, passed on
    to a child process, is not the user's: the user's is kept beside it)."""
    chosen = os.environ.get("NUMBA_CACHE_DIR", "")
    if chosen and chosen != os.environ.get("_STEPDAMP_NUMBA_CACHE_DIR"):
        return chosen
    return os.environ.get("_STEPDAMP_NUMBA_CACHE_BASE", "") if chosen else ""


def use_user_cache_dir() -> str:
    """Point numba's cache at :func:`user_cache_dir`."""
    base = _user_base()
    path = user_cache_dir()
    if os.environ.get("NUMBA_CACHE_DIR") != path:
        os.environ["NUMBA_CACHE_DIR"] = path
        # Ours, not the user's: a child process computes its own (its code may differ).
        os.environ["_STEPDAMP_NUMBA_CACHE_DIR"] = path
        os.environ["_STEPDAMP_NUMBA_CACHE_BASE"] = base
        config = sys.modules.get("numba.core.config")
        if config is not None:           # numba was imported first: re-read its settings
            config.reload_config()
    return path


def _call(fn, args):
    return fn(*args)


# CPython (3.11+) keeps Python frames on a stack of 16 KiB chunks and frees a
# chunk as soon as the frame at its base returns: a hot call that straddles a
# chunk boundary maps and unmaps memory on every call. numba's compiler, started
# at an unlucky depth, did that 3.3 million times while compiling the kernel (33 s
# instead of 15 s, half of it system time). A frame with a large value stack makes
# CPython allocate one chunk of twice its size; the calls below it run in the rest.
_ROOMY = type(_call)(_call.__code__.replace(co_stacksize=1 << 17), {})


def call_with_frame_room(fn, *args):
    """``fn(*args)`` with about 1 MiB of room on CPython's frame stack below it, so
    that no compile inside it straddles a frame-stack chunk boundary (see above).
    Before 3.11 (no frame stack) it only allocates one large frame."""
    return _ROOMY(fn, args)
