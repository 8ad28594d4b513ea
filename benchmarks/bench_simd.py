"""SIMD across drives: the kernel's batch against the same batch in lanes, one core.

Run: ``PYTHONPATH=. python benchmarks/bench_simd.py [--drives 64] [--periods 10000]
[--cpus native haswell generic] [--coverage]``.

For each variant of the drive the lanes run (``stepdamp_env.lanes``), a batch of
``--drives`` drives (the four presets, speeds 0.3-3.5 rev/s, open loop, 20 kHz
PWM, RK4, one substep) is stepped ``--periods`` PWM periods by
``kernel.run_batch`` (or ``run_batch_law``) and by ``lanes.run_batch_lanes`` (or
``run_batch_law_lanes``), in a process pinned to one core, best of ``--repeats``;
the two must end in the same bits. Rates are simulated drive-seconds per wall
second. Variants: ``plain`` (no current noise: what ``bench_sim.py`` times),
``noise`` (current-sensor noise on every drive), ``law+noise`` (and a damping law
with resonant terms, as the board's adaptive entries run); with noise too,
``servo`` (servo mode with the patent's feedforward), ``voltage`` (open loop in
voltage mode), ``kalman`` (servo with the Kalman velocity), ``s-curve`` (servo
moves of one revolution with S-curve ramps) and ``fast`` (open loop at 6-16
rev/s, where the RK4 stages shift the electrical angle by 1/8 rad or more: the
lanes' wide plant).

``--cpus`` repeats the measurement in children whose numba compiles for another
CPU (``NUMBA_CPU_NAME`` with that CPU's features only: ``haswell`` is AVX2, 4
doubles per vector; ``nehalem`` is x86-64-v2, SSE4.2, 2; ``generic`` is SSE2, 2). ``--coverage`` runs the v3 quick board in this process and counts
the drive-periods the lanes would cover (every variant since 0.18; a group of
lanes shares one substep count).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import time

import numpy as np

VARIANTS = ("plain", "noise", "law+noise", "servo", "voltage", "kalman", "s-curve", "fast")


def batch(drives: int, variant: str):
    """(configs, states, accumulators, inputs, laws or None) of one variant."""
    from stepdamp_env import kernel as K
    from stepdamp_env.motorfile import load_system
    from stepdamp_env.presets import preset_names
    from stepdamp_env.simulation import (RunSettings, SpeedProfile, build_config, initial_state,
                                         new_accumulators)

    names = preset_names()
    configs = []
    for i in range(drives):
        system = load_system(names[i % len(names)])
        if variant != "plain":
            system = system.replace(current_noise_a=0.02)
        speed = 0.3 + 3.2 * i / max(drives - 1, 1)
        if variant == "fast":
            speed = 6.0 + 10.0 * i / max(drives - 1, 1)
        profile = SpeedProfile(speed)
        settings = RunSettings(noise_seed=i)
        if variant in ("servo", "kalman", "s-curve"):
            settings = RunSettings(noise_seed=i, mode="servo", base_controller="patent-ff",
                                   velocity_estimator="kalman" if variant == "kalman" else "lowpass")
        if variant == "voltage":
            system = system.replace(drive_mode="voltage")
        if variant == "s-curve":
            profile = SpeedProfile(speed, kind="move", distance_rev=1.0, ramp="s-curve",
                                   accel_rps2=200.0)
        configs.append(build_config(system, profile, settings, window_start_s=0.1))
    c = np.array(configs)
    s = np.array([initial_state(row) for row in c])
    laws = None
    if variant == "law+noise":
        laws = np.zeros((drives, len(K.LAW)))
        laws[:, K.LAW.KV] = 0.02
        laws[:, K.LAW.KP] = 0.2
        laws[:, K.LAW.KR1:K.LAW.KI4 + 1] = 5.0
        laws[:, K.LAW.HP_ALPHA] = 0.01
        laws[:, K.LAW.LIMIT] = 0.3
    return c, s, new_accumulators(drives), np.zeros((drives, len(K.INPUT))), laws


def measure(drives: int, periods: int, repeats: int) -> dict:
    """Per variant: the kernel's and the lanes' rates (x real time) and whether
    their bits agree."""
    from stepdamp_env import kernel as K
    from stepdamp_env import lanes

    out = {}
    for variant in VARIANTS:
        c, s0, a0, u, l0 = batch(drives, variant)
        dt = float(c[0, K.CONFIG.DT])

        def kernel_run(s, a, law, n):
            if law is None:
                K.run_batch(c, s, a, u, n)
            else:
                K.run_batch_law(c, s, a, u, law, n)

        def lanes_run(s, a, law, n):
            if law is None:
                lanes.run_batch_lanes(c, s, a, u, n)
            else:
                lanes.run_batch_law_lanes(c, s, a, u, law, n)

        rates, ends = {}, {}
        for name, run in (("kernel", kernel_run), ("lanes", lanes_run)):
            run(s0.copy(), a0.copy(), None if l0 is None else l0.copy(), 1)       # compile
            best = 0.0
            for _ in range(repeats):
                s, a, law = s0.copy(), a0.copy(), None if l0 is None else l0.copy()
                t0 = time.perf_counter()
                run(s, a, law, periods)
                best = max(best, drives * periods * dt / (time.perf_counter() - t0))
            rates[name] = best
            ends[name] = b"".join(x.tobytes() for x in (s, a, law) if x is not None)
        out[variant] = {"kernel": rates["kernel"], "lanes": rates["lanes"],
                        "same_bits": ends["kernel"] == ends["lanes"]}
    return out


def coverage() -> dict:
    """Share of the v3 quick board's drive-periods (one worker, in this process)
    whose drives the lanes run, with and without the law."""
    from stepdamp_env import kernel as K
    from stepdamp_env import lanes
    from stepdamp_env.bench import run_leaderboard
    from stepdamp_env.bench.protocols.v3 import quick_protocol_v3

    counts: collections.Counter = collections.Counter()
    sizes: collections.Counter = collections.Counter()
    step = K.step_batch

    def count(c, n, kind):
        sizes[len(c)] += 1
        for row in c:
            counts[kind, bool(lanes.in_lanes(row, int(row[K.CONFIG.SUBSTEPS])))] += n

    def counted(c, s, a, u, lw, n):
        count(c, n, "plain" if lw is None else "law")
        return step(c, s, a, u, lw, n)

    K.step_batch = counted
    try:
        run_leaderboard(quick_protocol_v3(), workers=1, progress=False)
    finally:
        K.step_batch = step
    total = sum(counts.values())
    drives = sum(k * v for k, v in sizes.items())
    return {"in_lanes": sum(v for (_, inside), v in counts.items() if inside) / total,
            "with_law": sum(v for (kind, _), v in counts.items() if kind == "law") / total,
            "batches": sum(sizes.values()), "mean_drives_per_batch": drives / sum(sizes.values())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--drives", type=int, default=64)
    parser.add_argument("--periods", type=int, default=10000, help="PWM periods (20 kHz: 0.5 s)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cpus", nargs="+", default=["native", "haswell", "nehalem"],
                        help="numba's target CPUs: native, or a NUMBA_CPU_NAME (haswell, generic)")
    parser.add_argument("--coverage", action="store_true",
                        help="also count the v3 quick board's drive-periods the lanes cover")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()

    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    if args.child:
        print(json.dumps(measure(args.drives, args.periods, args.repeats)))
        return
    from stepdamp_env.lanes import LANES

    print(f"{args.drives} drives, {args.periods} PWM periods each, one core, best of {args.repeats}; "
          f"LANES = {LANES}; rates in simulated drive-seconds per wall second")
    for cpu in args.cpus:
        env = dict(os.environ)
        if cpu != "native":
            # No feature list: the named CPU's own (numba would add this CPU's).
            env.update(NUMBA_CPU_NAME=cpu, NUMBA_CPU_FEATURES="")
        out = subprocess.run([sys.executable, __file__, "--child", "--drives", str(args.drives),
                              "--periods", str(args.periods), "--repeats", str(args.repeats)],
                             env=env, check=True, capture_output=True, text=True)
        result = json.loads(out.stdout.strip().splitlines()[-1])
        for variant, r in result.items():
            print(f"  {cpu:8s} {variant:10s} kernel {r['kernel']:7.1f} x, lanes {r['lanes']:7.1f} x, "
                  f"ratio {r['lanes'] / r['kernel']:4.2f}, "
                  f"{'the same bits' if r['same_bits'] else 'BITS DIFFER'}")
    if args.coverage:
        cov = coverage()
        print(f"v3 quick board: {cov['in_lanes']:.1%} of its drive-periods run in lanes; "
              f"{cov['with_law']:.1%} run a damping law; {cov['batches']} kernel calls of "
              f"{cov['mean_drives_per_batch']:.1f} drives on average")


if __name__ == "__main__":
    main()
