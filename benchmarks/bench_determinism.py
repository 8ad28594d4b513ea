"""Same numbers on every x86-64 CPU: boards under emulated CPUs, against the published ones.

Quick boards (default): every variant of ``tests/cpu_variants.py`` (older and
newer BLAS kernels, numpy and torch without AVX2 or AVX-512, numba generic, the
C library without FMA, 1 or 2 workers) runs the v0, v1, v2 and v3 quick boards in
a fresh process; each must give the fingerprints in
``tests/data/quick_boards.json``. ``--full``: the full published boards, with their own entries
(``docs/results``: v1, ``docs/results/v0``, ``docs/results/v2``,
``docs/results/v3``), each run by
``stepdamp leaderboard`` under the chosen variants and compared, entry by
entry, with the committed ``leaderboard.json`` and its runs file.

    python benchmarks/bench_determinism.py [--variant NAME ...] [--protocol v1 ...]
    python benchmarks/bench_determinism.py --full --variant avx2 --protocol v1

Prints one line per variant (and protocol): its wall time and "identical" or
the entries that differ; exit status 1 if any differs.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))

import cpu_variants as V  # noqa: E402

PUBLISHED = {"v0": os.path.join(ROOT, "docs", "results", "v0"),
             "v1": os.path.join(ROOT, "docs", "results"),
             "v2": os.path.join(ROOT, "docs", "results", "v2"),
             "v3": os.path.join(ROOT, "docs", "results", "v3")}


def published_entries(protocol: str) -> list[str]:
    """The entries of the published board, in its order (v0's are those of 0.4.0,
    not today's defaults: an entry's ranks and probabilities depend on the others)."""
    from stepdamp_env.bench.report import load_leaderboard

    names: list[str] = []
    for entry in load_leaderboard(PUBLISHED[protocol])["entries"]:
        if entry["name"] not in names and not entry.get("reference"):   # v3's rows: always run
            names.append(entry["name"])
    return names


def full_board(variant: str, protocol: str, out: str) -> float:
    """Run the full board of ``protocol`` with the published board's entries under
    ``variant`` into ``out``; wall seconds."""
    env_vars, workers = V.VARIANTS[variant]
    env = {**os.environ, **env_vars, "STEPDAMP_CACHE_DIR": "off", "MPLBACKEND": "Agg"}
    cmd = [sys.executable, "-m", "stepdamp_env.cli", "leaderboard", "--protocol", protocol,
           "--out", out, "--no-plots", "--no-progress", "--no-resume", "--workers", str(workers),
           "--entries", *published_entries(protocol)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def compare_full(protocol: str, out: str) -> list[str]:
    from stepdamp_env.bench.provenance import entry_fingerprints
    from stepdamp_env.bench.report import load_leaderboard

    got = entry_fingerprints(load_leaderboard(out))
    want = entry_fingerprints(load_leaderboard(PUBLISHED[protocol]))
    return sorted(k for k in set(got) | set(want) if got.get(k) != want.get(k))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--variant", action="append", choices=sorted(V.VARIANTS))
    p.add_argument("--protocol", action="append", choices=V.PROTOCOLS)
    p.add_argument("--full", action="store_true", help="the full boards against docs/results")
    args = p.parse_args()
    protocols = tuple(args.protocol or V.PROTOCOLS)
    failed = 0
    for name in args.variant or sorted(V.VARIANTS):
        if not args.full:
            t0 = time.perf_counter()
            diff = V.differences({k: V.stored()[k] for k in protocols},
                                 V.run_variant(name, protocols))
            print(f"quick {'+'.join(protocols)} {name:16s} {time.perf_counter() - t0:7.1f} s  "
                  f"{'identical' if not diff else f'{len(diff)} differ: {diff[:6]}'}", flush=True)
            failed += bool(diff)
            continue
        for protocol in protocols:
            with tempfile.TemporaryDirectory() as tmp:
                out = os.path.join(tmp, "board")
                wall = full_board(name, protocol, out)
                diff = compare_full(protocol, out)
            print(f"full {protocol} {name:16s} {wall:7.1f} s  "
                  f"{'identical to the published board' if not diff else f'{len(diff)} differ: {diff[:6]}'}",
                  flush=True)
            failed += bool(diff)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
