"""What the damping law's resonant terms add to a per-step agent, on the dev split.

The ``damping-gains`` law has, per detent harmonic h = 1, 2, 4, a resonant term:
a phasor (the amplitude and phase of a harmonic current) that integrates the
velocity error demodulated at h*x, times a complex gain the agent sets. It is a
harmonic feedforward table that adapts on the motor within the run, its
adaptation law scheduled by the policy. This script scores an entry as trained
and with its six resonant gains held at zero (the phasors then stay zero: only
``kv`` and ``kp`` act) on stepdamp-bench v3's dev split (never scored), both
pooled over the entry's training seeds::

    python scripts/resonant_share.py ppo-open-loop-long [--suite open-loop] [--out DIR]

and prints each one's attenuation and the probability that the entry as
trained beats its ablation, with the effect (dB).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

#: The resonant gains' positions in a ``damping-gains`` action
#: (``kv, kp, r1_re, r1_im, r2_re, r2_im, r4_re, r4_im``).
RESONANT = slice(2, 8)


def main(argv: list[str] | None = None) -> int:
    from stepdamp_agents import reference_names, reference_seeds
    from stepdamp_agents.per_step import StepAgent
    from stepdamp_env.bench import run_leaderboard
    from stepdamp_env.bench.protocols import protocol_for
    from stepdamp_env.bench.registry import register_policy

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("entry", help="a committed per-step entry (damping-gains actions)")
    p.add_argument("--suite", default="open-loop", choices=("open-loop", "servo", "mid-band"))
    p.add_argument("--out", default=None, help="also write the dev board here")
    a = p.parse_args(argv)
    if a.entry not in reference_names():
        p.error(f"entry {a.entry!r} is not one of {list(reference_names())}")

    class WithoutResonant(StepAgent):
        def act_batch(self, observations: np.ndarray, rows: np.ndarray) -> np.ndarray:
            actions = np.array(super().act_batch(observations, rows))
            actions[:, RESONANT] = 0.0
            return actions

    ablated = f"{a.entry}-without-resonant"
    seeds = reference_seeds(a.entry)
    makers = {k: (lambda path=path: WithoutResonant(path, name=ablated))
              for k, path in seeds.items()}
    register_policy(ablated, makers[min(makers)], kind="agent", default=False,
                    description=f"{a.entry} with its resonant gains held at zero",
                    training_seeds=makers)
    protocol = protocol_for("v3").with_splits(["dev"]).with_suites([a.suite])
    board = run_leaderboard(protocol, [a.entry, ablated, "tuned-constant-gain"], progress=False)
    if a.out:
        from stepdamp_env.bench.report import write_outputs

        write_outputs(board, a.out, protocol)
    rows = {e["name"]: e for e in board["entries"] if e["suite"] == a.suite}
    print_comparison(rows, a.entry, [ablated, "tuned-constant-gain"], width=40, entry_first=True)
    return 0


def print_comparison(rows: dict[str, Any], entry: str, others: list[str], width: int,
                     entry_first: bool) -> None:
    """Each row's dev attenuation (``entry`` first or last), then ``entry`` against
    each of ``others`` (P(improvement) and the effect in dB), from a v3 board's
    rows by name."""
    for name in dict.fromkeys([entry, *others] if entry_first else [*others, entry]):
        db = rows[name]["attenuation_db"]
        print(f"{name:{width}s} dev {db['iqm']:.2f} dB [{db['ci'][0]:.2f}, {db['ci'][1]:.2f}]  "
              f"success {rows[name]['success_rate']:.2f}")
    e = rows[entry]
    for other in (o for o in dict.fromkeys(others) if o != entry):
        eff = e["effect_db"][other]
        print(f"{entry} against {other}: P {e['probability_of_improvement'][other]:.2f}, "
              f"effect {eff['median']:+.2f} dB [{eff['ci'][0]:+.2f}, {eff['ci'][1]:+.2f}]")


if __name__ == "__main__":
    sys.exit(main())
