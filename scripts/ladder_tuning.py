"""Choose the baseline ladder's design constants on training motors (never the protocol's).

Training motors: the four presets and ``--draws`` motors drawn around each with
v0's randomisation ranges from ``numpy.random.default_rng(SEED)`` (SEED below
the training-seed limit; the protocol draws with 7733051), usable by v0's own
rule; identification and sensor noise with seed 1. For every candidate value the
script prints the headline (mean ripple at the resonant speeds over the
undamped drive's) as a median and mean over the training motors.

Run: ``PYTHONPATH=. python scripts/ladder_tuning.py [--draws 2] [--suite open-loop]``
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any, Callable

import numpy as np

from stepdamp_baselines import make_baseline
from stepdamp_baselines.feedback import SensorlessDamping, VelocityFeedback
from stepdamp_baselines.learning import CalibratedTable, RepetitiveControl
from stepdamp_env.bench import full_protocol, protocol_motors, run_episode
from stepdamp_env.bench.leaderboard import protocol_knowledge
from stepdamp_env.bench.protocol import TRAINING_SEED_LIMIT
from stepdamp_env.identify import identify
from stepdamp_env.parallel import pool_map

SEED = 261122
NOISE_SEED = 1
assert SEED < TRAINING_SEED_LIMIT and NOISE_SEED < TRAINING_SEED_LIMIT

CANDIDATES: dict[str, list[tuple[str, Callable[[], Any]]]] = {
    "velocity-feedback": [(f"zeta={z},f={f}", (lambda z=z, f=f: VelocityFeedback(z, f)))
                          for z in (0.01, 0.02, 0.03, 0.05) for f in (30.0, 100.0)],
    "sensorless-damping": [(f"zeta={z},f={f}", (lambda z=z, f=f: SensorlessDamping(z, f)))
                           for z in (0.01, 0.02, 0.03, 0.05) for f in (30.0, 100.0)],
    "repetitive-control": [(f"gain={g}", (lambda g=g: RepetitiveControl(learning_gain=g)))
                           for g in (0.05, 0.1, 0.2, 0.4)],
    "calibrated-table": [("default", CalibratedTable)],
}

_STATE: dict[str, Any] = {}


def training_motors(draws: int):
    protocol = dataclasses.replace(full_protocol(), motor_seed=SEED, randomized_per_preset=draws)
    return protocol, protocol_motors(protocol)


def _job(args):
    name, k, mi = args
    protocol, motors, models = _STATE["protocol"], _STATE["motors"], _STATE["models"]
    motor = motors[mi]
    make = dict(CANDIDATES.get(name, []))[k] if name in CANDIDATES else \
        (lambda: make_baseline(name))
    knowledge = protocol_knowledge(motor, NOISE_SEED, models[mi], protocol)
    out = []
    for speed, label in zip(motor.speeds_rps, motor.speed_labels):
        if label == "off":
            continue
        r = run_episode(make(), knowledge, motor.system, mode=_STATE["suite"], speed_rps=speed,
                        seed=NOISE_SEED, accel_rps2=protocol.accel_rps2,
                        window_s=protocol.window_s)
        out.append(np.inf if r.failed or r.metrics is None
                   else r.metrics["rms_velocity_error_rad_s"])
    return float(np.mean(out))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--draws", type=int, default=2)
    p.add_argument("--suite", default="open-loop")
    p.add_argument("--only", nargs="*", default=list(CANDIDATES))
    p.add_argument("--workers", type=int, default=2)
    args = p.parse_args()
    protocol, motors = training_motors(args.draws)
    models = [identify(m.system, method=protocol.identification_method,
                       noise_seed=NOISE_SEED).model for m in motors]
    _STATE.update(protocol=protocol, motors=motors, models=models, suite=args.suite)
    print(f"{len(motors)} training motors (seed {SEED}), suite {args.suite}")
    jobs = [(name, "", i) for name in ("none", "ff-delay-comp", "patent-ff-identified")
            for i in range(len(motors))]
    for name in args.only:
        jobs += [(name, k, i) for k, _ in CANDIDATES[name] for i in range(len(motors))]
    res = pool_map(_job, jobs, args.workers, max_chunk=4)
    table: dict[tuple[str, str], list[float]] = {}
    for (name, k, i), v in zip(jobs, res):
        table.setdefault((name, k), []).append(v)
    ref = np.array(table[("none", "")])
    for (name, k), v in table.items():
        ratio = np.array(v) / ref
        print(f"{name:22s} {k:16s} headline median {np.median(ratio):.4f} "
              f"mean {np.mean(ratio):.4f} worst {np.max(ratio):.4f}")


if __name__ == "__main__":
    main()
