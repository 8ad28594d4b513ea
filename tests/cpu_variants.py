"""The quick boards under emulated CPUs: the same numbers on every x86-64 CPU.

Each variant runs the quick boards of v0 to v5 (every default entry of
each version, ``Protocol.default_entries``: the identification, estimators,
adaptive laws, learned networks and statistics all run) in a fresh process whose environment makes the libraries take the
code paths of another CPU:

* ``OPENBLAS_CORETYPE``: OpenBLAS's kernels for an older or newer core;
* ``NPY_DISABLE_CPU_FEATURES``: numpy's loops without AVX2/FMA or AVX-512;
* ``ATEN_CPU_CAPABILITY``: torch's kernels without AVX2 or AVX-512;
* ``NUMBA_CPU_NAME=generic``: numba/LLVM code for a generic x86-64 (no FMA);
  ``haswell`` with ``NUMBA_CPU_FEATURES=""``: an AVX2 CPU's code (numba would
  otherwise add this CPU's features to the name);
* ``GLIBC_TUNABLES=glibc.cpu.hwcaps=-AVX2,-FMA``: the C library's plain
  ``exp``/``log``/``sin``/``pow`` instead of its FMA variants (what a CPU
  without FMA runs);
* 1 or 2 worker processes (and threads);
* the vector env's drives on one and on two of numba's threads, and in SIMD lanes
  (the same bits; ``NUMBA_CPU_NAME`` sets the vector width: 2 doubles for
  ``generic``, 4 for ``haswell``, 8 natively on AVX-512).

Every variant must give the stored fingerprints (``tests/data/quick_boards.json``),
which the native run gives too (``tests/test_cpu_determinism.py``). The full
boards: ``python benchmarks/bench_determinism.py``. To store the quick boards'
fingerprints again (only at a re-baseline, which CHANGELOG must state, or for a
new protocol):

    python tests/cpu_variants.py --store [--protocol v3]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from typing import Any, Sequence

HERE = os.path.dirname(os.path.abspath(__file__))
STORED = os.path.join(HERE, "data", "quick_boards.json")
PROTOCOLS = ("v0", "v1", "v2", "v3", "v4", "v5", "env-v2", "env-v3")
#: Rollouts pinned beside the boards: the env versions no board runs.
ENV_ROLLOUTS = {"env-v2": "StepperDamp-v2", "env-v3": "StepperDamp-v3"}

_ABOVE_V2 = "X86_V3 X86_V4 AVX512_ICL AVX512_SPR"
_ABOVE_V3 = "X86_V4 AVX512_ICL AVX512_SPR"
_NO_FMA_LIBC = "glibc.cpu.hwcaps=-AVX2,-FMA"

#: name -> (environment, workers). "x86-64-v2" is the oldest CPU the package supports.
VARIANTS: dict[str, tuple[dict[str, str], int]] = {
    "native": ({}, 2),
    "x86-64-v2": ({"OPENBLAS_CORETYPE": "Prescott", "NPY_DISABLE_CPU_FEATURES": _ABOVE_V2,
                   "ATEN_CPU_CAPABILITY": "default", "NUMBA_CPU_NAME": "generic",
                   "GLIBC_TUNABLES": _NO_FMA_LIBC}, 1),
    "avx2": ({"OPENBLAS_CORETYPE": "Haswell", "NPY_DISABLE_CPU_FEATURES": _ABOVE_V3,
              "ATEN_CPU_CAPABILITY": "avx2", "NUMBA_CPU_NAME": "haswell",
              "NUMBA_CPU_FEATURES": ""}, 1),
    # The combination the reproducibility issue names.
    "sandybridge": ({"OPENBLAS_CORETYPE": "Sandybridge", "NPY_DISABLE_CPU_FEATURES": _ABOVE_V2,
                     "ATEN_CPU_CAPABILITY": "default", "NUMBA_CPU_NAME": "generic"}, 2),
    "skylakex": ({"OPENBLAS_CORETYPE": "SkylakeX"}, 1),
    "numba-generic": ({"NUMBA_CPU_NAME": "generic"}, 2),
    "libc-no-fma": ({"GLIBC_TUNABLES": _NO_FMA_LIBC}, 2),
    "numpy-x86-64-v2": ({"NPY_DISABLE_CPU_FEATURES": _ABOVE_V2}, 2),
}


def quick_boards(protocols: Sequence[str] = PROTOCOLS, workers: int = 2,
                 full: bool = False, lanes: bool = True) -> dict[str, Any]:
    """Board fingerprint and per-entry fingerprints of each protocol's quick board
    (every default entry), computed in this process; then the threads' and (with
    ``lanes``) the SIMD lanes' bit equality."""
    from stepdamp_env.bench import (full_protocol, full_protocol_v1, full_protocol_v2,
                                    quick_protocol, quick_protocol_v1, quick_protocol_v2,
                                    run_leaderboard)
    from stepdamp_env.bench.provenance import entry_fingerprints

    from stepdamp_env.bench.protocols.v3 import full_protocol_v3, quick_protocol_v3
    from stepdamp_env.bench.protocols.v4 import full_protocol_v4, quick_protocol_v4
    from stepdamp_env.bench.protocols.v5 import full_protocol_v5, quick_protocol_v5

    make = {"v0": (quick_protocol, full_protocol), "v1": (quick_protocol_v1, full_protocol_v1),
            "v2": (quick_protocol_v2, full_protocol_v2), "v3": (quick_protocol_v3, full_protocol_v3),
            "v4": (quick_protocol_v4, full_protocol_v4),
            "v5": (quick_protocol_v5, full_protocol_v5)}
    out = {}
    for name in protocols:
        if name in ENV_ROLLOUTS:
            out[name] = {"fingerprint": env_rollout_fingerprint(ENV_ROLLOUTS[name]),
                         "entries": {}}
            continue
        board = run_leaderboard(make[name][full](), workers=workers, progress=False)
        out[name] = {"fingerprint": board["fingerprint"], "entries": entry_fingerprints(board)}
    check_threads_give_the_same_bits()
    if lanes:
        check_lanes_give_the_same_bits()
    return out


def env_rollout_fingerprint(env_id: str) -> str:
    """sha256 of a native vector env's rollout (8 drives, seeded uniform random
    actions, 110 steps: past the 1 s episodes' end and autoreset): observations,
    rewards, episode ends and the per-step ripple info."""
    import hashlib
    import warnings

    import gymnasium as gym
    import numpy as np

    import stepdamp_env  # noqa: F401  (registers the envs)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                 # v2's note: a newer version exists
        env = gym.make_vec(env_id, num_envs=8, vectorization_mode="vector_entry_point")
    obs, _ = env.reset(seed=list(range(123, 131)))
    rng = np.random.default_rng(3)
    digest = hashlib.sha256(obs.tobytes())
    for _ in range(110):
        action = rng.uniform(-1.0, 1.0, env.action_space.shape).astype(np.float32)
        obs, reward, term, trunc, info = env.step(action)
        ripple = info.get("velocity_error_rms_rad_s", np.zeros(0))    # none at a reset step
        for part in (obs, reward, term, trunc, ripple):
            digest.update(np.ascontiguousarray(part).tobytes())
    env.close()
    return digest.hexdigest()


def _v1_rollout(seed: int, steps: int, **kwargs: Any) -> bytes:
    """Observations and rewards of a v1 vector env (agent at 250 Hz) under seeded
    random actions, as bytes."""
    import numpy as np

    from stepdamp_env.env import StepperDampV1VectorEnv

    env = StepperDampV1VectorEnv(agent_hz=250.0, **kwargs)
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    out = [obs.tobytes()]
    for _ in range(steps):
        obs, reward, _, _, _ = env.step(rng.uniform(-1, 1, env.action_space.shape))
        out += [obs.tobytes(), reward.tobytes()]
    return b"".join(out)


def check_threads_give_the_same_bits() -> None:
    """A training env's steps on numba's threads equal its serial steps here (the
    serial ones are pinned by the boards above); AssertionError otherwise."""
    import numba

    def rollout(threads: int) -> bytes:
        return _v1_rollout(5, 20, num_envs=4, num_threads=threads, randomize=True)

    threads = min(2, int(numba.config.NUMBA_NUM_THREADS))
    assert rollout(1) == rollout(threads), "parallel drive steps differ from the serial ones"


def check_lanes_give_the_same_bits() -> None:
    """A training env's steps in SIMD lanes equal its plain steps here, on one and on
    two of numba's threads; AssertionError otherwise."""
    import numba

    def rollout(simd: bool, threads: int, mode: str) -> bytes:
        return _v1_rollout(9, 10, num_envs=37, num_threads=threads, simd=simd, action_mode=mode,
                           randomize=True)

    for mode in ("harmonic", "damping-gains", "gain-phase"):   # the plain loop, the law's
        plain = rollout(False, 1, mode)
        for threads in {1, min(2, int(numba.config.NUMBA_NUM_THREADS))}:
            assert rollout(True, threads, mode) == plain, f"SIMD lanes differ ({mode})"


def openblas_core() -> str:
    """The kernels numpy's OpenBLAS picked here ("SkylakeX", "Haswell", ...); "" if
    it does not say."""
    import ctypes
    import glob

    import numpy as np

    for path in glob.glob(os.path.join(os.path.dirname(np.__file__), os.pardir, "numpy.libs",
                                       "*openblas*")):
        lib = ctypes.CDLL(path)
        for name in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename",
                     "openblas_get_corename64_", "openblas_get_corename"):
            get = getattr(lib, name, None)
            if get is not None:
                get.restype = ctypes.c_char_p
                return get().decode()
    return ""


def runs_here(name: str) -> bool:
    """False for a variant whose code needs an instruction set this CPU lacks, or
    that is this machine's own configuration ("skylakex" where OpenBLAS picks its
    SkylakeX kernels anyway: the "native" boards are that variant)."""
    from numba.core.codegen import get_host_cpu_features

    needs = {"avx2": "+avx2", "skylakex": "+avx512f"}.get(name)
    if needs is not None and needs not in get_host_cpu_features().split(","):
        return False
    return not (name == "skylakex" and openblas_core() == "SkylakeX")


def start_variant(name: str, protocols: Sequence[str] = PROTOCOLS, full: bool = False,
                  lanes: bool = True) -> subprocess.Popen:
    """:func:`quick_boards` started in a fresh process under the variant's
    environment (no identification cache: every variant identifies for itself;
    its own numba cache, so that its code for another CPU never rewrites the
    cache index this machine's processes read while they run);
    :func:`finish_variant` collects it. Variants started together run side by side."""
    env_vars, workers = VARIANTS[name]
    env = {k: v for k, v in os.environ.items()
           if k not in env_vars and k not in ("NUMBA_CACHE_DIR", "_STEPDAMP_NUMBA_CACHE_DIR")}
    env.update(env_vars)
    env.update(NUMBA_CACHE_DIR=os.path.join(tempfile.gettempdir(),
                                            f"stepdamp-numba-cpu-variant-{name}"))
    env.update(STEPDAMP_CACHE_DIR="off", OMP_NUM_THREADS=str(workers),
               OPENBLAS_NUM_THREADS=str(workers), MKL_NUM_THREADS=str(workers),
               MPLBACKEND="Agg")
    code = (f"import sys, json; sys.path.insert(0, {HERE!r}); import cpu_variants as V; "
            f"print(json.dumps(V.quick_boards({list(protocols)!r}, {workers}, {full!r}, "
            f"{lanes!r})))")
    proc = subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    proc.variant = name                     # type: ignore[attr-defined]
    return proc


def finish_variant(proc: subprocess.Popen, timeout_s: float = 3600.0) -> dict[str, Any]:
    """The started variant's result; RuntimeError with its stderr if it failed."""
    try:
        stdout, stderr = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise
    if proc.returncode != 0:
        raise RuntimeError(f"variant {proc.variant} failed:\n{stderr[-3000:]}")
    return json.loads(stdout.strip().splitlines()[-1])


def run_variant(name: str, protocols: Sequence[str] = PROTOCOLS, full: bool = False,
                timeout_s: float = 3600.0) -> dict[str, Any]:
    """:func:`quick_boards` in a fresh process under the variant's environment."""
    return finish_variant(start_variant(name, protocols, full), timeout_s)


def differences(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """The protocol|entry keys whose fingerprints differ between two results."""
    keys = []
    for proto in sorted(set(a) | set(b)):
        ea, eb = a.get(proto, {}).get("entries", {}), b.get(proto, {}).get("entries", {})
        mine = [f"{proto}: {k}" for k in sorted(set(ea) | set(eb)) if ea.get(k) != eb.get(k)]
        # The board's own fingerprint, where no entry of this protocol already differs.
        if not mine and a.get(proto, {}).get("fingerprint") != b.get(proto, {}).get("fingerprint"):
            mine.append(f"{proto}: board")
        keys += mine
    return keys


def stored() -> dict[str, Any]:
    with open(STORED, encoding="utf-8") as fh:
        return json.load(fh)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--variant", action="append", choices=sorted(VARIANTS),
                   help="variants to run (default: all)")
    p.add_argument("--protocol", action="append", choices=PROTOCOLS)
    p.add_argument("--store", action="store_true",
                   help="store the native quick boards' fingerprints of --protocol (default: "
                        "all; a re-baseline of a published protocol, or a new one)")
    args = p.parse_args(argv)
    protocols = tuple(args.protocol or PROTOCOLS)
    if args.store:          # the given protocols' (default: all), the others kept
        data = stored() if os.path.exists(STORED) else {}
        data.update(run_variant("native", protocols))
        with open(STORED, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=1, sort_keys=True)
            fh.write("\n")
        print(f"stored {STORED}")
        return 0
    reference = stored()
    failed = 0
    for name in args.variant or sorted(VARIANTS):
        t0 = time.perf_counter()
        got = run_variant(name, protocols)
        diff = differences({k: reference[k] for k in protocols}, got)
        failed += bool(diff)
        print(f"{name:16s} {time.perf_counter() - t0:6.1f} s  "
              f"{'identical' if not diff else f'{len(diff)} differ: {diff[:8]}'}", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
