"""Where a board was computed, and a fingerprint of what it computed.

A board records its environment (:func:`environment`: package versions, the
CPU's model and instruction-set flags, thread counts, the dispatch settings in
force) and a fingerprint of its numbers (:func:`board_fingerprint`). The
numbers do not depend on the environment (:mod:`stepdamp_env.fixedmath`), so
two boards of the same protocol, entries and package version have the same
fingerprint on any x86-64 CPU; the environment is recorded to tell why they
do not, should they ever differ.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import platform
import sys
from typing import Any, Mapping

from ..io import tree_digest

__all__ = ["environment", "package_versions", "code_fingerprint", "board_fingerprint",
           "entry_fingerprints", "DISPATCH_VARIABLES"]

#: Environment variables that choose a library's CPU code path or thread count.
DISPATCH_VARIABLES = ("OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
                      "MKL_NUM_THREADS", "NPY_DISABLE_CPU_FEATURES", "NPY_ENABLE_CPU_FEATURES",
                      "ATEN_CPU_CAPABILITY", "NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES",
                      "NUMBA_NUM_THREADS", "GLIBC_TUNABLES")
# Board keys that describe the run, not its numbers.
# "firmware": what export can write per entry, a property of the code, not a result.
_NOT_NUMBERS = ("wall_seconds", "versions", "environment", "fingerprint", "runs_file",
                "firmware")


def _plain(obj: Any) -> Any:
    if hasattr(obj, "tolist"):              # numpy scalars and arrays
        return obj.tolist()
    raise TypeError(f"cannot fingerprint {type(obj).__name__}")


def _canonical(value: Any) -> bytes:
    """JSON with sorted keys; floats as ``repr`` (round-trips every bit), so a
    board and the same board read back from its files give the same bytes."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=True,
                      default=_plain).encode()


def _numbers(board: Mapping[str, Any]) -> dict[str, Any]:
    """The board without what describes the run: wall time, versions, environment,
    and each entry's ``spec`` (a policy file's path differs between machines)."""
    out = {k: v for k, v in board.items() if k not in _NOT_NUMBERS}
    if "entries" in out:
        out["entries"] = [{k: v for k, v in e.items() if k != "spec"} for e in out["entries"]]
    return out


def board_fingerprint(board: Mapping[str, Any]) -> str:
    """sha256 of every number of a board (protocol, motors, identification, every
    entry with its per-run records), without its wall time, versions,
    environment or the entries' specs. ``board`` as
    :func:`.leaderboard.run_leaderboard` returns it or
    :func:`.report.load_leaderboard` reads it back."""
    digest = hashlib.sha256()
    for chunk in _canonical_chunks(_numbers(board)):
        digest.update(chunk)
    return digest.hexdigest()


def _canonical_chunks(numbers: Mapping[str, Any]) -> Any:
    """:func:`_canonical` of a board's numbers in pieces, an entry at a time (the
    same bytes): a thread compressing the runs file meanwhile gets the GIL
    between them."""
    yield b"{"
    for i, key in enumerate(sorted(numbers)):
        yield (("," if i else "") + json.dumps(key) + ":").encode()
        if key == "entries" and isinstance(numbers[key], list):
            yield b"["
            for j, entry in enumerate(numbers[key]):
                yield (b"," if j else b"") + _canonical(entry)
            yield b"]"
        else:
            yield _canonical(numbers[key])
    yield b"}"


def entry_fingerprints(board: Mapping[str, Any]) -> dict[str, str]:
    """sha256 per entry (``name|suite|split``), and of the protocol with its motors
    and of the identification: where two boards differ."""
    out = {"protocol": hashlib.sha256(_canonical(board.get("protocol"))).hexdigest(),
           "identification": hashlib.sha256(_canonical(board.get("identification"))).hexdigest()}
    for e in board.get("entries", ()):
        key = f"{e['name']}|{e['suite']}|{e.get('split', '')}"
        out[key] = hashlib.sha256(_canonical({k: v for k, v in e.items()
                                              if k != "spec"})).hexdigest()
    return out


def _cpu() -> dict[str, Any]:
    """Model name and instruction-set flags (Linux /proc/cpuinfo; else platform's word)."""
    model, flags = platform.processor() or platform.machine(), []
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and model in ("", platform.machine(),
                                                            platform.processor()):
                    model = value.strip()
                elif key.strip() == "flags" and not flags:
                    flags = sorted(value.split())
                if model and flags and key.strip() == "flags":
                    break
    except OSError:
        pass
    wanted = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512dq", "avx512bw", "avx512vl",
              "avx512_vnni", "avx512_bf16", "avx512fp16", "amx_tile")
    return {"model": model, "machine": platform.machine(),
            "flags": [f for f in wanted if f in flags]}


def _threads() -> dict[str, Any]:
    out: dict[str, Any] = {"cpus": os.cpu_count()}
    try:
        out["cpus_usable"] = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        pass
    if "torch" in sys.modules:
        out["torch"] = sys.modules["torch"].get_num_threads()
    try:
        import numba

        out["numba"] = int(numba.get_num_threads())
    except Exception:  # noqa: BLE001 - the record is informative, never fatal
        pass
    return out


def package_versions() -> dict[str, str]:
    """Versions of this package, Python and the numerical dependencies."""
    from ..version import __version__

    out = {"package": __version__, "python": platform.python_version()}
    for dist, key in (("numpy", "numpy"), ("numba", "numba"), ("gymnasium", "gymnasium"),
                      ("stable-baselines3", "stable-baselines3"), ("torch", "torch")):
        try:
            out[key] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[key] = "not installed"
    return out


def code_fingerprint() -> str:
    """This package's Python sources (read now) and the versions of its numerical
    dependencies: a result kept on disk is reused only by the same code."""
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    return hashlib.sha256(json.dumps([tree_digest(here, (".py",)), package_versions()],
                                     sort_keys=True).encode()).hexdigest()


def _numpy_simd() -> dict[str, Any]:
    """numpy's baseline and the instruction-set groups it dispatches to here."""
    import numpy as np

    try:
        simd = np.show_config(mode="dicts")["SIMD Extensions"]
        return {"baseline": list(simd.get("baseline", [])), "found": list(simd.get("found", []))}
    except Exception:  # noqa: BLE001 - an older numpy: not recorded
        return {}


def environment() -> dict[str, Any]:
    """The software and hardware a board was computed on (JSON-ready)."""
    versions = dict(package_versions())
    for dist in ("llvmlite", "sb3-contrib", "filterpy"):
        try:
            versions[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            versions[dist] = "not installed"
    return {"versions": versions,
            "python": platform.python_implementation() + " " + platform.python_version(),
            "libc": " ".join(platform.libc_ver()).strip(),
            "system": platform.platform(),
            "cpu": _cpu(),
            "numpy_simd": _numpy_simd(),
            "threads": _threads(),
            "dispatch_variables": {k: os.environ[k] for k in DISPATCH_VARIABLES
                                   if k in os.environ}}
