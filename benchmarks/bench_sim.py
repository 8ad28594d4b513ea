"""Simulation speed: simulated seconds per wall-clock second, one core.

Runs the full open-loop model (PWM and current loop at 20 kHz, RK4 plant, one
substep, metrics on, no trace) of the patent preset on one pinned core, and,
in the same run, the very same code interpreted by Python (numba's JIT
disabled in a subprocess) as the reference.

    python benchmarks/bench_sim.py [--sim-seconds 20] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time


def measure(sim_seconds: float, repeats: int, speed_rps: float, motor: str) -> dict:
    import numpy as np

    from stepdamp_env import kernel as K
    from stepdamp_env.motorfile import load_system
    from stepdamp_env.simulation import (RunSettings, SpeedProfile, build_config,
                                         initial_state, new_accumulators, run_periods_chunked)

    system = load_system(motor)
    config = build_config(system, SpeedProfile(speed_rps), RunSettings(), window_start_s=0.1)
    n = int(round(sim_seconds * system.drive.pwm_hz))
    empty = np.zeros((0, len(K.TRACE)))
    u = np.zeros(len(K.INPUT))
    K.run_periods(config, initial_state(config), new_accumulators(), u, 10, empty, 1)  # compile
    # One kernel call, and simulate()'s chunks (signals handled between them), interleaved.
    ways = {"one call": K.run_periods, "chunked": run_periods_chunked}
    rates: dict[str, list[float]] = {way: [] for way in ways}
    for _ in range(repeats):
        for way, run in ways.items():
            state, acc = initial_state(config), new_accumulators()
            t0 = time.perf_counter()
            run(config, state, acc, u, n, empty, 1)
            rates[way].append(sim_seconds / (time.perf_counter() - t0))
    one = rates["one call"]
    return {"sim_seconds": sim_seconds, "repeats": repeats, "best": max(one),
            "median": float(np.median(one)), "worst": min(one),
            "ns_per_pwm_period": 1e9 / (system.drive.pwm_hz * float(np.median(one))),
            "chunked_over_one_call": float(np.median(rates["chunked"]) / np.median(one))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sim-seconds", type=float, default=20.0)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--speed", type=float, default=1.0, help="command speed (rev/s)")
    parser.add_argument("--motor", default="patent")
    parser.add_argument("--reference-sim-seconds", type=float, default=0.05,
                        help="simulated time for the interpreted reference")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()

    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    if args.child:
        print(json.dumps(measure(args.sim_seconds, 1, args.speed, args.motor)))
        return

    compiled = measure(args.sim_seconds, args.repeats, args.speed, args.motor)
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    out = subprocess.run([sys.executable, __file__, "--child", "--sim-seconds",
                          str(args.reference_sim_seconds), "--speed", str(args.speed),
                          "--motor", args.motor], env=env, check=True, capture_output=True,
                         text=True)
    interpreted = json.loads(out.stdout.strip().splitlines()[-1])
    print(f"motor {args.motor}, open loop at {args.speed} rev/s, 20 kHz PWM, one core")
    print(f"numba kernel : {compiled['median']:9.1f} x real time (median of {args.repeats}; "
          f"best {compiled['best']:.1f}, worst {compiled['worst']:.1f}); "
          f"{compiled['ns_per_pwm_period']:.0f} ns per PWM period")
    print(f"pure Python  : {interpreted['median']:9.4f} x real time (same code, JIT off, "
          f"{args.reference_sim_seconds} s simulated)")
    print(f"speed-up     : {compiled['median'] / interpreted['median']:9.0f} x")
    print(f"in chunks    : {compiled['chunked_over_one_call']:9.3f} x the rate of one call "
          "(simulate's chunks of 2^18 plant steps, interleaved)")


if __name__ == "__main__":
    main()
