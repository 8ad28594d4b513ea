"""Write the result tables of README.md and docs/results.md from the committed
boards (``docs/results/v5``: v5, the default, and ``docs/results/v4``: v4, their
scores without the runs file; ``docs/results/v3``: v3; ``docs/results``: v1; ``docs/results/v0``: v0),
between their markers ``<!-- results:begin -->`` / ``<!-- results:end -->``
(and ``results-v5:``, ``results-v4:``, ``results-v3:``, ``results-v0:``).
Never typed by hand: ``tests/test_readme.py`` checks them with ``--check``.

    python scripts/readme_table.py [--check]
"""

from __future__ import annotations

import argparse
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# file -> (marker name, board directory) pairs
TARGETS = {
    "README.md": (("results", "docs/results/v5"), ("summary", "docs/results/v5"),
                  ("caption", "docs/results/v5")),
    "docs/results.md": (("results-v5", "docs/results/v5"), ("results-v4", "docs/results/v4"),
                        ("results-v3", "docs/results/v3"),
                        ("results", "docs/results"), ("results-v0", "docs/results/v0")),
}


#: Boards committed without their runs file (over the repository's 5 MB): read
#: as scores only, even where a run wrote the file back beside them.
SCORES_ONLY = ("docs/results/v5", "docs/results/v4")
#: How the README names each version's bound.
BOUND_TEXT = {"plant-bound": "`plant-bound` (privileged: the true plant)",
              "board-envelope": "`board-envelope` (privileged: per cell, the best of the "
                                "board's laws, `plant-bound` and `none` included, chosen on "
                                "the other evaluation seeds)"}


def _load(board_dir: str) -> dict:
    """A committed board (its scores only if in :data:`SCORES_ONLY`)."""
    from stepdamp_env.bench.report import load_leaderboard

    return load_leaderboard(os.path.join(ROOT, board_dir), runs=board_dir not in SCORES_ONLY)


def rendered(board_dir: str) -> str:
    from stepdamp_env.bench.report import render_ladder

    return render_ladder(_load(board_dir)).strip()


def _cell(e: dict | None) -> str:
    if e is None:
        return "-"
    rank = "zero-shot" if e.get("zero_shot") else e.get("rank")
    return f"`{e['name']}` {e['attenuation_db']['iqm']:.1f}" + (f" ({rank})" if rank else "")


def tables(board_dir: str) -> str:
    """v4's README table: per suite and split the reference, the best classical
    and the best learned rows (rank in parentheses), the bound, the headroom and
    where the bound holds (the board's ``tables``)."""
    board = _load(board_dir)
    out = ["| suite, split | reference | best classical (rank) | best learned (rank) "
           "| bound | headroom | bound holds | rank 1 |",
           "|---|---|---|---|---|---|---|---|"]
    for t in board["tables"]:
        rows = _rows(board, t["suite"], t["split"])
        ref = next(e for e in rows if e.get("reference"))
        bound = next((e for e in rows if e["spec"] == t["bound_check"]["entry"]), None) \
            if t.get("bound_check") else None
        firsts = sum(e.get("rank") == 1 for e in rows)
        ranked = sum(e.get("rank") is not None for e in rows)
        bc = t["bound_check"]
        out.append(f"| {t['suite']}, {t['split']} | {ref['attenuation_db']['iqm']:.1f} "
                   f"| {_cell(_best(rows, learned=False))} "
                   f"| {_cell(_best(rows, learned=True, ranked_only=False))} "
                   + (f"| {bound['attenuation_db']['iqm']:.1f} | " if bound else "| - | ")
                   + (f"{t['headroom_db']:+.1f} dB" if t["headroom_db"] is not None else "-")
                   + (f" | {bc['holds']}/{bc['motors']}" if bc else " | -")
                   + f" | {firsts} of {ranked} |")
    p = board["protocol"]
    return (f"{p['name']} {p['version']} ({p['variant']}): attenuation of the velocity ripple "
            "at the headline speeds against no damping, dB (higher is better), IQM over "
            "motors; `reference`: the same motors without the phenomenon; bound: "
            + BOUND_TEXT.get(p["bound_entry"], f"`{p['bound_entry']}`")
            + "; headroom: the bound minus the best "
            "ranked row; rank 1: the rows sharing it of the ranked rows ("
            + p["rank_rule"] + "); `zero-shot`: a learned entry outside its training (unranked)"
            "\n\n" + "\n".join(out))


def _rows(board: dict, suite: str, split: str) -> list[dict]:
    return [e for e in board["entries"] if e["suite"] == suite and e.get("split") == split]


def _db(e: dict) -> str:
    a = e["attenuation_db"]
    return f"{a['iqm']:.1f} dB [{a['ci'][0]:.1f}, {a['ci'][1]:.1f}]"


def _versus(a: dict, b: dict) -> str:
    """The effect of ``a`` over ``b`` (median over motors [interval]) and the
    board's P(a better than b)."""
    eff = a["effect_db"][b["name"]]
    return (f"{eff['median']:+.1f} dB [{eff['ci'][0]:+.1f}, {eff['ci'][1]:+.1f}], "
            f"P(better) {a['probability_of_improvement'][b['name']]:.2f}")


def _best(rows: list[dict], learned: bool, ranked_only: bool = True) -> dict | None:
    """The best row by attenuation among learned (or classical: not learned, not
    privileged, not the reference, not `none`) entries; ranked rows only, unless
    none of the kind is ranked."""
    kind = [e for e in rows if bool(e.get("learned")) == learned and not e.get("reference")
            and not e.get("privileged") and e["spec"] != "none"]
    ranked = [e for e in kind if e.get("rank") is not None]
    pool = ranked or ([] if ranked_only else kind)
    return max(pool, key=lambda e: e["attenuation_db"]["iqm"]) if pool else None


def summary(board_dir: str) -> str:
    """The README's short reading of the board, per suite: the reference, the best
    classical and the best learned entry (effect and P(better) between them, on
    each split), the patent's feedforward and the runs `none` loses."""
    board = _load(board_dir)
    out = []
    for suite in board["protocol"]["suites"]:
        parts = []
        for split in ("interpolation", "extrapolation", "catalogue"):
            rows = _rows(board, suite, split)
            if not rows:
                continue
            ref = next(e for e in rows if e.get("reference"))
            classical = _best(rows, learned=False)
            learned = _best(rows, learned=True, ranked_only=False)
            none = next(e for e in rows if e["spec"] == "none")
            text = f"*{split}*: best classical `{classical['name']}` {_db(classical)}"
            if learned is not None:
                how = "" if learned.get("rank") is not None else " (zero-shot: outside its training)"
                text += (f"; best learned `{learned['name']}`{how} {_db(learned)}, "
                         f"{_versus(learned, classical)}")
            if split == "interpolation":
                patent = next((e for e in rows if e["spec"] == "patent-ff-identified"), None)
                text += (f"; `reference` (no phenomenon) {ref['attenuation_db']['iqm']:.1f} dB"
                         + (f"; the patent's feedforward {patent['attenuation_db']['iqm']:.1f} dB"
                            if patent else ""))
            lost = 1.0 - none["success_rate"]
            if lost > 0:
                text += f"; `none` loses {lost:.0%} of its runs"
            parts.append(text)
        out.append(f"* **{suite}.** " + ". ".join(parts) + ".")
    return "\n".join(out)


def caption(board_dir: str) -> str:
    """The overview figure's numbers: the patent's feedforward and the best
    entry in open loop on the interpolation motors."""
    board = _load(board_dir)
    rows = _rows(board, "open-loop", "interpolation")
    patent = next(e for e in rows if e["spec"] == "patent-ff-identified")
    best = max((e for e in rows if e.get("rank") is not None and e["spec"] != "none"),
               key=lambda e: e["attenuation_db"]["iqm"])
    p = patent["attenuation_db"]["iqm"]
    return (f"The patent's feedforward with an identified model attenuates them by {p:.1f} dB "
            f"over the interpolation motors (about {1 - 10 ** (-p / 20):.0%} less ripple), "
            f"and the entry with the highest IQM, `{best['name']}`, by "
            f"{best['attenuation_db']['iqm']:.1f} dB.")


def updated(text: str, marker: str, table: str) -> str:
    """``text`` with the block between the marker pair replaced by ``table``."""
    pattern = re.compile(rf"(<!-- {re.escape(marker)}:begin -->\n).*?(<!-- {re.escape(marker)}:end -->)",
                         re.S)
    if not pattern.search(text):
        raise SystemExit(f"readme_table: no <!-- {marker}:begin/end --> pair")
    return pattern.sub(lambda m: m.group(1) + "\n" + table + "\n\n" + m.group(2), text)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--check", action="store_true", help="exit 1 if a file is stale")
    args = p.parse_args(argv)
    stale = []
    for name, pairs in TARGETS.items():
        path = os.path.join(ROOT, name)
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
        new = text
        render = {"summary": summary, "caption": caption,
                  **({"results": tables} if name == "README.md" else {})}
        for marker, board in pairs:
            new = updated(new, marker, render.get(marker, rendered)(board))
        if new != text:
            stale.append(name)
            if not args.check:
                tmp = path + ".tmp"
                with open(tmp, "w", encoding="utf-8") as fh:
                    fh.write(new)
                os.replace(tmp, path)
    if args.check and stale:
        print(f"stale: {', '.join(stale)} (run python scripts/readme_table.py)", file=sys.stderr)
        return 1
    print(("stale: " if args.check else "wrote: ") + (", ".join(stale) or "nothing"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
