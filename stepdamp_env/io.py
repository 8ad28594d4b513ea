"""Atomic writes: a crash never leaves a half-written result file, nor a result
directory that mixes two runs.

Every file goes to a temporary file in its own directory, is flushed and
fsynced, renamed over its name, and the directory is fsynced
(:func:`atomic_path`). A command's output directory is built as a staging
directory beside it and swapped in whole when the run is complete
(:func:`staged_directory`); a killed run leaves the previous results as they
were, and its leftovers are removed by the next run.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import fnmatch
import hashlib
import json
import os
import shutil
import tempfile
from contextlib import contextmanager
from typing import Any, Iterator, Sequence

import numpy as np

__all__ = ["atomic_path", "write_json", "write_text", "write_npz", "check_writable",
           "check_output_dir", "staged_directory", "cache_dir", "read_json_or_none",
           "file_digest", "tree_digest", "related_files"]


@contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[str]:
    """Yield a temporary path beside ``path``; on success it replaces ``path``.

    The temporary file lives in the same directory so ``os.replace`` is an
    atomic rename; on any exception it is removed and ``path`` is untouched.
    """
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    base, ext = os.path.splitext(os.path.basename(path))
    fd, tmp = tempfile.mkstemp(prefix=f".{base}.", suffix=f".tmp{ext}", dir=directory)
    os.close(fd)
    # mkstemp makes the file private (0600); a result file gets the usual mode.
    os.chmod(tmp, 0o666 & ~_umask())
    try:
        yield tmp
        _fsync_path(tmp)
        os.replace(tmp, path)
        _fsync_path(directory)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _fsync_path(path: str) -> None:
    """fsync a file or a directory by name (the data, or the directory entry)."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) * os.path.isdir(path))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"cannot serialise {type(obj).__name__}")


def write_json(path: str | os.PathLike[str], data: Any) -> None:
    """Write ``data`` as indented JSON, atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=2, default=_default, allow_nan=True)
            fh.write("\n")


def read_json_or_none(path: str | os.PathLike[str]) -> Any:
    """The JSON in ``path``, or None if it is missing or unreadable (a cache entry)."""
    try:
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)
    except (OSError, ValueError):
        return None


def cache_dir(kind: str) -> str | None:
    """A writable directory for cached results of ``kind`` (made if needed):
    ``$STEPDAMP_CACHE_DIR/kind``, else ``$XDG_CACHE_HOME/stepdamp/kind`` or
    ``~/.cache/stepdamp/kind``; None if it cannot be made or written (the
    caller then computes without a cache). ``STEPDAMP_CACHE_DIR=off`` turns it off."""
    root = os.environ.get("STEPDAMP_CACHE_DIR")
    if root == "off":
        return None
    if not root:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"),
                                                                 ".cache")
        root = os.path.join(base, "stepdamp")
    path = os.path.join(root, kind)
    try:
        os.makedirs(path, exist_ok=True)
    except OSError:
        return None
    return path if os.access(path, os.W_OK) else None


def file_digest(path: str | os.PathLike[str]) -> str:
    """sha256 of a file's bytes, read now (never cached: a key must see the file
    as it is when the result it keys is used)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def tree_digest(root: str | os.PathLike[str], suffixes: tuple[str, ...] = (),
                exclude: Sequence[str | os.PathLike[str]] = ()) -> str:
    """sha256 of the files under ``root`` (their paths relative to it and their
    bytes, read now), those ending in ``suffixes`` if given; symbolic links are
    followed (once each). Skipped: hidden names (resume batches, staging
    directories, temporary files of :func:`atomic_path`), ``__pycache__`` and
    the ``exclude`` paths, compared as real paths (a result directory inside
    the tree must not change the key of its own results)."""
    root = os.path.abspath(os.fspath(root))
    skip = {os.path.realpath(os.fspath(e)) for e in exclude}
    seen = {os.path.realpath(root)}
    h = hashlib.sha256()
    for d, dirs, files in os.walk(root, followlinks=True):
        keep = []
        for x in sorted(dirs):
            real = os.path.realpath(os.path.join(d, x))
            if x.startswith(".") or x == "__pycache__" or real in skip or real in seen:
                continue                        # hidden, excluded, or a link cycle
            seen.add(real)
            keep.append(x)
        dirs[:] = keep
        for f in sorted(files):
            path = os.path.join(d, f)
            if f.startswith(".") or os.path.realpath(path) in skip or \
                    (suffixes and not f.endswith(suffixes)):
                continue
            h.update(os.path.relpath(path, root).encode("utf-8", "surrogateescape") + b"\0")
            h.update(file_digest(path).encode())
    return h.hexdigest()


def related_files(path: str | os.PathLike[str]) -> list[str]:
    """A file and its side files: the files beside it whose name starts with its
    name less the extension, and a dot (``model.zip``: ``model.json``,
    ``model.agent.json``), sorted. Only the file's own name is split, never
    the directories above it."""
    path = os.path.abspath(os.fspath(path))
    folder, name = os.path.split(path)
    stem = os.path.splitext(name)[0] + "."
    return sorted(os.path.join(folder, f) for f in os.listdir(folder)
                  if f == name or (f.startswith(stem) and not f.startswith(".")
                                   and os.path.isfile(os.path.join(folder, f))))


def write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8), atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)


def write_npz(path: str | os.PathLike[str], **arrays: np.ndarray) -> None:
    """Write arrays to a compressed .npz, atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)


def check_writable(path: str | os.PathLike[str], option: str, *, directory: bool) -> None:
    """Before any work: make sure ``path`` (a directory, or a file's directory) can
    be written, else a one-line ``ParameterError`` naming ``option``."""
    from .params import ParameterError

    path = os.fspath(path)
    target = path if directory else (os.path.dirname(os.path.abspath(path)) or ".")
    if not directory and os.path.isdir(path):
        raise ParameterError(f"{option} {path!r} is a directory; give a file name")
    try:
        os.makedirs(target, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".write-test.", dir=target)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise ParameterError(f"{option} {path!r} is not writable: {exc.strerror or exc}") \
            from None



_STAGING = ".{name}.staging-{pid}"
_PREVIOUS = ".{name}.previous-{pid}"


def check_output_dir(path: str | os.PathLike[str], option: str,
                     own_dirs: Sequence[str] = ()) -> None:
    """Before any work: ``path`` can be written and holds no sub-directory other
    than the command's own ``own_dirs`` (a run swaps the whole directory in,
    carrying other files over, see :func:`staged_directory`)."""
    from .params import ParameterError

    path = os.fspath(path)
    existed = os.path.isdir(path)
    check_writable(path, option, directory=True)
    if not existed:                 # made by the probe; the run makes it when done
        os.rmdir(path)
        return
    subdirs = sorted(e.name for e in os.scandir(path)
                     if e.is_dir(follow_symlinks=False) and e.name not in own_dirs)
    if subdirs:
        raise ParameterError(
            f"{option} {path!r} holds the directory {subdirs[0]!r}; a run replaces its output "
            "directory whole, so give a directory of files only (a new one, or an earlier "
            "result directory)")


@contextmanager
def staged_directory(path: str | os.PathLike[str], results: Sequence[str]) -> Iterator[str]:
    """Yield a fresh staging directory beside ``path``; on success it becomes ``path``.

    ``results`` are glob patterns of the files the command writes: those of a
    previous run in ``path`` are dropped (never mixed with the new ones); any
    other file there is carried over (hard link, else copy). The swap is one
    atomic exchange where the system has it (Linux renameat2), else two renames.
    On any exception the staging directory is removed and ``path`` is untouched.
    """
    path = os.path.abspath(os.fspath(path))
    parent, name = os.path.split(path)
    os.makedirs(parent, exist_ok=True)
    _clean_leftovers(parent, name)
    staging = os.path.join(parent, _STAGING.format(name=name, pid=os.getpid()))
    shutil.rmtree(staging, ignore_errors=True)
    os.mkdir(staging)
    try:
        yield staging
        if os.path.isdir(path):
            for entry in os.scandir(path):
                if entry.is_file(follow_symlinks=False) and not entry.name.startswith(".") \
                        and not any(fnmatch.fnmatch(entry.name, pat) for pat in results) \
                        and not os.path.exists(os.path.join(staging, entry.name)):
                    _link_or_copy(entry.path, os.path.join(staging, entry.name))
        _fsync_path(staging)
        _swap_in(staging, path)
        _fsync_path(parent)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _link_or_copy(src: str, dst: str) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _swap_in(staging: str, path: str) -> None:
    """Put ``staging`` at ``path``; the previous ``path`` ends at ``staging``."""
    if not os.path.exists(path):
        os.rename(staging, path)
        return
    if _exchange(staging, path):
        return
    parent, name = os.path.split(path)
    previous = os.path.join(parent, _PREVIOUS.format(name=name, pid=os.getpid()))
    os.rename(path, previous)
    os.rename(staging, path)
    os.rename(previous, staging)


def _exchange(a: str, b: str) -> bool:
    """Atomically exchange two paths (Linux renameat2 RENAME_EXCHANGE); False if
    the system cannot."""
    libc_name = ctypes.util.find_library("c")
    if libc_name is None:
        return False
    try:
        fn = ctypes.CDLL(libc_name, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    if ctypes.get_errno() in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EPERM):
        return False
    err = ctypes.get_errno()
    raise OSError(err, os.strerror(err), b)


def _clean_leftovers(parent: str, name: str) -> None:
    """Remove the staging directories of killed runs (their process is gone) and
    put back a previous result directory a killed fallback swap left aside."""
    path = os.path.join(parent, name)
    for entry in os.scandir(parent):
        for pattern, restore in ((_STAGING, False), (_PREVIOUS, True)):
            prefix = pattern.format(name=name, pid="")
            if not entry.name.startswith(prefix):
                continue
            pid = entry.name[len(prefix):]
            if pid.isdigit() and _alive(int(pid)):
                continue
            if restore and not os.path.exists(path):
                os.rename(entry.path, path)
            else:
                shutil.rmtree(entry.path, ignore_errors=True)


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
