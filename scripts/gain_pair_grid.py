"""The best constant pair (kv, kp) of the damping law on the dev split: how strong
a classical reference tuned where the agents are selected would be.

``tuned-constant-gain`` is one constant ``kv`` (0.5) picked on training motors.
This script runs ``tuned-gain-pair`` (StepperDamp-v1's damping law on
``ff-delay-comp``) at every constant pair of a grid (``kv`` the velocity gain, ``kp`` the high-passed
position gain; the resonant gains 0) on stepdamp-bench v3's dev split of one
suite, and prints each pair's attenuation; then the best pair against an entry::

    python scripts/gain_pair_grid.py [--entry ppo-open-loop-long] [--suite open-loop] \
        [--kv 0.3 0.4 ...] [--kp -0.4 -0.2 ...]

The best pair is scored on the split it was picked on, so its figure is
optimistic: an upper bound of what the tuned pair would score there.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

#: The open-loop grid of docs/results/ablations/gain_pair_grid.txt.
KV = (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
KP = (-1.0, -0.8, -0.7, -0.6, -0.5, -0.4, -0.2, 0.0, 0.2, 0.4)


def named(policy: Any, name: str) -> Any:
    """``policy`` under another name (one grid point)."""
    policy.name = name
    return policy


def main(argv: list[str] | None = None) -> int:
    from resonant_share import print_comparison  # scripts/, beside this file
    from stepdamp_baselines import TunedGainPair
    from stepdamp_env.bench import run_leaderboard
    from stepdamp_env.bench.protocols import protocol_for
    from stepdamp_env.bench.registry import register_policy

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--entry", default="ppo-open-loop-long")
    p.add_argument("--suite", default="open-loop", choices=("open-loop", "servo", "mid-band"))
    p.add_argument("--kv", type=float, nargs="+", default=KV, help="velocity gains, in [-1, 1]")
    p.add_argument("--kp", type=float, nargs="+", default=KP, help="position gains, in [-1, 1]")
    a = p.parse_args(argv)
    for flag, values in (("--kv", a.kv), ("--kp", a.kp)):
        if not all(-1.0 <= v <= 1.0 for v in values):
            p.error(f"{flag} {list(values)}: each gain must lie in [-1, 1]")

    names = []
    for kv in a.kv:
        for kp in a.kp:
            name = f"gain-pair-kv{kv:g}-kp{kp:g}"
            register_policy(name, (lambda kv=kv, kp=kp: named(TunedGainPair({a.suite: (kv, kp)}),
                                                              f"gain-pair-kv{kv:g}-kp{kp:g}")),
                            default=False, description=f"damping law at kv={kv}, kp={kp}")
            names.append(name)
    protocol = protocol_for("v3").with_splits(["dev"]).with_suites([a.suite])
    board = run_leaderboard(protocol, [*names, a.entry, "tuned-constant-gain"], progress=False)
    rows = {e["name"]: e for e in board["entries"] if e["suite"] == a.suite}
    print("dev attenuation IQM (dB), kv down, kp across:")
    print("kv \\ kp " + "".join(f"{kp:>8g}" for kp in a.kp))
    for kv in a.kv:
        print(f"{kv:<8g}" + "".join(f"{rows[f'gain-pair-kv{kv:g}-kp{kp:g}']['attenuation_db']['iqm']:8.2f}"
                                    for kp in a.kp))
    best = max(names, key=lambda n: rows[n]["attenuation_db"]["iqm"])
    print_comparison(rows, a.entry, [best, "tuned-constant-gain"], width=28, entry_first=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
