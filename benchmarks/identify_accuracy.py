"""How well the torque balance identifies the detent model from drive logs, and
whether its stated uncertainty says so (docs/drivelogs.md, "Accuracy").

Run: ``PYTHONPATH=. python benchmarks/identify_accuracy.py [--seeds 2]``.

Logs are simulated (one sample per PWM period, current-sensor noise 0.01 A
where the motor has none) on the four presets and ``docs/motors/17hs4401.json``
(a catalogue motor), in servo and open loop, with a prior that is the truth
except for its J, 20 % high by default (``--prior-j``; below 1 a prior that
misses a load's inertia):

* ``plan``: the three logs ``stepdamp identify --plan`` asks for;
* ``single``: one log at each of five speeds from 0.2 x f4 to the motor's top
  speed (the bridge limit), as a user might log (J is then the prior's);
* ``fast``: two logs at 1.2 and 2.4 x f4, above the resonance, where J is
  fitted and trades against the harmonics.

Per case it prints the error of Kd1, Kd2, Kd4 against the truth, the stated
relative uncertainty, and whether the identification warned. The summary
counts the cases whose worst error exceeds 5 % (and 10 %) without a warning.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
AMPLITUDES = ("Kd1", "Kd2", "Kd4")


def motors():
    from stepdamp_env.motorfile import load_system
    from stepdamp_env.presets import preset_names

    names = list(preset_names()) + [os.path.join(ROOT, "docs", "motors", "17hs4401.json")]
    return [load_system(n) for n in names]


def record(system, speed_rps, mode, seed, duration_s):
    """One simulated drive log (the table ``identify --log`` reads)."""
    from stepdamp_env.drivelog import trace_table
    from stepdamp_env.simulation import RunSettings, SpeedProfile, simulate

    result = simulate(system, profile=SpeedProfile(speed_rps=speed_rps),
                      settings=RunSettings(mode=mode, noise_seed=seed),
                      duration_s=duration_s, trace=True)
    return trace_table(result)


def case(truth, prior, speeds, mode, seed, durations):
    from stepdamp_env.logfit import MAX_UNCERTAINTY, identify_from_tables

    tables = [record(truth, v, mode, seed * 7 + k, d)
              for k, (v, d) in enumerate(zip(speeds, durations))]
    result = identify_from_tables(prior, tables)
    errors = {n: getattr(result.model, n) / getattr(truth.motor, n) - 1.0 for n in AMPLITUDES}
    stated = {n: result.relative_uncertainty(n) for n in AMPLITUDES}
    # Warned of its accuracy: a stated uncertainty above 5 %, or a warning that
    # the harmonics hang on J (one speed, or J fitted above the resonance).
    stated_high = any(not stated[n] <= MAX_UNCERTAINTY for n in AMPLITUDES)
    warned = stated_high or any(w.startswith(("J fitted from logs above", "the logs hold one"))
                                for w in result.warnings)
    return errors, stated, (stated_high, warned), result


def main() -> int:
    sys.path.insert(0, ROOT)
    from stepdamp_env.analysis import bridge_limit_rps
    from stepdamp_env.logplan import log_plan

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2, help="noise seeds per case")
    parser.add_argument("--prior-j", type=float, default=1.2,
                        help="the prior's J over the truth's")
    args = parser.parse_args()
    rows = []
    for truth in motors():
        if truth.drive.current_noise_a == 0.0:
            truth = truth.replace(current_noise_a=0.01)
        prior = truth.replace(J=args.prior_j * truth.motor.J)
        plan = log_plan(prior)
        f4 = truth.predicted_resonances_rps()[4]
        top = bridge_limit_rps(truth)
        nr = truth.motor.Nr
        cases = [("plan", plan.speeds_rps, plan.durations_s)]
        cases += [(f"single {v / f4:.2f} f4", (v,), (0.1 + max(1.0, 40.0 / (nr * v)),))
                  for v in np.geomspace(0.2 * f4, top, 5)]
        cases += [("fast 1.2+2.4 f4", (1.2 * f4, 2.4 * f4), (1.2, 1.2))]
        for mode in ("servo", "open-loop"):
            for label, speeds, durations in cases:
                for seed in range(args.seeds):
                    errors, stated, (high, warned), result = case(truth, prior, speeds, mode,
                                                                  seed, durations)
                    worst = max(abs(e) for e in errors.values())
                    j_error = result.J / truth.motor.J - 1.0
                    rows.append((truth.name, mode, label, seed, worst, warned, j_error, high))
                    print(f"{truth.name:20s} {mode:9s} {label:16s} seed {seed}: "
                          + "  ".join(f"{n} {errors[n]:+7.1%} (+-{stated[n]:5.1%})"
                                      for n in AMPLITUDES)
                          + f"  J {j_error:+6.1%}" + ("" if "J" in result.fitted else " (prior)")
                          + ("  warned" if warned else ""), flush=True)
    print()
    for kind in ("plan", "single", "fast"):
        sel = [r for r in rows if r[2].startswith(kind)]
        within = sum(r[4] <= 0.05 for r in sel)
        silent5 = sum(r[4] > 0.05 and not r[5] for r in sel)
        silent10 = sum(r[4] > 0.10 and not r[5] for r in sel)
        unstated = sum(r[4] > 0.05 and not r[7] for r in sel)
        worst_plan = max(r[4] for r in sel)
        print(f"{kind:6s}: {len(sel)} identifications; worst error within 5 % in {within}; "
              f"warned in {sum(r[5] for r in sel)} (a stated uncertainty above 5 % in "
              f"{sum(r[7] for r in sel)}); over 5 % without a warning {silent5}, over 10 % "
              f"without a warning {silent10}; over 5 % with every stated uncertainty under 5 % "
              f"{unstated}; largest error {worst_plan:.1%}")
        if kind in ("plan", "fast"):
            print(f"        J from the logs: {min(r[6] for r in sel):+.1%} to "
                  f"{max(r[6] for r in sel):+.1%} of the truth")
    return 0


if __name__ == "__main__":
    sys.exit(main())
