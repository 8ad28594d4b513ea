"""The logs ``stepdamp identify --plan`` asks for, on the catalogue's real motors:
open loop (what the plan asks for) against servo (docs/drivelogs.md, "On
catalogue motors").

Run: ``PYTHONPATH=. python benchmarks/identify_plan_catalogue.py``.

For each of the 27 motors of ``stepdamp_env/bench/catalogue.json`` (public
datasheets, with the v4 protocol's sensors: 0.01 A current noise, 4000-count
encoder) and a prior that is the truth except for its J (x0.6, x1, x1.3), the
plan's three logs are simulated (one sample per PWM period) all in open loop,
all in servo, and in servo except where the plan predicts stick-slip
(``LogPlan.servo_stick_slip``), then identified with that prior. Per case the
worst relative error of Kd1, Kd2, Kd4 and whether ``identify`` warned; the
summary per log set.
"""

from __future__ import annotations

import dataclasses
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from identify_accuracy import record  # noqa: E402

PRIOR_J = (0.6, 1.0, 1.3)
AMPLITUDES = ("Kd1", "Kd2", "Kd4")


def main() -> None:
    from stepdamp_env.bench.protocols.v4 import catalogue_systems, full_protocol_v4
    from stepdamp_env.logfit import identify_from_tables
    from stepdamp_env.logplan import log_plan

    sets = {"open loop (the plan)": [], "servo": [], "servo unless stick-slip": []}
    for truth in catalogue_systems(full_protocol_v4()):
        for ratio in PRIOR_J:
            prior = dataclasses.replace(truth, motor=dataclasses.replace(
                truth.motor, J=truth.motor.J * ratio))
            plan = log_plan(prior)
            modes = {"open loop (the plan)": ["open-loop"] * 3, "servo": ["servo"] * 3,
                     "servo unless stick-slip": ["open-loop" if s else "servo"
                                                 for s in plan.servo_stick_slip]}
            for label, chosen in modes.items():
                tables = [record(truth, v, m, 1 + k, d) for k, (v, d, m) in
                          enumerate(zip(plan.speeds_rps, plan.durations_s, chosen))]
                result = identify_from_tables(prior, tables)
                worst = max(abs(getattr(result.model, a) / getattr(truth.motor, a) - 1.0)
                            for a in AMPLITUDES)
                sets[label].append((truth.name, ratio, worst, bool(result.warnings)))
    print("| logs | identifications | worst of Kd1, Kd2, Kd4: median | largest | > 5 % off "
          "(not warned) | > 10 % off (not warned) |")
    print("|---|---|---|---|---|---|")
    for label, rows in sets.items():
        w = np.array([r[2] for r in rows])
        warned = np.array([r[3] for r in rows])
        print(f"| {label} | {len(rows)} | {100 * np.median(w):.1f} % | {100 * w.max():.1f} % | "
              f"{int((w > 0.05).sum())} ({int(((w > 0.05) & ~warned).sum())}) | "
              f"{int((w > 0.1).sum())} ({int(((w > 0.1) & ~warned).sum())}) |")
    for label, rows in sets.items():
        quiet = [f"{r[0]} x{r[1]:g} {100 * r[2]:.1f} %" for r in rows if r[2] > 0.05 and not r[3]]
        if quiet:
            print(f"{label}: over 5 % without a warning: {', '.join(quiet)}")


if __name__ == "__main__":
    main()
