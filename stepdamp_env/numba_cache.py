"""Where numba keeps its compiled cache: a per-user directory, never the package,
one sub-directory per version of this package's code.

numba re-checks a cached function against its own source file only (modified
time and size), not against the files it calls into: ``env/compiled.py``
inlines the kernel (``kernel/``), so a changed kernel would leave its compiled steps
stale. The sub-directory is named by a hash of every Python source of the
package and the numba and llvmlite versions (:func:`code_key`), so changed
code never meets an old cache.

The cache is code: numba's index and data files are pickles, and loading one
runs whatever it says. So the folders this module creates are private (mode
0700), and an existing folder that another user owns or others may write is
not used (a private temporary folder is, for this run). A cache file that
fails to load is deleted and its function compiled again; a cache that cannot
be written costs only the compile (docs/caches.md).
"""

from __future__ import annotations

import atexit
import hashlib
import importlib.metadata
import os
import re
import shutil
import stat
import sys
import tempfile

__all__ = ["use_user_cache_dir", "user_cache_dir", "active_cache_dir", "code_key",
           "package_subpath", "call_with_frame_room", "remove_private_folders"]

_active = ""            # the folder numba caches this package's code in ("" none)
_told: set[str] = set()  # notes printed, one line each per process
_private: list[str] = []  # temporary cache folders this process made (removed at exit)


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
    return os.path.join(_cache_root(), *_own_parts())


def active_cache_dir() -> str:
    """The folder numba caches this package's code in, as :func:`use_user_cache_dir`
    chose it (:func:`user_cache_dir`, or a private temporary folder when that one
    may not be used); "" when nothing is cached or before the choice."""
    return _active


def _cache_root() -> str:
    """The user's folder the cache goes under (never created private nor changed here)."""
    base = _user_base()
    if base:
        return base
    if sys.platform == "win32":
        return os.environ.get("LOCALAPPDATA") or os.path.expanduser("~")
    return os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")


def _own_parts() -> list[str]:
    """The folders below :func:`_cache_root` that this package creates."""
    if _user_base():
        return [f"stepdamp-{code_key()}"]
    return ["stepdamp", "numba", code_key()]


def _user_base() -> str:
    """The user's own ``$NUMBA_CACHE_DIR``, or "" (one this package set, passed on
    to a child process, is not the user's: the user's is kept beside it)."""
    chosen = os.environ.get("NUMBA_CACHE_DIR", "")
    if chosen and chosen != os.environ.get("_STEPDAMP_NUMBA_CACHE_DIR"):
        return chosen
    return os.environ.get("_STEPDAMP_NUMBA_CACHE_BASE", "") if chosen else ""


def _note(kind: str, line: str) -> None:
    if kind not in _told:
        _told.add(kind)
        print(f"stepdamp: {line}", file=sys.stderr, flush=True)


def _unsafe(path: str, leaf: bool) -> str:
    """Why the existing folder ``path`` may not hold code this process loads, or "".
    Another user's folder, or one others may write, could hold their pickles; a
    folder above the leaf may be group-writable (a umask of 002 gives that)."""
    try:
        st = os.stat(path)
    except OSError as e:
        return e.strerror or type(e).__name__
    if not stat.S_ISDIR(st.st_mode):
        return "not a folder"
    if not hasattr(os, "getuid"):       # Windows: a folder in the user's own profile
        return ""
    if st.st_uid != os.getuid():
        return f"owned by uid {st.st_uid}, not {os.getuid()}"
    if st.st_mode & (0o022 if leaf else 0o002):
        return f"writable by others, mode {stat.S_IMODE(st.st_mode):04o}"
    return ""


def _make_private(root: str, parts: list[str]) -> tuple[str, str]:
    """Create ``root/parts...`` with each folder of ``parts`` private (0700) and
    check the ones that exist; ``root`` (the user's) only created if missing.
    Returns ("", "") or (the folder that fails, why)."""
    try:
        os.makedirs(root, mode=0o700, exist_ok=True)
    except FileExistsError:
        return root, "not a folder"
    except OSError as e:
        return root, e.strerror or type(e).__name__
    here = root
    for k, part in enumerate(parts):
        here = os.path.join(here, part)
        try:
            os.mkdir(here, 0o700)
            os.chmod(here, 0o700)          # mkdir's mode passes through the umask
        except FileExistsError:
            why = _unsafe(here, leaf=k == len(parts) - 1)
            if why:
                return here, why
        except OSError as e:
            return here, e.strerror or type(e).__name__
    try:                                   # numba checks this too, then falls back silently
        tempfile.TemporaryFile(dir=here).close()
    except OSError as e:
        return here, e.strerror or type(e).__name__
    return "", ""


def _fallback(refused: str) -> tuple[str, bool]:
    """A private temporary folder for this run, removed at exit ("" if none can be
    made), and whether it is the parent process's (which refused the same folder
    and said so)."""
    inherited = os.environ.get("NUMBA_CACHE_DIR", "")
    if os.environ.get("_STEPDAMP_NUMBA_CACHE_REFUSED") == refused and inherited \
            and inherited == os.environ.get("_STEPDAMP_NUMBA_CACHE_DIR") \
            and not _unsafe(inherited, leaf=True):
        return inherited, True
    try:
        path = tempfile.mkdtemp(prefix="stepdamp-numba-")      # mode 0700
    except OSError:
        return "", False
    _private.append(path)
    atexit.register(shutil.rmtree, path, ignore_errors=True)
    os.environ["_STEPDAMP_NUMBA_CACHE_REFUSED"] = refused
    return path, False


def use_user_cache_dir() -> str:
    """Point numba's cache at :func:`user_cache_dir`, made private (0700); if that
    folder may not be used, at a private temporary one, with a line on stderr.
    Installs the guard that turns a cache file failing to load into a compile.
    Returns the folder used ("" when nothing is cached)."""
    global _active
    base = _user_base()
    root, parts = _cache_root(), _own_parts()
    path = os.path.join(root, *parts)
    bad, why = _make_private(root, parts)
    if bad:
        path, inherited = _fallback(path)
        if path and not inherited:
            _note("refused", f"not using numba's cache folder {bad} ({why}); compiling into "
                             f"a temporary folder this run (remove or fix it, or set "
                             f"NUMBA_CACHE_DIR)")
        elif not path:
            _note("off", f"not using numba's cache folder {bad} ({why}); compiling without "
                         f"a cache")
    _active = path
    if path and os.environ.get("NUMBA_CACHE_DIR") != path:
        os.environ["NUMBA_CACHE_DIR"] = path
        # Ours, not the user's: a child process computes its own (its code may differ).
        os.environ["_STEPDAMP_NUMBA_CACHE_DIR"] = path
        os.environ["_STEPDAMP_NUMBA_CACHE_BASE"] = base
        config = sys.modules.get("numba.core.config")
        if config is not None:           # numba was imported first: re-read its settings
            config.reload_config()
    _install_guard()
    return path


def _inside(path: str) -> bool:
    """Whether numba's cache folder ``path`` is in the folder this package chose."""
    if not _active:
        return False
    top = os.path.abspath(_active)
    try:
        return os.path.commonpath([os.path.abspath(path), top]) == top
    except ValueError:                  # another drive
        return False


def _why(error: BaseException) -> str:
    return getattr(error, "strerror", None) or type(error).__name__


def _install_guard() -> None:
    """Make numba's dispatchers build their caches through :func:`_guarded_caches`'
    classes: in this package's folder, a cache file that fails to load (an empty
    index: EOFError; garbage: UnpicklingError; anything else) is deleted and counts
    as a miss, and a failed write costs only the compile; this package's functions
    are cached nowhere else (numba would fall back to the package's folder)."""
    try:
        from numba.core import caching, dispatcher
        plain = dispatcher.FunctionCache
    except (ImportError, AttributeError):   # another numba layout: numba's own behaviour
        return
    if getattr(plain, "stepdamp_guard", False):
        return
    guarded, package = _guarded_caches(caching)

    def function_cache(py_func):
        ours = (getattr(py_func, "__module__", "") or "").split(".")[0] == __package__
        if ours and not _active:        # no folder of ours (said at import)
            return caching.NullCache()
        try:
            cache = (package if ours else guarded)(py_func)
        except Exception as e:          # noqa: BLE001 - numba found no folder it can write
            _note("off", f"numba cannot cache in {_active or 'any folder'} ({_why(e)}); "
                         f"compiling without a cache")
            return caching.NullCache()
        if ours and not _inside(cache.cache_path):
            if _active:
                _note("off", f"numba cannot cache in {_active}; compiling without a cache")
            return caching.NullCache()
        return cache

    function_cache.stepdamp_guard = True
    dispatcher.FunctionCache = function_cache


def _guarded_caches(caching):
    """numba's ``FunctionCache`` and its index/data file, guarded (see
    :func:`_install_guard`; outside this package's folder they behave as numba's),
    and the same cache located by the code's place in this package, for its own
    functions (``PackageLocator``)."""

    class GuardedFile(caching.IndexDataCacheFile):
        def __init__(self, cache_path, filename_base, source_stamp):
            super().__init__(cache_path, filename_base, source_stamp)
            self._stepdamp_data = re.compile(re.escape(filename_base) + r"\.\d+\.nbc")
            self._stepdamp_name = filename_base

        def discard_damaged(self, error: BaseException) -> None:
            """Delete this function's index and data files (all of its signatures)."""
            try:
                names = [n for n in os.listdir(self._cache_path)
                         if self._stepdamp_data.fullmatch(n)]
            except OSError:
                names = []
            for path in [self._index_path] + [os.path.join(self._cache_path, n) for n in names]:
                try:
                    os.remove(path)
                except OSError:
                    pass
            _note("damaged", f"discarded a damaged numba cache entry ({self._stepdamp_name}: "
                             f"{_why(error)}) in {_active}; recompiling")

        def _load_index(self):
            try:
                return super()._load_index()
            except Exception as e:      # noqa: BLE001 - any failure to read is a miss
                if not _inside(self._cache_path):
                    raise
                self.discard_damaged(e)
                return {}

        def load(self, key):
            try:
                return super().load(key)
            except Exception as e:      # noqa: BLE001
                if not _inside(self._cache_path):
                    raise
                self.discard_damaged(e)
                return None

    class PackageLocator(caching.UserProvidedCacheLocator):
        """This package's functions: cached under their folder's path inside the
        package, not under the install path (numba's own locator hashes the absolute
        folder), so ``pip install .`` and ``pip install -e .`` of the same code, or
        two checkouts of it, share one compile. The folder is already this code's
        (:func:`code_key`) and each file is stamped by its content."""

        def __init__(self, py_func, py_file):
            super().__init__(py_func, py_file)
            # numba's path is CACHE_DIR/<folder>_<sha1 of the absolute folder>.
            self._cache_path = os.path.join(os.path.dirname(self._cache_path),
                                            package_subpath(py_file))

        @classmethod
        def from_function(cls, py_func, py_file):
            if not package_subpath(py_file):
                return None
            return super().from_function(py_func, py_file)

        def get_source_stamp(self):
            # The file's content, as numba 0.68 stamps it; older numba stamps its
            # modified time and size, which differ between two installs.
            with open(self._py_file, "rb") as fh:
                return hashlib.sha256(fh.read()).digest()

    class PackageImpl(caching.CompileResultCacheImpl):
        _locator_classes = [PackageLocator]

    class GuardedCache(caching.FunctionCache):
        def __init__(self, py_func):
            super().__init__(py_func)
            self._cache_file = GuardedFile(self._cache_path, self._impl.filename_base,
                                           self._impl.locator.get_source_stamp())

        def load_overload(self, sig, target_context):
            try:
                return super().load_overload(sig, target_context)
            except Exception as e:      # noqa: BLE001 - e.g. rebuilding what was read
                if not _inside(self._cache_path):
                    raise
                self._cache_file.discard_damaged(e)
                return None

        def save_overload(self, sig, data):
            try:
                super().save_overload(sig, data)
            except Exception as e:      # noqa: BLE001 - a full disk: the compiled code still runs
                if not _inside(self._cache_path):
                    raise
                _note("unwritten", f"cannot write numba's cache in {_active} ({_why(e)}); "
                                   f"compiled code is not kept")

    class PackageCache(GuardedCache):
        _impl_class = PackageImpl

    return GuardedCache, PackageCache


def package_subpath(py_file: str) -> str:
    """The folder of ``py_file`` inside this package as numba's cache names it
    (``stepdamp_env.kernel``), or "" for a file outside the package."""
    here = os.path.dirname(os.path.abspath(__file__))
    folder = os.path.dirname(os.path.abspath(py_file))
    try:
        if os.path.commonpath([folder, here]) != here:
            return ""
    except ValueError:                  # another drive
        return ""
    rel = os.path.relpath(folder, os.path.dirname(here))
    return rel.replace(os.sep, ".")


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


def remove_private_folders() -> None:
    """Remove the temporary cache folders this process made (as at exit), for a
    process that leaves without the interpreter's shutdown."""
    for path in _private:
        shutil.rmtree(path, ignore_errors=True)
