"""Scores of a policy's runs against the reference runs, and a leaderboard entry."""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from .protocol import FAILURE_RATIO, Protocol
from .stats import cell_summary, probability_of_improvement, summary

__all__ = ["reference_index", "score_runs", "make_entry", "make_entry_v1",
           "add_probability_of_improvement", "db_row_fields", "SCORE_KEYS"]

# The per-(motor, seed) scores summarised in an entry, headline first.
SCORE_KEYS = ("headline", "sweep_mean_ratio", "sweep_worst_ratio", "rms_injected_current_a")


def reference_index(runs: Sequence[Mapping[str, Any]]) -> dict[tuple, Mapping[str, Any]]:
    """The reference runs by (motor, seed, speed_rps), as :func:`score_runs` wants them."""
    return {(r["motor"], r["seed"], r["speed_rps"]): r for r in runs}


def score_runs(runs: Sequence[Mapping[str, Any]], reference: Mapping[tuple, Mapping[str, Any]],
               failure_ratio: float = FAILURE_RATIO, failed_reference_counts: bool = False
               ) -> list[dict[str, Any]]:
    """Per-cell scores of one entry against the reference runs; a cell is a
    (motor, seed) pair, and a training seed too where runs carry one.

    ``headline``: mean ripple at the headline speeds (labels other than "off")
    over the reference's; ``sweep_mean_ratio`` / ``sweep_worst_ratio``: mean and
    maximum of the per-speed ratios; a failed run counts with
    ``failure_ratio`` times the reference's ripple (its own if larger). v0: a
    reference run that lost steps or ended before its window leaves the speed
    out. v1 (``failed_reference_counts``): a reference that lost steps is taken
    as measured; where it ended before its window, the mean of its measured
    headline speeds stands in, so every run is scored.
    """
    groups: dict[tuple[str, int, Any], list[Mapping[str, Any]]] = {}
    for r in runs:
        groups.setdefault((r["motor"], r["seed"], r.get("training_seed")), []).append(r)
    out = []
    for (motor, seed, training_seed), rs in groups.items():
        ratios, res_p, res_n, currents = [], [], [], []
        stand_in = _stand_in(rs, reference, motor, seed) if failed_reference_counts else math.nan
        for r in rs:
            ref = reference.get((motor, seed, r["speed_rps"]))
            ok_ref = ref is not None and ref["metrics"] is not None and \
                (failed_reference_counts or not ref["failed"])
            ref_rms = ref["metrics"]["rms_velocity_error_rad_s"] if ok_ref else stand_in
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
        cell: dict[str, Any] = {"motor": motor, "seed": seed}
        if training_seed is not None:
            cell["training_seed"] = training_seed
        out.append({
            **cell,
            "headline": float(pn[both].mean() / nn[both].mean()) if both.any() else math.nan,
            "sweep_mean_ratio": float(fin.mean()) if fin.size else math.nan,
            "sweep_worst_ratio": float(fin.max()) if fin.size else math.nan,
            "rms_injected_current_a": float(np.mean(currents)) if currents else math.nan,
            "step_losses": int(sum(r["failed"] for r in rs)),
            "runs": len(rs)})
    return out


def _stand_in(rs: Sequence[Mapping[str, Any]], reference: Mapping[tuple, Mapping[str, Any]],
              motor: str, seed: int) -> float:
    """v1: the undamped ripple that stands in where the reference run ended before
    its window: the mean of the reference's measured headline speeds (NaN if none)."""
    measured = [ref["metrics"]["rms_velocity_error_rad_s"] for r in rs
                if r["speed_label"] != "off"
                for ref in [reference.get((motor, seed, r["speed_rps"]))]
                if ref is not None and ref["metrics"] is not None]
    return float(np.mean(measured)) if measured else math.nan


def make_entry(name: str, spec: str, suite: str, runs: list[dict[str, Any]],
               reference: Mapping[tuple, Mapping[str, Any]], protocol: Protocol,
               meta: Mapping[str, Any]) -> dict[str, Any]:
    """One leaderboard entry: summaries over motors and seeds, per-motor means, raw data."""
    scores = score_runs(runs, reference, protocol.failure_ratio)
    strata = [s["motor"] for s in scores]
    entry: dict[str, Any] = {"name": name, "spec": spec, "suite": suite, **meta}
    return _summarise(entry, scores, runs, lambda values: summary(
        values, strata, resamples=protocol.bootstrap_resamples, seed=protocol.bootstrap_seed,
        confidence=protocol.confidence))


def _summarise(entry: dict[str, Any], scores: list[dict[str, Any]], runs: list[dict[str, Any]],
               summarise: Any) -> dict[str, Any]:
    """Fill an entry: ``summarise(values)`` of every score key, the worst ratio's
    maximum, step losses, per-motor headline means and the raw data."""
    for key in SCORE_KEYS:
        entry[key] = summarise([s[key] for s in scores])
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


def make_entry_v1(name: str, spec: str, suite: str, split: str, runs: list[dict[str, Any]],
                  reference: Mapping[tuple, Mapping[str, Any]], protocol: Any,
                  strata: Mapping[str, str], meta: Mapping[str, Any]) -> dict[str, Any]:
    """One stepdamp-bench v1 entry (one split, one suite): summaries over the
    (motor, seed, training seed) cells with the two-level interval (``strata``:
    motor -> stratum), per-motor means, raw data."""
    scores = score_runs(runs, reference, protocol.failure_ratio, failed_reference_counts=True)
    motors = [s["motor"] for s in scores]
    seeds = sorted({s["training_seed"] for s in scores if "training_seed" in s})
    entry: dict[str, Any] = {"name": name, "spec": spec, "suite": suite, "split": split,
                             **meta, "training_seeds": seeds}
    return _summarise(entry, scores, runs, lambda values: cell_summary(
        values, motors, strata, resamples=protocol.bootstrap_resamples,
        seed=protocol.bootstrap_seed, confidence=protocol.confidence))


def add_probability_of_improvement(entries: Sequence[dict[str, Any]], protocol: Any,
                                   strata: Mapping[str, str]) -> None:
    """For every ordered pair of entries (one split and suite): P(row improves on
    other), lower headline better, into ``probability_of_improvement`` and
    ``probability_of_improvement_ci95`` keyed by the other entry's name."""
    cells = {e["name"]: ([s["headline"] for s in e["scores"]],
                         [s["motor"] for s in e["scores"]]) for e in entries}
    for e in entries:
        e["probability_of_improvement"] = {}
        e["probability_of_improvement_ci95"] = {}
    # P(Y < X) = 1 - P(X < Y) in every resample (ties count half): computed once a pair.
    for i, e in enumerate(entries):
        for other in entries[i + 1:]:
            x, y = cells[e["name"]], cells[other["name"]]
            keep_x = [i for i, v in enumerate(x[0]) if math.isfinite(v)]
            keep_y = [i for i, v in enumerate(y[0]) if math.isfinite(v)]
            res = probability_of_improvement(
                [x[0][i] for i in keep_x], [x[1][i] for i in keep_x],
                [y[0][i] for i in keep_y], [y[1][i] for i in keep_y], strata=strata,
                resamples=protocol.bootstrap_resamples, seed=protocol.bootstrap_seed,
                confidence=protocol.confidence)
            e["probability_of_improvement"][other["name"]] = res["p"]
            e["probability_of_improvement_ci95"][other["name"]] = res["ci95"]
            other["probability_of_improvement"][e["name"]] = 1.0 - res["p"]
            other["probability_of_improvement_ci95"][e["name"]] = [1.0 - res["ci95"][1],
                                                                   1.0 - res["ci95"][0]]


def db_row_fields(runs: Sequence[Mapping[str, Any]], keys: Sequence[tuple[str, Any]],
                  cell_db: Sequence[float], run_ratios: Sequence[float],
                  ratio: Mapping[str, Any], motor_db: Mapping[str, float],
                  ratio_of_db: Any) -> dict[str, Any]:
    """The fields a row scored in dB (v3 on) has beside its attenuation:
    success, full sweep, per-motor dB, the ratio headline, step losses, the
    cell scores and the runs. ``keys``: (motor, training seed) per cell."""
    lost = sum(bool(r["failed"]) for r in runs)
    fin = [v for v in run_ratios if math.isfinite(v)]
    return {
        "success_rate": 1.0 - lost / len(runs) if runs else math.nan,
        "full_sweep": {"mean": float(np.mean(fin)) if fin else math.nan,
                       "worst": float(np.max(fin)) if fin else math.nan},
        "per_motor_db": dict(motor_db),
        # What the plots and v1-style readers use: the ratio, lower better.
        "headline": {"iqm": ratio["iqm"], "ci95": ratio["ci"], "n": len(cell_db)},
        "step_losses": {"runs_lost": lost, "runs": len(runs)},
        "scores": [{"motor": k[0], **({"training_seed": k[1]} if k[1] is not None else {}),
                    "attenuation_db": v, "headline": ratio_of_db(v)}
                   for k, v in zip(keys, cell_db)],
        "runs": list(runs)}
