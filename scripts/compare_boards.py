"""What changed between two leaderboards of one protocol: numbers, ranks, claims.

    python scripts/compare_boards.py OLD_DIR NEW_DIR [--markdown]

Per (suite, split): the largest relative change of any entry's headline IQM and
of its interval ends; every rank that moved; every probability of improvement
that crossed 0.5 (a claim "A beats B" that flipped). The re-baseline of 0.10.0
(CHANGELOG) quotes its output for v0, v1 and v2.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from stepdamp_env.bench.report import load_leaderboard  # noqa: E402


def _rel(a: float, b: float) -> float:
    if a == b or (math.isnan(a) and math.isnan(b)):
        return 0.0
    if not (math.isfinite(a) and math.isfinite(b)) or a == 0.0:
        return math.inf
    return abs(b - a) / abs(a)


def compare(old: dict, new: dict) -> dict:
    key = lambda e: (e["name"], e["suite"], e.get("split", ""))  # noqa: E731
    a = {key(e): e for e in old["entries"]}
    b = {key(e): e for e in new["entries"]}
    out = {"largest": {}, "ranks": [], "flips": [], "missing": sorted(set(a) ^ set(b))}
    for k in sorted(set(a) & set(b)):
        ea, eb = a[k], b[k]
        group = k[1:]
        changes = [(_rel(ea["headline"]["iqm"], eb["headline"]["iqm"]), k[0], "IQM",
                    ea["headline"]["iqm"], eb["headline"]["iqm"])]
        for i, end in enumerate(("low", "high")):
            changes.append((_rel(ea["headline"]["ci95"][i], eb["headline"]["ci95"][i]), k[0],
                            f"CI {end}", ea["headline"]["ci95"][i], eb["headline"]["ci95"][i]))
        best = max(changes)
        if best[0] > out["largest"].get(group, (-1.0,))[0]:
            out["largest"][group] = best
        if ea.get("rank") != eb.get("rank"):
            out["ranks"].append((group, k[0], ea.get("rank"), eb.get("rank")))
        pa, pb = ea.get("probability_of_improvement", {}), eb.get("probability_of_improvement", {})
        for other in sorted(set(pa) & set(pb)):
            va = pa[other]["p"] if isinstance(pa[other], dict) else pa[other]
            vb = pb[other]["p"] if isinstance(pb[other], dict) else pb[other]
            if (va - 0.5) * (vb - 0.5) < 0 or ((va == 0.5) != (vb == 0.5)):
                out["flips"].append((group, k[0], other, va, vb))
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("old")
    p.add_argument("new")
    args = p.parse_args()
    old, new = load_leaderboard(args.old), load_leaderboard(args.new)
    c = compare(old, new)
    print(f"{old['protocol']['version']}: {len(new['entries'])} entries")
    for group, (rel, name, what, va, vb) in sorted(c["largest"].items()):
        print(f"  {' / '.join(x for x in group if x):32s} largest change {rel:.2e} "
              f"({name}, {what}: {va!r} -> {vb!r})")
    for group, name, ra, rb in c["ranks"]:
        print(f"  rank moved: {' / '.join(x for x in group if x)}: {name} {ra} -> {rb}")
    for group, name, other, va, vb in c["flips"]:
        print(f"  P({name} beats {other}) crossed 0.5 in {' / '.join(x for x in group if x)}: "
              f"{va:.3f} -> {vb:.3f}")
    if not c["ranks"] and not c["flips"]:
        print("  no rank moved; no probability of improvement crossed 0.5")
    if c["missing"]:
        print(f"  entries in one board only: {c['missing']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
