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
import fcntl
import fnmatch
import hashlib
import json
import os
import re
import shutil
import stat
import sys
import tempfile
from contextlib import contextmanager
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np

from .errors import ParameterError
from .limits import LIMITS

__all__ = ["atomic_path", "write_json", "write_text", "write_npz", "check_writable",
           "check_output_dir", "staged_directory", "cache_dir", "read_json_or_none",
           "read_json", "parse_json",
           "write_checked_json", "read_checked_json", "output_lock", "refuse_link",
           "check_regular_file",
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
    except BaseException as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        # A write or fsync error (a full disk: ENOSPC) names no file, a failed
        # rename the temporary one: name the file being written.
        if isinstance(exc, OSError) and exc.filename is None:
            exc.filename = path
        elif isinstance(exc, OSError) and exc.filename == tmp and exc.errno is not None:
            raise OSError(exc.errno, exc.strerror, path).with_traceback(exc.__traceback__) \
                from None
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


def _json_depth(text: str) -> int:
    """Deepest nesting of ``[`` and ``{`` in JSON ``text``, brackets inside strings
    left out, in linear time without recursion: a bracket is inside a string when
    an odd number of unescaped quotes stands before it (a quote is escaped by an
    odd run of backslashes)."""
    codes = np.frombuffer(text.encode("utf-8", "surrogatepass"), dtype=np.uint8)
    brackets = np.flatnonzero((codes == 91) | (codes == 93) | (codes == 123) | (codes == 125))
    if brackets.size == 0:
        return 0
    quotes = np.flatnonzero(codes == 34)
    slashes = np.flatnonzero(codes == 92)
    if quotes.size and slashes.size:
        # Length of the run of backslashes ending just before each quote.
        new_run = np.ones(slashes.size, dtype=bool)
        new_run[1:] = np.diff(slashes) != 1
        run_start = np.maximum.accumulate(np.where(new_run, np.arange(slashes.size), 0))
        j = np.searchsorted(slashes, quotes) - 1
        touching = (j >= 0) & (slashes[np.maximum(j, 0)] == quotes - 1)
        run = np.where(touching, j - run_start[np.maximum(j, 0)] + 1, 0)
        quotes = quotes[run % 2 == 0]
    outside = brackets[np.searchsorted(quotes, brackets) % 2 == 0]
    kind = codes[outside]
    steps = np.where((kind == 91) | (kind == 123), 1, -1)
    return max(0, int(np.cumsum(steps).max())) if steps.size else 0


def parse_json(text: str, label: str) -> Any:
    """``json.loads(text)``; invalid JSON, nesting deeper than ``LIMITS.json_depth``
    or a non-finite number is a one-line ``ParameterError`` naming ``label``."""
    depth = _json_depth(text)
    if depth > LIMITS.json_depth:
        raise ParameterError(f"{label} nests {depth} levels deep; allowed at most "
                             f"{LIMITS.json_depth}")
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as exc:     # a decode error, an int of 4300+ digits
        raise ParameterError(f"{label} is not valid JSON: {' '.join(str(exc).split())}") \
            from None


def read_json(path: str | os.PathLike[str], label: str, *, opener: Any = None) -> Any:
    """The JSON in the file ``path`` (through ``opener(path, "rt", encoding=...)`` if
    given, e.g. ``lzma.open``); an unreadable, truncated, oversized, too deeply
    nested or invalid file is a one-line ``ParameterError`` naming ``label`` and
    the file. Every JSON file the tool reads goes through here."""
    where = f"{label} {os.fspath(path)!r}"
    check_regular_file(path, where)
    try:
        with (opener or open)(path, "rt", encoding="utf-8") as fh:
            text = fh.read(LIMITS.json_bytes + 1)
    except UnicodeDecodeError as exc:
        raise ParameterError(f"{where} is not UTF-8 text: {exc.reason}") from None
    except IsADirectoryError:
        raise ParameterError(f"{where} is a directory, not a file") from None
    except FileNotFoundError:
        raise ParameterError(f"{where} does not exist") from None
    except OSError as exc:
        raise ParameterError(f"{where} cannot be read: {exc.strerror or exc}") from None
    except (EOFError, ValueError) as exc:       # a truncated or damaged xz / gzip stream
        raise ParameterError(f"{where} is truncated or damaged ({exc})") from None
    except Exception as exc:  # noqa: BLE001 - lzma/gzip raise their own error types
        raise ParameterError(f"{where} cannot be read ({type(exc).__name__}: {exc})") \
            from None
    if len(text) > LIMITS.json_bytes:
        raise ParameterError(f"{where} is over {LIMITS.json_bytes} bytes; allowed at most that")
    return parse_json(text, where)


def check_regular_file(path: str | os.PathLike[str], where: str) -> None:
    """A one-line ``ParameterError`` unless ``path`` is a regular file (after
    links): a FIFO would block a read for ever, a device never end it."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise ParameterError(f"{where} does not exist") from None
    except OSError as exc:
        raise ParameterError(f"{where} cannot be read: {exc.strerror or exc}") from None
    if stat.S_ISDIR(mode):
        raise ParameterError(f"{where} is a directory, not a file")
    if not stat.S_ISREG(mode):
        raise ParameterError(f"{where} is not a regular file (a pipe or a device)")


def read_json_or_none(path: str | os.PathLike[str]) -> Any:
    """The JSON in ``path``, or None if it is missing, unreadable or refused by
    :func:`read_json` (a cache entry: computed again)."""
    try:
        return read_json(path, "cache entry")
    except ParameterError:
        return None


def _checked_parts(key: str, content: Any) -> tuple[str, str]:
    """A kept entry's key and content as compact JSON, dicts' keys in their own
    order (as a kept file holds them, so that its reader encodes the same text)."""
    return json.dumps(key), json.dumps(content, default=_default, allow_nan=True)


def _checksum(key_text: str, content_text: str) -> str:
    """sha256 of a kept entry's key and content, ``[key, content]`` as JSON."""
    return hashlib.sha256(f"[{key_text}, {content_text}]".encode("utf-8")).hexdigest()


def write_checked_json(path: str | os.PathLike[str], key: str, content: Any) -> None:
    """Keep ``content`` at ``path`` (atomically) with its key and a checksum of
    both, for :func:`read_checked_json`: ``{"key": ..., "sha256": ..., "content":
    ...}`` in compact JSON, one encoding for the file and the checksum (json's C
    encoder; a board's parent writes a batch while its workers run)."""
    key_text, content_text = _checked_parts(key, content)
    write_text(path, f'{{"key": {key_text}, "sha256": "{_checksum(key_text, content_text)}", '
                     f'"content": {content_text}}}\n')


def read_checked_json(path: str | os.PathLike[str], key: str, what: str) -> Any:
    """The content kept at ``path`` by :func:`write_checked_json` under ``key``;
    None if there is none, or (with a one-line note on stderr naming the file)
    if it is unreadable, of another key or does not match its checksum: the
    caller computes it again. A checksum finds damage and edits by hand, not
    a forger, who can recompute it (docs/caches.md)."""
    if not os.path.lexists(path):
        return None
    kept = read_json_or_none(path)
    if isinstance(kept, dict) and kept.get("key") == key and "content" in kept and \
            kept.get("sha256") == _checksum(*_checked_parts(key, kept["content"])):
        return kept["content"]
    print(f"stepdamp: note: {what} {os.fspath(path)!r} is damaged or edited (its checksum "
          "does not match); computing it again", file=sys.stderr)
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
                     own_dirs: Sequence[str] = ()) -> str:
    """Before any work: ``path`` can be written and holds no sub-directory other
    than the command's own ``own_dirs`` (a run swaps the whole directory in,
    carrying other files over, see :func:`staged_directory`). Returns the
    directory as the system resolves it (``a/link/..`` is where ``link``
    points, not ``a``), which every later step must use; a previous result
    directory a killed run left aside is put back first."""
    refuse_link(path, option)
    path = os.path.realpath(os.fspath(path))
    parent, name = os.path.split(path)
    if os.path.isdir(parent):
        _clean_leftovers(parent, name)
    existed = os.path.isdir(path)
    check_writable(path, option, directory=True)
    if not existed:                 # made by the probe; the run makes it when done
        os.rmdir(path)
        return path
    subdirs = sorted(e.name for e in os.scandir(path)
                     if e.is_dir(follow_symlinks=False) and e.name not in own_dirs)
    if subdirs:
        raise ParameterError(
            f"{option} {path!r} holds the directory {subdirs[0]!r}; a run replaces its output "
            "directory whole, so give a directory of files only (a new one, or an earlier "
            "result directory)")
    return path


def refuse_link(path: str | os.PathLike[str], option: str,
                hint: str = "the tool replaces it: give the real directory instead") -> None:
    """A one-line ``ParameterError`` if ``path`` is a symbolic link: what the tool
    deletes or replaces is never reached through one (it would act on what the
    link points to)."""
    path = os.fspath(path).rstrip(os.sep) or os.fspath(path)
    if os.path.islink(path):
        raise ParameterError(f"{option} {path!r} is a symbolic link (to {os.readlink(path)!r}); "
                             f"{hint}")


_LOCK_FILE = ".stepdamp.lock"


@contextmanager
def output_lock(path: str | os.PathLike[str], option: str) -> Iterator[None]:
    """Hold an exclusive lock (``fcntl.flock``) on the output directory ``path``
    (made if needed) while a run writes it; a second run on the same directory
    gets a one-line ``ParameterError`` naming the process that holds it. The
    lock file lives inside ``path`` and goes with the directory it locked."""
    path = os.fspath(path)
    refuse_link(path, option)
    os.makedirs(path, exist_ok=True)
    lock = os.path.join(path, _LOCK_FILE)
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC,
                     0o644)
    except OSError as exc:
        raise ParameterError(f"{option} {path!r}: its lock file {lock!r} cannot be opened "
                             f"({exc.strerror}); remove it") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode) or info.st_nlink != 1:
            raise ParameterError(f"{option} {path!r}: its lock file {lock!r} is not a plain file "
                                 "of its own (a pipe, a device or a hard link); remove it")
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode("ascii", "replace").strip() or "another process"
            raise ParameterError(f"{option} {path!r} is being written by process {holder}; wait "
                                 "for it to finish or give another directory") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)                    # closing releases the lock


def _carried_over(entry: os.DirEntry, results: Sequence[str]) -> bool:
    """Whether a file of the previous output directory belongs in the new one:
    every file and link but the command's own results and the tool's own
    hidden files (the lock, temporary files)."""
    if entry.name == _LOCK_FILE or _TEMP_FILE.fullmatch(entry.name):
        return False
    if any(fnmatch.fnmatch(entry.name, pat) for pat in results):
        return False
    return entry.is_symlink() or entry.is_file(follow_symlinks=False)


# The temporary files of :func:`atomic_path` (mkstemp: prefix, 8 random characters).
_TEMP_FILE = re.compile(r"\..+\.[a-z0-9_]{8}\.tmp(\.[A-Za-z0-9]+)?")


@contextmanager
def staged_directory(path: str | os.PathLike[str], results: Sequence[str],
                     own_dirs: Mapping[str, Callable[[str], None]] | None = None
                     ) -> Iterator[str]:
    """Yield a fresh staging directory beside ``path``; on success it becomes ``path``.

    ``results`` are glob patterns of the files the command writes: those of a
    previous run in ``path`` are dropped (never mixed with the new ones); any
    other file there is carried over (hard link, else copy). The swap is one
    atomic exchange where the system has it (Linux renameat2), else two renames.
    On any exception the staging directory is removed and ``path`` is untouched.
    After the swap the previous directory is emptied of what the run replaced
    or copied; whatever else it holds (added while the run went on: folders,
    pipes, files) is moved into the new one, never deleted. ``own_dirs``: the
    command's own sub-directories and how to empty them of its files (what
    stays is moved across too).
    """
    path = os.path.abspath(os.fspath(path))
    refuse_link(path, "output directory")
    parent, name = os.path.split(path)
    os.makedirs(parent, exist_ok=True)
    _clean_leftovers(parent, name)
    staging = os.path.join(parent, _STAGING.format(name=name, pid=os.getpid()))
    refuse_link(staging, "staging directory", "stepdamp builds its output there: remove the link")
    shutil.rmtree(staging, ignore_errors=True)
    os.mkdir(staging)
    try:
        yield staging
        if os.path.isdir(path):
            for entry in os.scandir(path):
                if _carried_over(entry, results) and \
                        not os.path.lexists(os.path.join(staging, entry.name)):
                    _link_or_copy(entry.path, os.path.join(staging, entry.name))
        _fsync_path(staging)
        _swap_in(staging, path)
        _fsync_path(parent)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)      # ours alone: results, links, copies
        raise
    if os.path.isdir(staging):          # the previous directory, swapped out
        _retire(staging, path, results, own_dirs or {})


def _retire(old: str, new: str, results: Sequence[str],
            own_dirs: Mapping[str, Callable[[str], None]]) -> None:
    """Remove from the previous output directory ``old`` what the run replaced
    or copied into ``new``, move the rest into ``new``, then remove ``old``; if
    anything could not be moved it is kept, renamed, with a note on stderr."""
    for entry in os.scandir(old):
        target = os.path.join(new, entry.name)
        plain = entry.is_symlink() or entry.is_file(follow_symlinks=False)
        if entry.name in own_dirs and entry.is_dir(follow_symlinks=False):
            try:
                own_dirs[entry.name](entry.path)
                os.rmdir(entry.path)
                continue
            except (OSError, ValueError):   # something of the user's in it: moved across
                pass
        if entry.name == _LOCK_FILE or _TEMP_FILE.fullmatch(entry.name) or \
                (plain and (os.path.lexists(target) or
                            any(fnmatch.fnmatch(entry.name, pat) for pat in results))):
            os.unlink(entry.path)       # replaced, or standing in ``new`` (link or copy)
        elif not os.path.lexists(target):
            os.rename(entry.path, target)
    try:
        os.rmdir(old)
    except OSError:
        kept = os.path.join(os.path.dirname(new),
                            f".{os.path.basename(new)}.kept-{os.getpid()}")
        os.rename(old, kept)
        print(f"stepdamp: note: what the previous {new!r} held and the new one has a result "
              f"of the same name for is kept in {kept!r}", file=sys.stderr)


def _link_or_copy(src: str, dst: str) -> None:
    if os.path.islink(src):             # the link itself, never its target
        os.symlink(os.readlink(src), dst)
        return
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
            if not pid.isdigit() or _alive(int(pid)):
                continue                # not of our making, or a live run's
            refuse_link(entry.path, "leftover staging directory",
                        "stepdamp removes killed runs' leftovers: remove the link")
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
