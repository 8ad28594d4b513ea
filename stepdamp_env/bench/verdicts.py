"""The facts of one board table (a suite on a split) from its rows alone:
``headroom_db``, ``saturated`` and why, ``bound_check``, ``told_apart`` and
``rank_stability`` (stepdamp-bench v4 on; the rules in docs/protocol_v4.md).
``protocol`` is the board's protocol: its ``bound_entry``, paired-rank
settings (``rank_confidence``, ``decisive_share``, ``min_paired_motors``,
``bootstrap_resamples``, ``bootstrap_seed``), ``bound_share_min`` and
``saturation_db``."""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from .protocol import REFERENCE_POLICY
from .stats import paired_difference

__all__ = ["beats", "saturated", "table_facts"]


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
    out["told_apart"] = {name: beats(protocol, best, r) or beats(protocol, r, best)
                         for name, r in (("reference", ref), ("bound", bound))
                         if r is not None and best is not None}
    if bound is not None:
        others = [r for r in rows if not (r["reference"] or r["privileged"])]
        beaten = []
        motors = sorted(bound["per_motor_db"])
        unscored = sorted({m for r in others for m in r["per_motor_db"]} - set(motors))
        for m in motors:
            top = max(((r["per_motor_db"].get(m, -math.inf), r["name"]) for r in others),
                      default=(-math.inf, ""))
            if top[0] > bound["per_motor_db"][m]:
                beaten.append({"motor": m, "by": top[1],
                               "by_db": top[0] - bound["per_motor_db"][m]})
        out["bound_check"] = {"entry": protocol.bound_entry, "motors": len(motors),
                              "holds": len(motors) - len(beaten),
                              "share": (1.0 - len(beaten) / len(motors)) if motors else None,
                              "beaten_on": beaten, "no_score_on": unscored}
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
