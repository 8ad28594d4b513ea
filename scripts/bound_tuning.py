"""Choose privileged-bound's settings (added damping ratio, decision rate) per suite
on stepdamp-bench v3's dev split, never on a scored motor.

For every candidate (zeta_add, agent_hz, feedforward) the script runs the dev split's board
(``ProtocolV3`` with ``splits=("dev",)``) and prints each candidate's IQM
attenuation (dB) per suite; per suite, the candidate whose interval has the
highest lower end goes into
``stepdamp_baselines.feedback.PRIVILEGED_SETTINGS``.

Run: ``python scripts/bound_tuning.py [--quick]``
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

from stepdamp_baselines.feedback import PrivilegedBound
from stepdamp_env.bench import run_leaderboard
from stepdamp_env.bench.protocols.v3 import full_protocol_v3, quick_protocol_v3

ZETAS = (0.0, 0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0)
RATES = (1000.0, 5000.0)
FEEDFORWARDS = ("delay-comp", "patent", "none")
HERE = os.path.abspath(__file__)


def candidate(zeta: float, hz: float, ff: str) -> PrivilegedBound:
    p = PrivilegedBound({suite: (zeta, hz, ff) for suite in ("open-loop", "servo", "mid-band")})
    p.name = f"bound-z{zeta:g}-{hz:g}hz-{ff}"
    return p


def _factory_name(zeta: float, hz: float, ff: str) -> str:
    return f"cand_z{zeta:g}_{hz:g}_{ff}".replace(".", "p").replace("-", "_")


for _z in ZETAS:        # one zero-argument factory per candidate: a policy spec each
    for _hz in RATES:
        for _ff in FEEDFORWARDS:
            globals()[_factory_name(_z, _hz, _ff)] = \
                (lambda z=_z, hz=_hz, ff=_ff: candidate(z, hz, ff))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="v3's quick settings on the dev split")
    p.add_argument("--workers", type=int, default=None)
    args = p.parse_args(argv)
    base = quick_protocol_v3() if args.quick else full_protocol_v3()
    protocol = dataclasses.replace(base, splits=("dev",))
    specs = [f"{HERE}:{_factory_name(z, hz, ff)}" for z in ZETAS for hz in RATES
             for ff in FEEDFORWARDS]
    board = run_leaderboard(protocol, specs, progress=False, workers=args.workers)
    for suite in protocol.suites:
        rows = sorted((e for e in board["entries"] if e["suite"] == suite
                       and e["name"].startswith("bound")),
                      key=lambda e: -e["attenuation_db"]["ci"][0])
        print(f"{suite} (dev, {sum(m['split'] == 'dev' for m in board['protocol']['motors'])} "
              "motors): IQM attenuation dB [interval] (by its lower end), gap closed, success")
        for e in rows:
            a = e["attenuation_db"]
            print(f"  {e['name']:24s} {a['iqm']:6.2f} [{a['ci'][0]:.2f}, {a['ci'][1]:.2f}]  "
                  f"gap {e['gap_closed']['iqm']:.3f}  success {e['success_rate']:.2f}")
    print(f"wall {board['wall_seconds']:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
