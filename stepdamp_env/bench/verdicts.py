"""The facts of one board table (a suite on a split) from its rows alone:
``headroom_db``, ``saturated`` and why, ``bound_check``, ``told_apart`` and
``rank_stability`` (stepdamp-bench v4 on; the rules in docs/protocol_v4.md), and
their text on the board's pages.
``protocol`` is the board's protocol: its ``bound_entry``, paired-rank
settings (``rank_confidence``, ``decisive_share``, ``min_paired_motors``,
``bootstrap_resamples``, ``bootstrap_seed``), ``bound_share_min`` and
``saturation_db``; v5's ``bound_tolerance_db`` and ``saturated_near_reference``
where it has them (v4 has not: its tables stay as published)."""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from .protocol import REFERENCE_POLICY
from .stats import paired_difference

__all__ = ["beats", "saturated", "table_facts", "table_facts_line", "render_table_facts"]


def beats(protocol: Any, a: Mapping[str, Any], b: Mapping[str, Any]) -> bool:
    """The ranks' rule (:func:`..stats.paired_ranks`) for one pair of rows."""
    t = paired_difference(a["per_motor_db"], b["per_motor_db"],
                          confidence=protocol.rank_confidence,
                          resamples=protocol.bootstrap_resamples, seed=protocol.bootstrap_seed)
    p = a.get("probability_of_improvement", {}).get(b["name"], math.nan)
    return t["motors"] >= protocol.min_paired_motors and (
        (t["iqm"] > 0.0 and (t["low"] > 0.0 or t["share"] >= protocol.decisive_share))
        or p >= protocol.decisive_share)


def saturated(protocol: Any, t: Mapping[str, Any]) -> tuple[bool | None, str]:
    """Whether damping has nothing left to win in a table, and why: the bound
    must hold on >= ``bound_share_min`` of the motors (else there is no
    headroom to measure), then less than ``saturation_db`` of headroom, or
    a best entry the paired rule cannot tell from the bound, is saturated."""
    b = t["bound_check"]
    if t["best"] is None or b is None or b["share"] is None:
        return None, "no bound or no ranked entry in this table"
    if b["motors"] < protocol.min_paired_motors:
        return None, (f"{b['motors']} motors: fewer than the {protocol.min_paired_motors} the "
                      "paired rule needs")
    if b["share"] < protocol.bound_share_min:
        return None, (f"the bound is beaten on {b['motors'] - b['holds']} of {b['motors']} "
                      "motors: no headroom is measured against it")
    if "reference_gap_db" in t and t["reference_gap_db"] is None:
        return None, "the reference row has no score"
    gap = t.get("reference_gap_db")
    if gap is not None and gap >= protocol.saturation_db:
        # v5: saturated only near both the bound and the reference.
        if t["headroom_db"] < protocol.saturation_db or not t["told_apart"].get("bound", False):
            return False, (f"headroom {t['headroom_db']:.1f} dB to the bound, but the "
                           f"reference (no phenomenon) is {gap:.1f} dB above the best entry")
    if t["headroom_db"] < protocol.saturation_db:
        return True, f"headroom {t['headroom_db']:.1f} dB < {protocol.saturation_db:g} dB"
    if not t["told_apart"].get("bound", False):
        return True, "the best entry is not told apart from the bound"
    return False, (f"headroom {t['headroom_db']:.1f} dB, the best entry told apart from "
                   "the bound")


def table_facts(protocol: Any, rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The facts of one table (module docstring) from its ranked ``rows``."""
    ranked = [r for r in rows if r.get("rank") is not None]
    contenders = [r for r in ranked if r["spec"] != REFERENCE_POLICY]
    best = min((r for r in contenders if math.isfinite(r["attenuation_db"]["iqm"])),
               key=lambda r: (-r["attenuation_db"]["iqm"], r["name"]), default=None)
    ref = next((r for r in rows if r["reference"]), None)
    bound = next((r for r in rows if r["name"] == protocol.bound_entry), None)
    out: dict[str, Any] = {"cells": rows[0]["cells"], "best": best["name"] if best else None}
    if best is not None and bound is not None:
        out["headroom_db"] = bound["attenuation_db"]["iqm"] - best["attenuation_db"]["iqm"]
    else:
        out["headroom_db"] = None
    if getattr(protocol, "saturated_near_reference", False) and best is not None \
            and ref is not None:
        gap = ref["attenuation_db"]["iqm"] - best["attenuation_db"]["iqm"]
        out["reference_gap_db"] = gap if math.isfinite(gap) else None
    out["told_apart"] = {name: beats(protocol, best, r) or beats(protocol, r, best)
                         for name, r in (("reference", ref), ("bound", bound))
                         if r is not None and best is not None}
    if bound is not None:
        # v5's tolerance (seed noise; 0 in v4).
        out["bound_check"] = _per_motor_check(
            protocol.bound_entry, bound, rows, float(getattr(protocol, "bound_tolerance_db", 0.0)))
        # v5: the privileged laws' own check, kept as information (never the verdict).
        also = [r for r in rows for name in getattr(protocol, "also_checked", ())
                if r["name"] == name]
        if also:
            out["also_checked"] = [_per_motor_check(r["name"], r, rows, 0.0) for r in also]
    else:
        out["bound_check"] = None
    out["saturated"], out["saturated_why"] = saturated(protocol, out)
    seeds = sorted({s for r in ranked for s in r.get("rank_by_seed", {})})
    if seeds and best is not None:
        leader = [r for r in ranked if r["rank"] == 1]
        kept = sum(all(r["rank_by_seed"].get(s) == 1 for r in leader) for s in seeds)
        moves = [abs(r["rank_by_seed"][s] - r["rank"]) for r in ranked for s in seeds
                 if r["rank_by_seed"].get(s) is not None]
        out["rank_stability"] = {"seeds": len(seeds),
                                 "rank_1_kept_on_seeds": kept,
                                 "mean_rank_change": float(np.mean(moves)) if moves else 0.0,
                                 "max_rank_change": int(max(moves)) if moves else 0}
    else:
        out["rank_stability"] = None
    return out


def _per_motor_check(name: str, bound: Mapping[str, Any], rows: Sequence[Mapping[str, Any]],
                     tolerance: float) -> dict[str, Any]:
    """Where no non-privileged row scores above ``bound`` per motor (by more than
    ``tolerance`` dB; those within it are listed apart where it is above 0)."""
    others = [r for r in rows if not (r["reference"] or r["privileged"])]
    beaten, within = [], []
    motors = sorted(bound["per_motor_db"])
    unscored = sorted({m for r in others for m in r["per_motor_db"]} - set(motors))
    for m in motors:
        top = max(((r["per_motor_db"].get(m, -math.inf), r["name"]) for r in others),
                  default=(-math.inf, ""))
        if top[0] > bound["per_motor_db"][m]:
            (beaten if top[0] > bound["per_motor_db"][m] + tolerance else within).append(
                {"motor": m, "by": top[1], "by_db": top[0] - bound["per_motor_db"][m]})
    out = {"entry": name, "motors": len(motors), "holds": len(motors) - len(beaten),
           "share": (1.0 - len(beaten) / len(motors)) if motors else None,
           "beaten_on": beaten, "no_score_on": unscored}
    if tolerance > 0.0:
        out.update(tolerance_db=tolerance, within_tolerance_on=within)
    return out


def table_facts_line(t: Mapping[str, Any]) -> str:
    """One table's facts (v4's ``tables``): cells, headroom, saturation, the
    bound per motor, rank stability over the evaluation seeds."""
    parts = [f"cells scored {t['cells']['scored']} of {t['cells']['split']}"]
    if t.get("headroom_db") is not None and math.isfinite(t["headroom_db"]):
        parts.append(f"headroom {t['headroom_db']:+.1f} dB (bound minus `{t['best']}`)")
    if "saturated" in t:
        word = {True: "saturated", False: "not saturated", None: "saturation unknown"}
        parts.append(f"{word[t['saturated']]} ({t['saturated_why']})")
    b = t.get("bound_check")
    if b:
        worst = max(b["beaten_on"], key=lambda x: x["by_db"], default=None)
        near = b.get("within_tolerance_on", [])
        parts.append(f"bound holds on {b['holds']} of {b['motors']} motors"
                     + (f" (worst: `{worst['by']}` {worst['by_db']:.1f} dB above it on "
                        f"{worst['motor']})" if worst else "")
                     + (f"; on {len(near)} of them an entry is less than "
                        f"{b['tolerance_db']:g} dB above it" if near else ""))
    r = t.get("rank_stability")
    if r:
        parts.append(f"rank 1 kept on {r['rank_1_kept_on_seeds']} of {r['seeds']} seeds, "
                     f"ranks move {r['mean_rank_change']:.2f} on average (at most "
                     f"{r['max_rank_change']})")
    return "Table: " + "; ".join(parts) + "."


def render_table_facts(board: Mapping[str, Any]) -> list[str]:
    """LEADERBOARD.md's table of v4's per-table facts (none before v4)."""
    tables = board.get("tables")
    if not tables:
        return []
    p = board["protocol"]
    # v5: the privileged laws' own per-motor check beside the bound's.
    also = list(dict.fromkeys(a["entry"] for t in tables for a in t.get("also_checked", [])))
    lines = ["| suite, split | best ranked | headroom (dB) | saturated | bound holds "
             "(motors) | " + "".join(f"`{a}` holds | " for a in also)
             + "rank 1 kept (seeds) |", "|---|---|---|---|---|" + "---|" * len(also) + "---|"]
    for t in tables:
        b, r = t.get("bound_check"), t.get("rank_stability")
        checked = {a["entry"]: a for a in t.get("also_checked", [])}
        lines.append(
            f"| {t['suite']}, {t['split']} | {t['best'] or '-'} | "
            + (f"{t['headroom_db']:+.1f}" if t.get("headroom_db") is not None
               and math.isfinite(t["headroom_db"]) else "-") + " | "
            + {True: "yes", False: "no", None: f"unknown: {t.get('saturated_why', '')}"}[
                t.get("saturated")] + " | "
            + (f"{b['holds']}/{b['motors']}" if b else "-") + " | "
            + "".join(f"{checked[a]['holds']}/{checked[a]['motors']} | " if a in checked
                      else "- | " for a in also)
            + (f"{r['rank_1_kept_on_seeds']}/{r['seeds']}" if r else "-") + " |")
    return [f"Per table: headroom = the bound (`{p.get('bound_entry')}`) minus the best "
            f"ranked entry; saturated = less than {p.get('saturation_db')} dB of headroom, or "
            "the best ranked entry not told apart from the bound"
            + (f", and the best ranked entry within {p.get('saturation_db')} dB of the "
               "`reference` row" if p.get("saturated_near_reference") else "")
            + " (unknown where the bound "
            f"holds on fewer than {p.get('bound_share_min', 0.95):.0%} of the motors); the "
            "bound holds on a motor where no non-privileged "
            "entry scores above it" + (
                f" by more than {p['bound_tolerance_db']:g} dB" if p.get("bound_tolerance_db")
                else "") + "; rank 1 kept = seeds on which every rank-1 entry is "
            "rank 1 again.", "", *lines, ""]
