"""Paired A/B of the kernel's and the lanes' rates between two checkouts.

Run: ``python benchmarks/bench_ab.py BEFORE_DIR AFTER_DIR [--rounds 15]
[--cases plain:kernel1 plain:kernel plain:lanes noise:lanes law+noise:kernel
law+noise:lanes]``.

Two long-lived workers, one per checkout (each imports its own
``stepdamp_env`` and ``benchmarks/bench_simd.py``), pinned to core 1 and
asked in alternation, so that a slow spell of a noisy machine falls on both:
per case a batch of 64 drives (``bench_simd.batch``; ``kernel1``: one drive,
bench_sim's configuration) stepped 2000 PWM periods, ``--rounds`` times each.
Prints the best and median rates (x real time) and after/before as the ratio
of the bests and the median of the paired ratios.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

WORKER = r'''
import sys, time, json
sys.path.insert(0, sys.argv[1]); sys.path.insert(0, sys.argv[1] + "/benchmarks")
import bench_simd as B
from stepdamp_env import kernel as K, lanes
cache = {}
for line in sys.stdin:
    variant, kind, periods = line.split(); periods = int(periods)
    if variant not in cache:
        cache[variant] = B.batch(64, variant)
    c, s0, a0, u, l0 = cache[variant]
    dt = float(c[0, K.CONFIG.DT])
    s, a, law = s0.copy(), a0.copy(), None if l0 is None else l0.copy()
    if kind == "kernel1":      # one drive, as bench_sim
        c1, s1, a1, u1 = c[:1], s[:1], a[:1], u[:1]
        t0 = time.perf_counter(); K.run_batch(c1, s1, a1, u1, periods * 8); el = time.perf_counter() - t0
        print(json.dumps(periods * 8 * dt / el), flush=True); continue
    run = {("kernel", True): lambda: K.run_batch(c, s, a, u, periods),
           ("kernel", False): lambda: K.run_batch_law(c, s, a, u, law, periods),
           ("lanes", True): lambda: lanes.run_batch_lanes(c, s, a, u, periods),
           ("lanes", False): lambda: lanes.run_batch_law_lanes(c, s, a, u, law, periods)}[kind, l0 is None]
    t0 = time.perf_counter(); run(); el = time.perf_counter() - t0
    print(json.dumps(64 * periods * dt / el), flush=True)
'''

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("before"); parser.add_argument("after")
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--cases", nargs="+", default=["plain:kernel1", "plain:kernel", "plain:lanes", "noise:lanes",
                                                       "law+noise:kernel", "law+noise:lanes"])
    args = parser.parse_args()
    trees = {"before": os.path.abspath(args.before), "after": os.path.abspath(args.after)}
    procs = {k: subprocess.Popen(["taskset", "-c", "1", sys.executable, "-c", WORKER, v], stdin=subprocess.PIPE,
                                 stdout=subprocess.PIPE, text=True, cwd=v, env={**os.environ, "PYTHONPATH": v})
             for k, v in trees.items()}
    def ask(k, msg):
        procs[k].stdin.write(msg + "\n"); procs[k].stdin.flush()
        return json.loads(procs[k].stdout.readline())
    rounds = args.rounds
    for variant, kind in [tuple(v.split(":")) for v in args.cases]:
        for k in trees: ask(k, f"{variant} {kind} 50")   # compile, warm
        rates = {k: [] for k in trees}
        for r in range(rounds):
            order = list(trees) if r % 2 == 0 else list(trees)[::-1]
            for k in order:
                rates[k].append(ask(k, f"{variant} {kind} 2000"))
        ratios = [a / b for a, b in zip(rates["after"], rates["before"])]
        print(f"{variant:10s} {kind:8s} before best {max(rates['before']):7.1f}x med {statistics.median(rates['before']):7.1f}x | "
              f"after best {max(rates['after']):7.1f}x med {statistics.median(rates['after']):7.1f}x | "
              f"after/before: best {max(rates['after'])/max(rates['before']):.3f}, median paired {statistics.median(ratios):.3f}", flush=True)


if __name__ == "__main__":
    main()
