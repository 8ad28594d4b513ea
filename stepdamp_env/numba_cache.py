"""Where numba keeps its compiled cache: a per-user directory, never the package."""

from __future__ import annotations

import os
import sys

__all__ = ["use_user_cache_dir", "user_cache_dir"]


def user_cache_dir() -> str:
    """``$NUMBA_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/stepdamp/numba``
    (``~/.cache/stepdamp/numba``; ``%LOCALAPPDATA%`` on Windows)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return os.environ["NUMBA_CACHE_DIR"]
    if sys.platform == "win32":
        base = os.environ.get("LOCALAPPDATA") or os.path.expanduser("~")
    else:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"),
                                                                 ".cache")
    return os.path.join(base, "stepdamp", "numba")


def use_user_cache_dir() -> str:
    """Point numba's cache at :func:`user_cache_dir` (a no-op if the user chose one)."""
    path = user_cache_dir()
    if os.environ.get("NUMBA_CACHE_DIR") != path:
        os.environ["NUMBA_CACHE_DIR"] = path
        config = sys.modules.get("numba.core.config")
        if config is not None:           # numba was imported first: re-read its settings
            config.reload_config()
    return path
