"""Scores of a policy's runs against the reference runs, and a leaderboard entry."""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from .protocol import FAILURE_RATIO, Protocol
from .stats import summary

__all__ = ["reference_index", "score_runs", "make_entry", "SCORE_KEYS"]

# The per-(motor, seed) scores summarised in an entry, headline first.
SCORE_KEYS = ("headline", "sweep_mean_ratio", "sweep_worst_ratio", "rms_injected_current_a")


def reference_index(runs: Sequence[Mapping[str, Any]]) -> dict[tuple, Mapping[str, Any]]:
    """The reference runs by (motor, seed, speed_rps), as :func:`score_runs` wants them."""
    return {(r["motor"], r["seed"], r["speed_rps"]): r for r in runs}


def score_runs(runs: Sequence[Mapping[str, Any]], reference: Mapping[tuple, Mapping[str, Any]],
               failure_ratio: float = FAILURE_RATIO) -> list[dict[str, Any]]:
    """Per (motor, seed) scores of one entry against the reference runs.

    ``headline``: mean ripple at the resonant speeds (labels other than "off")
    over the reference's; ``sweep_mean_ratio`` / ``sweep_worst_ratio``: mean and
    maximum of the per-speed ratios; a failed run counts with
    ``failure_ratio`` times the reference's ripple (its own if larger).
    """
    groups: dict[tuple[str, int], list[Mapping[str, Any]]] = {}
    for r in runs:
        groups.setdefault((r["motor"], r["seed"]), []).append(r)
    out = []
    for (motor, seed), rs in groups.items():
        ratios, res_p, res_n, currents = [], [], [], []
        for r in rs:
            ref = reference.get((motor, seed, r["speed_rps"]))
            ok_ref = ref is not None and not ref["failed"] and ref["metrics"] is not None
            ref_rms = ref["metrics"]["rms_velocity_error_rad_s"] if ok_ref else math.nan
            own = r["metrics"]["rms_velocity_error_rad_s"] if r["metrics"] else math.nan
            if r["failed"]:
                own = max(own, failure_ratio * ref_rms) if math.isfinite(own) \
                    else failure_ratio * ref_rms
            ratios.append(own / ref_rms)
            if r["speed_label"] != "off":
                res_p.append(own)
                res_n.append(ref_rms)
            if r["metrics"]:
                currents.append(r["metrics"]["rms_injected_current_a"])
        ratios_a = np.asarray(ratios)
        fin = ratios_a[np.isfinite(ratios_a)]
        pn, nn = np.asarray(res_p, dtype=float), np.asarray(res_n, dtype=float)
        both = np.isfinite(pn) & np.isfinite(nn)
        out.append({
            "motor": motor, "seed": seed,
            "headline": float(pn[both].mean() / nn[both].mean()) if both.any() else math.nan,
            "sweep_mean_ratio": float(fin.mean()) if fin.size else math.nan,
            "sweep_worst_ratio": float(fin.max()) if fin.size else math.nan,
            "rms_injected_current_a": float(np.mean(currents)) if currents else math.nan,
            "step_losses": int(sum(r["failed"] for r in rs)),
            "runs": len(rs)})
    return out


def make_entry(name: str, spec: str, suite: str, runs: list[dict[str, Any]],
               reference: Mapping[tuple, Mapping[str, Any]], protocol: Protocol,
               meta: Mapping[str, Any]) -> dict[str, Any]:
    """One leaderboard entry: summaries over motors and seeds, per-motor means, raw data."""
    scores = score_runs(runs, reference, protocol.failure_ratio)
    strata = [s["motor"] for s in scores]
    entry: dict[str, Any] = {"name": name, "spec": spec, "suite": suite, **meta}
    for key in SCORE_KEYS:
        entry[key] = summary([s[key] for s in scores], strata,
                             resamples=protocol.bootstrap_resamples,
                             seed=protocol.bootstrap_seed, confidence=protocol.confidence)
    entry["sweep_worst_ratio"]["max"] = float(np.nanmax([s["sweep_worst_ratio"]
                                                         for s in scores]))
    entry["step_losses"] = {"runs_lost": int(sum(r["failed"] for r in runs)),
                            "runs": len(runs)}
    per_motor: dict[str, list[float]] = {}
    for s in scores:
        per_motor.setdefault(s["motor"], []).append(s["headline"])
    entry["per_motor_headline_mean"] = {k: float(np.mean(v)) for k, v in per_motor.items()}
    entry["scores"] = scores
    entry["runs"] = runs
    return entry
