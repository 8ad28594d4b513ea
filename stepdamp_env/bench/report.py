"""The leaderboard's report: leaderboard.json (compact), its runs (compressed),
LEADERBOARD.md and the figures, written atomically into one directory.

``leaderboard.json`` holds the protocol, versions, identification and every
entry's summaries; each entry's per-cell ``scores`` and raw ``runs`` are in
``leaderboard_runs.json.xz`` (:data:`RUNS_FILE`; boards written before 0.13.0:
``leaderboard_runs.json.gz``, named by their ``runs_file``);
:func:`load_leaderboard` joins them again. Every figure draws each policy with
the same colour and marker (:func:`policy_styles`).
"""

from __future__ import annotations

import gzip
import json
import lzma
import math
import os
from typing import Any, Mapping, Sequence

import numpy as np

from .. import kernel as K
from ..io import atomic_path, read_json, write_json, write_text
from ..params import FeedforwardModel, ParameterError
from ..plots import (POLICY_COLOURS, POLICY_MARKERS, finish_ripple_axes, legend_outside,
                     mark_resonances, pyplot, save_figure)
from .motors import ProtocolMotor, protocol_motors
from .leaderboard import protocol_knowledge
from .policy import MotorKnowledge
from .protocol import REFERENCE_POLICY, SUITE_MODE, Protocol
from .protocols import protocol_class
from .provenance import board_fingerprint
from .registry import default_policy_names, resolve_policy
from .runner import episode_window, run_episode

__all__ = ["RESULT_FILES", "RUNS_FILE", "GZIP_RUNS_FILE", "open_runs_file", "format_summary", "render_markdown", "render_results",
           "render_ladder", "render_suite_page", "suite_page", "row_notes", "best_eligible", "scored_in_db",
           "highlighted_rows", "entry_knowledge", "entry_rows", "render_per_motor", "has_splits", "splits",
           "plot_performance_profile",
           "load_leaderboard", "verify_fingerprint", "policy_styles", "plot_ripple", "plot_overview",
           "plot_resonance_traces", "trace_run", "write_outputs"]

#: The runs file: xz at preset 1 (the full v3 board's runs, 27 MB of JSON: 3.8 MB
#: in 0.8 s; gzip -9 made 5.4 MB). Boards before 0.13.0 wrote gzip.
RUNS_FILE = "leaderboard_runs.json.xz"
GZIP_RUNS_FILE = "leaderboard_runs.json.gz"
#: What a leaderboard run writes (glob patterns): replaced as a set, never mixed.
RESULT_FILES = ("leaderboard.json", RUNS_FILE, GZIP_RUNS_FILE, "LEADERBOARD.md",
                "LEADERBOARD_*.md", "overview.png",
                "performance_profile.png",
                "ripple_vs_speed_*.png", "velocity_error_resonances_*.png")
_RAW_KEYS = ("scores", "runs")


def format_summary(s: Mapping[str, Any]) -> str:
    """``IQM [low, high]`` to four significant digits; the IQM alone where the
    interval has no width (one run per motor, as in ``--quick``): there is none."""
    lo, hi = s["ci95"]
    if not lo < hi:
        return f"{s['iqm']:#.4g} (no interval)"
    return f"{s['iqm']:#.4g} [{lo:#.4g}, {hi:#.4g}]"


def format_db(s: Mapping[str, Any]) -> str:
    """``IQM [low, high]`` of a v3 score (``attenuation_db``, ``gap_closed``, ``ratio``)."""
    lo, hi = s["ci"]
    if not lo < hi:
        return f"{s['iqm']:.3g} (no interval)"
    return f"{s['iqm']:.3g} [{lo:.3g}, {hi:.3g}]"


def scored_in_db(board: Mapping[str, Any]) -> bool:
    """Whether the board's rows are v3's (attenuation in dB, reference rows)."""
    return any("attenuation_db" in e for e in board["entries"])


def row_rank(e: Mapping[str, Any]) -> str:
    """A row's rank column: its rank, or why it has none (v3)."""
    if e.get("rank") is not None:
        return str(e["rank"])
    if e.get("reference"):
        return "ref"
    return "zero-shot" if e.get("zero_shot") else "privileged" if e.get("privileged") else "-"


def row_notes(e: Mapping[str, Any]) -> list[str]:
    """Why a v3 row's score needs reading with care: it lost every run, it has
    no score, or it is privileged and still worse than no damping."""
    if "attenuation_db" not in e or e.get("reference"):
        return []
    notes = []
    att = e["attenuation_db"]["iqm"]
    sl = e["step_losses"]
    if sl["runs"] and sl["runs_lost"] == sl["runs"]:
        notes.append("loses every run: the rotor falls behind the command at every speed "
                     "of this suite on these motors, with or without this entry's help")
    elif not math.isfinite(att):
        notes.append("no score: `none` lost every headline run on these motors, so there "
                     "is no undamped ripple to attenuate (a stalled rotor does not resonate)")
    errors = [r["error"] for r in e.get("runs", []) if r.get("error")]
    if errors:
        notes.append(f"could not run in {len(errors)} of {sl['runs']} runs, each counted as "
                     f"lost (first: {errors[0]})")
    if e.get("privileged") and math.isfinite(att) and att < 0.0:
        notes.append("privileged, yet worse than no damping: the exact model or true state "
                     "does not make this law right for this motor and suite (a privileged "
                     "row shows what that knowledge buys its law; it is no floor)")
    return notes


def best_eligible(rows: Sequence[Mapping[str, Any]], skip: Sequence[str] = ()
                  ) -> Mapping[str, Any] | None:
    """The best-ranked row a drive can use: ranked (not the reference, not
    privileged, not zero-shot), not ``none``, not in ``skip``."""
    ranked = [e for e in rows if e.get("rank") is not None and not e.get("oracle")
              and not e.get("reference") and e["spec"] != REFERENCE_POLICY
              and e["spec"] not in skip]
    return min(ranked, key=lambda e: e["rank"]) if ranked else None


def score_label(e: Mapping[str, Any]) -> str:
    """A row's headline for a figure's legend: v3's attenuation, else the ratio."""
    if "attenuation_db" in e:
        return f"{e['attenuation_db']['iqm']:.1f} dB"
    return f"headline {e['headline']['iqm']:.3g}"


def entry_line(e: Mapping[str, Any]) -> str:
    """One console line of a row."""
    sl = e["step_losses"]
    if "attenuation_db" in e:
        notes = "".join(f"\n             note: {n}" for n in row_notes(e))
        return (f"{row_rank(e):>9s}. {e['name']:28s} {format_db(e['attenuation_db']):26s} dB, "
                f"gap closed {format_db(e['gap_closed']):24s} success {e['success_rate']:.2f}"
                + notes)
    return (f"{e['rank']:2d}. {e['name']:28s} headline IQM {format_summary(e['headline']):32s} "
            f"step losses {sl['runs_lost']}/{sl['runs']}")


def has_splits(board: Mapping[str, Any]) -> bool:
    """Whether the board's entries are per split of its motors (v1 and later)."""
    return "splits" in board["protocol"]


def splits(board: Mapping[str, Any]) -> list[str | None]:
    """The board's splits in protocol order ([None] for a protocol without splits)."""
    return list(board["protocol"]["splits"]) if has_splits(board) else [None]


def render_markdown(board: Mapping[str, Any]) -> str:
    """``LEADERBOARD.md``: one ranked table per suite (v1: per split and suite,
    with the probability of improvement of every pair)."""
    if scored_in_db(board):
        return _render_summary_db(board)
    if has_splits(board):
        return _render_markdown_by_split(board)
    p = board["protocol"]
    lines = [f"# Leaderboard: {p['name']} {p['version']} ({p['variant']})", "",
             f"{len(p['motors'])} motors x {len(p['eval_seeds'])} seeds; "
             f"window {p['window_s']} s, ramp {p['accel_rps2']} rev/s^2, current noise "
             f"{p['current_noise_a']} A, encoder {p['encoder_cpr']} counts/rev.",
             "Headline: mean RMS velocity ripple at the three resonant speeds over that of "
             "`none` (lower is better); IQM over motors x seeds with a 95 % stratified "
             "bootstrap interval. `oracle` entries use what no drive can know (the plant's "
             "exact model or true states). Knowledge: what each entry senses while it runs, "
             "the motor model it uses, what it calibrates before the run (simulated rig time "
             "per run, not scored).", ""]
    for suite in p["suites"]:
        rows = sorted((e for e in board["entries"] if e["suite"] == suite),
                      key=lambda e: e["rank"])
        lines += [f"## {suite}", "",
                  "| rank | policy | headline IQM [95 % CI] | sweep mean ratio | "
                  "sweep worst (IQM / max) | step losses | RMS injected current (A) | "
                  "knowledge |",
                  "|---|---|---|---|---|---|---|---|"]
        for e in rows:
            name = e["name"] + (" (oracle)" if e.get("oracle") else "")
            sw = e["sweep_worst_ratio"]
            sl = e["step_losses"]
            lines.append(f"| {e['rank']} | {name} | {format_summary(e['headline'])} | "
                         f"{format_summary(e['sweep_mean_ratio'])} | "
                         f"{sw['iqm']:.4g} / {sw['max']:.4g} | {sl['runs_lost']}/{sl['runs']} | "
                         f"{e['rms_injected_current_a']['iqm']:.4g} | {entry_knowledge(e)} |")
        lines.append("")
        lines += _not_run(board, suite)
    return _with_versions(board, lines)


def _not_run(board: Mapping[str, Any], suite: str) -> list[str]:
    """LEADERBOARD.md's lines on the entries that do not run in ``suite``."""
    out: list[str] = []
    for x in board.get("not_run", []):
        if x["suite"] == suite:
            out += [f"Not run in {suite}: `{x['name']}` ({x['reason']}).", ""]
    return out


def _with_versions(board: Mapping[str, Any], lines: list[str]) -> str:
    v = board["versions"]
    return "\n".join(lines + ["Versions: " + ", ".join(f"{k} {val}" for k, val in v.items())]
                     ) + "\n"


def _render_markdown_by_split(board: Mapping[str, Any]) -> str:
    p = board["protocol"]
    fewest = protocol_class(p["version"]).min_training_seeds
    counts = {sp: sum(m.get("split") == sp for m in p["motors"]) for sp in p["splits"]}
    lines = [f"# Leaderboard: {p['name']} {p['version']} ({p['variant']})", "",
             "Motors per split: " + ", ".join(f"{sp} {n}" for sp, n in counts.items())
             + f"; evaluation seeds {', '.join(str(k) for k in p['eval_seeds'])}; learned "
             "entries pool their training "
             f"seeds. Wall time {board.get('wall_seconds', math.nan):.0f} s, simulated "
             f"{board.get('simulated_seconds', math.nan):.0f} s.",
             "Headline: mean RMS velocity ripple at the suite's headline speeds (open loop: "
             "the three resonances; servo: the low-speed grid) over that of `none` (lower is "
             "better); IQM over (motor, evaluation seed, training seed) cells with a 95 % "
             "two-level stratified bootstrap interval (motors, then cells). P(better) "
             "columns: probability of improvement over that entry, per motor over every "
             "pair of cells, with its interval. `oracle` entries use what no drive can know.",
             ""]
    for suite in p["suites"]:
        for split in p["splits"]:
            rows = entry_rows(board, suite, split)
            if not rows:
                continue
            refs = [n for n in ("ff-delay-comp", REFERENCE_POLICY)
                    if any(e["name"] == n for e in rows)]
            lines += [f"## {suite}, {split}", "",
                      "| rank | policy | headline IQM [95 % CI] | "
                      + "".join(f"P(better than {r}) | " for r in refs)
                      + "step losses | training seeds | knowledge |",
                      "|---|---|---|" + "---|" * len(refs) + "---|---|---|"]
            for e in rows:
                name = e["name"] + (" (oracle)" if e.get("oracle") else "")
                poi = "".join(
                    (f"{e['probability_of_improvement'][r]:.2f} "
                     f"[{e['probability_of_improvement_ci95'][r][0]:.2f}, "
                     f"{e['probability_of_improvement_ci95'][r][1]:.2f}] | ")
                    if r != e["name"] else "- | " for r in refs)
                sl = e["step_losses"]
                seeds = ", ".join(str(k) for k in e.get("training_seeds", [])) or "-"
                if e.get("learned") and len(e.get("training_seeds", [])) < fewest:
                    seeds += f" (fewer than {fewest}: no claim)"
                lines.append(f"| {e['rank']} | {name} | {format_summary(e['headline'])} | "
                             f"{poi}{sl['runs_lost']}/{sl['runs']} | {seeds} | "
                             f"{entry_knowledge(e)} |")
            lines += ["", f"Probability of improvement, {suite}, {split} (row better than "
                      "column):", "",
                      "| | " + " | ".join(e["name"] for e in rows) + " |",
                      "|---|" + "---|" * len(rows)]
            for e in rows:
                cells = ["-" if o is e else f"{e['probability_of_improvement'][o['name']]:.2f}"
                         for o in rows]
                lines.append(f"| {e['name']} | " + " | ".join(cells) + " |")
            lines.append("")
            if split == "custom":
                lines += [render_per_motor(board, suite, split)]
        lines += _not_run(board, suite)
    return _with_versions(board, lines)


def suite_page(suite: str) -> str:
    """The file of a v3 board's full table of one suite."""
    return f"LEADERBOARD_{suite}.md"


def _db_header(board: Mapping[str, Any]) -> list[str]:
    """A v3 page's title and its line on motors, seeds and time."""
    p = board["protocol"]
    counts = {sp: sum(m.get("split") == sp for m in p["motors"]) for sp in p["splits"]}
    return [f"# Leaderboard: {p['name']} {p['version']} ({p['variant']})", "",
            "Motors per split: " + ", ".join(f"{sp} {n}" for sp, n in counts.items())
            + f"; evaluation seeds {', '.join(str(k) for k in p['eval_seeds'])}. Wall time "
            f"{board.get('wall_seconds', math.nan):.0f} s, simulated "
            f"{board.get('simulated_seconds', math.nan):.0f} s."]


def _render_summary_db(board: Mapping[str, Any]) -> str:
    """v3's LEADERBOARD.md: per suite and split the reference, the three best
    ranked entries and the patent's feedforward, with links to the suite pages."""
    p = board["protocol"]
    lines = _db_header(board) + ["",
             "Attenuation of the velocity ripple at the suite's headline speeds against no "
             "damping, dB (higher is better), IQM over motors [95 % interval]; `reference`: "
             "the same motors without the phenomenon. Rank 1 may be shared (overlapping "
             "intervals). Every entry, P(improvement), effect sizes, success and knowledge: "
             + ", ".join(f"[{suite}]({suite_page(suite)})" for suite in p["suites"]) + ".", "",
             "| suite, split | reference | 1st | 2nd | 3rd | patent-ff-identified |",
             "|---|---|---|---|---|---|"]
    notes = 0
    for suite in p["suites"]:
        for split in p["splits"]:
            rows = entry_rows(board, suite, split)
            if not rows:
                continue
            notes += sum(bool(row_notes(e)) for e in rows)
            ref = next((e for e in rows if e.get("reference")), None)
            ranked = sorted((e for e in rows if e.get("rank") is not None
                             and e["spec"] != REFERENCE_POLICY),
                            key=lambda e: (e["rank"], -e["attenuation_db"]["iqm"]))[:3]
            patent = next((e for e in rows if e["spec"] == PATENT_ENTRY), None)

            def cell(e: Mapping[str, Any] | None, name: bool = True) -> str:
                if e is None:
                    return "-"
                db = e["attenuation_db"]["iqm"]
                return (f"`{e['name']}` " if name else "") + \
                    (f"{db:.1f} ({e['rank']})" if e.get("rank") is not None else f"{db:.1f}")

            lines.append(f"| [{suite}]({suite_page(suite)}), {split} | {cell(ref, False)} | "
                         + " | ".join(cell(e) for e in ranked + [None] * (3 - len(ranked)))
                         + f" | {cell(patent, False)} |")
    lines.append("")
    if notes:
        lines += [f"{notes} rows carry a note (a lost suite, no score, or a privileged entry "
                  "worse than no damping): see the suite pages.", ""]
    return _with_versions(board, lines)


def render_suite_page(board: Mapping[str, Any], suite: str) -> str:
    """A v3 board's full table of one suite (:func:`suite_page`)."""
    return _render_markdown_db(board, suites=(suite,))


def _render_markdown_db(board: Mapping[str, Any], suites: Sequence[str] | None = None) -> str:
    p = board["protocol"]
    lines = _db_header(board) + [
             "Attenuation: 20 log10(ripple of `none` / ripple of the entry) at the suite's "
             "headline speeds, per motor (mean over speeds, seeds, training seeds), IQM over "
             "motors [95 % interval] (higher is better; 0 dB = no damping; a lost run "
             f"{p.get('failure_db', -20):g} dB). Gap closed: attenuation / the `reference` "
             "row's (the same motors without the phenomenon: 1 = as good as removing it). "
             "Ratio: ripple over `none`'s. Full sweep: mean / worst ratio over every speed. "
             "Rank: entries whose intervals overlap share a rank; `ref`, `privileged` "
             "(true state or exact model; `privileged-bound` is the bound) and `zero-shot` "
             "(a learned entry outside its training coverage) rows are unranked. Effect: median over motors "
             "of the difference in dB against the best ranked entry, with its interval.", ""]
    for suite in suites or p["suites"]:
        for split in p["splits"]:
            rows = entry_rows(board, suite, split)
            if not rows:
                continue
            best = next((e for e in rows if e.get("rank") == 1), None)
            lines += [f"## {suite}, {split}", "",
                      "| rank | entry | attenuation (dB) | gap closed | ratio | success | "
                      "full sweep mean / worst | effect vs "
                      f"{best['name'] if best else '-'} (dB) | P(better than it) | "
                      "training seeds | knowledge |",
                      "|---|---|---|---|---|---|---|---|---|---|---|"]
            for e in rows:
                fs = e["full_sweep"]
                eff = e.get("effect_db", {}).get(best["name"]) if best and e is not best \
                    else None
                poi = e.get("probability_of_improvement", {}).get(best["name"]) \
                    if best and e is not best else None
                seeds = ", ".join(str(k) for k in e.get("training_seeds", [])) or "-"
                effect = (f"{eff['median']:+.2f} [{eff['ci'][0]:+.2f}, {eff['ci'][1]:+.2f}]"
                          if eff else "-")
                know = ("policy none on the motor without the phenomenon"
                        if e.get("reference") else entry_knowledge(e))
                lines.append(
                    f"| {row_rank(e)} | {e['name']} | {format_db(e['attenuation_db'])} | "
                    f"{format_db(e['gap_closed'])} | {format_db(e['ratio'])} | "
                    f"{e['success_rate']:.2f} | {fs['mean']:.3g} / {fs['worst']:.3g} | "
                    f"{effect} | {'-' if poi is None else f'{poi:.2f}'} | {seeds} | {know} |")
            lines.append("")
            for e in rows:
                lines += [f"Note on `{e['name']}`: {n}." for n in row_notes(e)]
            if any(row_notes(e) for e in rows):
                lines.append("")
        lines += _not_run(board, suite)
    return _with_versions(board, lines)


def render_per_motor(board: Mapping[str, Any], suite: str, split: str) -> str:
    """Per motor, the entries ranked by their mean headline on it (the custom
    split's answer to "which damping is best on my motor?"; v3: by attenuation)."""
    rows = entry_rows(board, suite, split)
    motors = [m["name"] for m in board["protocol"]["motors"] if m.get("split") == split]
    in_db = scored_in_db(board)
    what = ("attenuation in dB, mean over its speeds; higher is better" if in_db else
            "mean headline over its cells; lower is better")
    lines = [f"Per motor, {suite}, {split} ({what}):",
             "", "| motor | " + " | ".join(f"#{k}" for k in range(1, len(rows) + 1)) + " |",
             "|---|" + "---|" * len(rows)]
    for motor in motors:
        if in_db:
            ranked = sorted((-e["per_motor_db"][motor], e["name"]) for e in rows
                            if motor in e["per_motor_db"])
            lines.append(f"| {motor} | " + " | ".join(f"{n} {-v:.3g}" for v, n in ranked)
                         + " |")
            continue
        ranked = sorted((e["per_motor_headline_mean"][motor], e["name"]) for e in rows
                        if motor in e["per_motor_headline_mean"])
        lines.append(f"| {motor} | " + " | ".join(f"{n} {v:.4g}" for v, n in ranked) + " |")
    return "\n".join(lines) + "\n"


def entry_rows(board: Mapping[str, Any], suite: str, split: str | None = None
               ) -> list[Mapping[str, Any]]:
    """One table's entries by rank: a suite (and, on a v1 board, a split)."""
    return sorted((e for e in board["entries"] if e["suite"] == suite
                   and e.get("split") == split), key=_row_order)


def _row_order(e: Mapping[str, Any]) -> tuple:
    if "attenuation_db" not in e:
        return (e["rank"],)
    db = e["attenuation_db"]["iqm"]
    return (not e.get("reference"), e.get("rank") is None, e.get("rank") or 0,
            -db if math.isfinite(db) else math.inf, e["name"])


def entry_knowledge(e: Mapping[str, Any]) -> str:
    """An entry's knowledge column: its card's line, else what its env options say."""
    text = e.get("knowledge")
    if not text:
        opts = e.get("env_options", {})
        model = opts.get("estimate", "exact") if opts.get("base_controller") != "none" else "none"
        text = f"sensors: encoder, currents (observation); model: {model}"
        if e.get("oracle"):
            text += "; oracle"
    calib = [r.get("calibration_s", 0.0) for r in e.get("runs", [])]
    if calib and max(calib) > 0:
        text += f" ({float(np.mean(calib)):.3g} s per run)"
    return text


def render_ladder(board: Mapping[str, Any]) -> str:
    """The README's table of the whole ladder: every entry's headline in each suite
    beside its knowledge, ranked by the first suite."""
    p = board["protocol"]
    columns = [(suite, split) for suite in p["suites"] for split in splits(board)]
    by = {(e["name"], e["suite"], e.get("split")): e for e in board["entries"]}
    if scored_in_db(board):
        return _ladder_db(board, columns, by)
    names = [e["name"] for e in entry_rows(board, *columns[0])]
    names += sorted({e["name"] for e in board["entries"]} - set(names))
    if has_splits(board):
        title = (f"{p['name']} {p['version']} ({p['variant']}): mean RMS ripple at the "
                 "headline speeds over undamped, IQM [95 % CI] over motor x seed x "
                 "training-seed cells, two-level bootstrap (lower is better)")
        heads = [f"{suite}, {split}" for suite, split in columns]
    else:
        title = (f"{p['name']} {p['version']} ({p['variant']}): mean RMS ripple at the "
                 "resonances over undamped, IQM [95 % CI] over motors x seeds (lower is better)")
        heads = [suite for suite, _ in columns]
    lines = [title, "", "| policy | " + " | ".join(heads) + " | knowledge |",
             "|---|" + "---|" * len(heads) + "---|"]
    for name in names:
        cells, know = [], ""
        for key in columns:
            e = by.get((name, *key))
            cells.append(format_summary(e["headline"]) if e else "not run")
            know = know or (entry_knowledge(e) if e else "")
        oracle = any(by[(name, *k)].get("oracle") for k in columns if (name, *k) in by)
        lines.append(f"| {name}{' (oracle)' if oracle else ''} | " + " | ".join(cells)
                     + f" | {know} |")
    return "\n".join(lines) + "\n"


def _ladder_db(board: Mapping[str, Any], columns: list[tuple[str, Any]],
               by: Mapping[tuple, Mapping[str, Any]]) -> str:
    """v3's ladder: attenuation (dB) per suite and split, the reference row first."""
    p = board["protocol"]
    names = [e["name"] for e in entry_rows(board, *columns[0])]
    names += sorted({e["name"] for e in board["entries"]} - set(names))
    title = (f"{p['name']} {p['version']} ({p['variant']}): attenuation of the velocity ripple "
             "at the headline speeds against no damping, dB (higher is better), IQM over "
             "motors [95 % interval]; rank in parentheses (shared where intervals overlap), "
             "`ref`: the same motors without the phenomenon, `privileged`: true state or "
             "exact model, "
             "`zero-shot`: a learned entry outside its training coverage (unranked)")
    heads = [f"{suite}, {split}" for suite, split in columns]
    lines = [title, "", "| entry | " + " | ".join(heads) + " | knowledge |",
             "|---|" + "---|" * len(heads) + "---|"]
    for name in names:
        cells, know = [], ""
        for key in columns:
            e = by.get((name, *key))
            cells.append(f"{format_db(e['attenuation_db'])} ({row_rank(e)})" if e
                         else "not run")
            if e and not know:
                know = ("policy none on the motor without the phenomenon" if e.get("reference")
                        else entry_knowledge(e))
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {know} |")
    return "\n".join(lines) + "\n"


def render_results(board: Mapping[str, Any], suite: str = "open-loop") -> str:
    """A compact Markdown table of one suite (for a README; v1: one per split):
    rank, policy, headline IQM and interval, step losses."""
    p = board["protocol"]
    if has_splits(board):
        return "\n".join(_results_table(board, suite, split) for split in p["splits"])
    return _results_table(board, suite, None)


def _results_table(board: Mapping[str, Any], suite: str, split: str | None) -> str:
    rows = entry_rows(board, suite, split)
    p = board["protocol"]
    where = suite if split is None else f"{suite}, {split}"
    speeds = "resonances" if split is None else "headline speeds"
    lines = [f"{p['name']} {p['version']} ({p['variant']}), {where}: mean RMS ripple at the "
             f"{speeds} over undamped (IQM [95 % CI], lower is better)", "",
             "| rank | policy | headline | step losses |", "|---|---|---|---|"]
    for e in rows:
        name = e["name"] + (" (oracle)" if e.get("oracle") else "")
        sl = e["step_losses"]
        lines.append(f"| {e['rank']} | {name} | {format_summary(e['headline'])} | "
                     f"{sl['runs_lost']}/{sl['runs']} |")
    return "\n".join(lines) + "\n"


def open_runs_file(path: str | os.PathLike[str]) -> Any:
    """A runs file opened for reading as text: xz, or gzip (boards before 0.13.0)."""
    opener = lzma.open if os.fspath(path).endswith(".xz") else gzip.open
    return opener(path, "rt", encoding="utf-8")


def load_leaderboard(directory: str | os.PathLike[str]) -> dict[str, Any]:
    """The board as :func:`~.leaderboard.run_leaderboard` returned it, read from
    ``leaderboard.json`` and its runs file."""
    board = read_json(os.path.join(directory, "leaderboard.json"), "board")
    protocol = board.get("protocol") if isinstance(board, dict) else None
    if not (isinstance(board, dict) and isinstance(board.get("entries"), list)
            and all(isinstance(e, dict) for e in board["entries"])
            and isinstance(protocol, dict) and isinstance(protocol.get("motors"), list)
            and protocol["motors"] and all(isinstance(m, dict) for m in protocol["motors"])):
        raise ParameterError(f"board {os.path.join(directory, 'leaderboard.json')!r} is not a "
                             "leaderboard (it needs a list of entries and a protocol with its "
                             "motors)")
    runs_file = board.get("runs_file", GZIP_RUNS_FILE)
    if not isinstance(runs_file, str) or os.path.basename(runs_file) != runs_file:
        raise ParameterError(f"board {directory!r}: runs_file must be a file name beside it, "
                             f"got {runs_file!r}")
    path = os.path.join(directory, runs_file)
    raw = read_json(path, "runs file", opener=lzma.open if path.endswith(".xz") else gzip.open)
    try:
        by_key = {(r["name"], r["suite"], r.get("split")): r for r in raw["entries"]}
        for e in board["entries"]:
            for key in _RAW_KEYS:
                e[key] = by_key[(e["name"], e["suite"], e.get("split"))][key]
    except (KeyError, TypeError, AttributeError) as exc:
        raise ParameterError(f"board {directory!r}: its runs file does not hold the board's "
                             f"entries ({type(exc).__name__}: {exc})") from None
    board.pop("runs_file", None)
    return board


def verify_fingerprint(board: Mapping[str, Any], directory: str) -> None:
    """A one-line ``ParameterError`` if a board read back does not match the
    fingerprint it was written with (an edited or damaged file); boards written
    before fingerprints are taken as they are."""
    kept = board.get("fingerprint")
    if kept is None:
        raise ParameterError(f"board {directory!r} records no fingerprint, so its numbers "
                             "cannot be checked (an edited board, or one of an early version); "
                             "--no-verify to show it anyway")
    if board_fingerprint(board) != kept:
        raise ParameterError(f"board {directory!r}: its numbers do not match its fingerprint "
                             f"{str(kept)[:16]}... (leaderboard.json or its runs file was edited "
                             "or damaged); run the board again, or --no-verify to show it anyway")


def _representative(board: Mapping[str, Any]) -> tuple[str, int]:
    p = board["protocol"]
    return p["motors"][0]["name"], p["eval_seeds"][0]


def policy_styles(names: Sequence[str]) -> dict[str, tuple[str, str]]:
    """(colour, marker) per policy name, the same in every figure: registered
    default policies in registry order first, then the others sorted; ``none``
    is always black circles."""
    order = [n for n in default_policy_names() if n != REFERENCE_POLICY]
    order += sorted(set(names) - set(order) - {REFERENCE_POLICY})
    styles = {REFERENCE_POLICY: ("black", "o")}
    for k, name in enumerate(order):
        styles[name] = (POLICY_COLOURS[k % len(POLICY_COLOURS)],
                        POLICY_MARKERS[(k + k // len(POLICY_COLOURS)) % len(POLICY_MARKERS)])
    return styles


def _suite_rows(board: Mapping[str, Any], suite: str) -> list[Mapping[str, Any]]:
    """The suite's entries by rank, of the representative motor's split (v1)."""
    return [e for e in entry_rows(board, suite, board["protocol"]["motors"][0].get("split"))
            if not e.get("reference")]


def _first_model(runs: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """A learned entry's runs of its first training seed (all runs otherwise)."""
    seeds = sorted({r["training_seed"] for r in runs if "training_seed" in r})
    return [r for r in runs if r.get("training_seed") == (seeds[0] if seeds else None)]


#: Entries a ripple figure highlights at most (the reference line included).
HIGHLIGHTED = 6


def highlighted_rows(rows: Sequence[Mapping[str, Any]], reference: bool
                     ) -> list[Mapping[str, Any]]:
    """The rows a ripple figure draws in colour: ``none``, the patent's
    feedforward, then the best eligible entries, at most :data:`HIGHLIGHTED`
    lines with the reference's (if ``reference``)."""
    room = HIGHLIGHTED - int(reference)
    shown = [e for e in rows if e["spec"] in (REFERENCE_POLICY, PATENT_ENTRY)]
    shown += [e for e in sorted((e for e in rows if e.get("rank") is not None
                                 and not e.get("oracle") and e not in shown),
                                key=lambda e: e["rank"])][:max(room - len(shown), 0)]
    return shown[:room]


def plot_ripple(board: Mapping[str, Any], suite: str, path: str) -> None:
    """RMS ripple against speed for the representative motor and seed (a learned
    entry: its first training seed's model): ``none``, the patent's feedforward
    and the best eligible entries in colour (:func:`highlighted_rows`), every
    other entry as a thin grey line. Markers shrink with rank so that equal
    curves stay visible. Resonances are marked in open loop only (the servo loop
    has no peak there)."""
    plt = pyplot()
    motor, seed = _representative(board)
    info = board["protocol"]["motors"][0]
    rows = _suite_rows(board, suite)
    split = board["protocol"]["motors"][0].get("split")
    refs = [e for e in entry_rows(board, suite, split) if e.get("reference")]
    shown = highlighted_rows(rows, reference=bool(refs))
    styles = policy_styles([e["name"] for e in rows])
    fig, ax = plt.subplots(figsize=(9, 4.8))

    def curve(e: Mapping[str, Any]) -> tuple[list[float], list[float]]:
        rs = sorted((r for r in _first_model(e["runs"]) if r["motor"] == motor
                     and r["seed"] == seed and r["metrics"] is not None),
                    key=lambda r: r["speed_rps"])
        return ([r["speed_rps"] for r in rs],
                [r["metrics"]["rms_velocity_error_rad_s"] for r in rs])

    others = [e for e in rows if e not in shown]
    where = suite_page(suite) if scored_in_db(board) else "LEADERBOARD.md"
    for k, e in enumerate(others):
        ax.semilogy(*curve(e), color="0.75", lw=0.7, zorder=1,
                    label=f"{len(others)} other entries ({where})" if k == 0 else None)
    n = len(shown)
    shown.sort(key=lambda e: rows.index(e))
    for k, e in enumerate(shown):
        colour, marker = styles[e["name"]]
        ax.semilogy(*curve(e), color=colour, marker=marker, ms=4 + 1.2 * k, mfc="none",
                    lw=1.0, zorder=3 + n - k, label=f"{row_rank(e)}. {e['name']}")
    for e in refs:                                # v3: the motor without the phenomenon
        if e.get("reference"):
            rs = sorted((r for r in e["runs"] if r["motor"] == motor and r["seed"] == seed
                         and r["metrics"] is not None), key=lambda r: r["speed_rps"])
            ax.semilogy([r["speed_rps"] for r in rs],
                        [r["metrics"]["rms_velocity_error_rad_s"] for r in rs], "k--", lw=1.2,
                        zorder=2, label="reference (no phenomenon)")
    if suite == "open-loop":
        mark_resonances(ax, info["predicted_resonances_rps"])
    finish_ripple_axes(ax, f"{suite}: {motor}, seed {seed}")
    save_figure(fig, path)


def _knowledge(board: Mapping[str, Any], motor: ProtocolMotor, seed: int,
               protocol: Protocol) -> MotorKnowledge:
    ident = next(x["model"] for x in board["identification"]
                 if x["motor"] == motor.name and x["seed"] == seed)
    return protocol_knowledge(motor, seed, FeedforwardModel(**ident) if ident else None,
                              protocol)


#: The patent's method as a user has it (identified model), drawn in the overview.
PATENT_ENTRY = "patent-ff-identified"


def _best(board: Mapping[str, Any], suite: str) -> Mapping[str, Any] | None:
    """The best-ranked eligible entry other than the patent's own feedforward
    (:func:`best_eligible`)."""
    rows = _suite_rows(board, suite)
    return best_eligible(rows, skip=(PATENT_ENTRY,)) or best_eligible(rows)


def plot_overview(board: Mapping[str, Any], path: str, protocol: Protocol,
                  points: int = 41, suite: str = "open-loop") -> None:
    """The README's figure: RMS ripple against speed on the representative motor,
    undamped, the patent's feedforward and the best other entry, on one axis.

    ``points`` speeds, log-spaced from 0.6x the lowest to 1.3x the highest
    predicted resonance, each one run as the protocol runs it.
    """
    motor = protocol_motors(protocol)[0]
    seed = protocol.eval_seeds[0]
    knowledge = _knowledge(board, motor, seed, protocol)
    res = motor.system.predicted_resonances_rps()
    speeds = np.geomspace(0.6 * min(res.values()), 1.3 * max(res.values()), points)
    rows = _suite_rows(board, suite)
    by_spec = {e["spec"]: e for e in rows}
    shown = [by_spec[s] for s in (REFERENCE_POLICY, PATENT_ENTRY) if s in by_spec]
    best = _best(board, suite)
    if best is not None:
        shown.append(best)
    styles = policy_styles([e["name"] for e in rows])
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.5))
    for e in shown:
        ripple = []
        for v in speeds:
            r = run_episode(resolve_policy(e["spec"]).make(), knowledge, motor.system,
                            mode=suite, speed_rps=float(v), seed=seed,
                            accel_rps2=protocol.accel_rps2, window_s=protocol.window_s,
                            settle_s=motor.settle_s(suite),
                            lag_limit_steps=protocol.lag_limit())
            ripple.append(r.metrics["rms_velocity_error_rad_s"] if r.metrics and not r.failed
                          else math.nan)
        colour, marker = styles[e["name"]]
        ax.semilogy(speeds, ripple, color=colour, marker=marker, ms=4, mfc="none", lw=1.2,
                    label=f"{e['name']}\n({score_label(e)})")
    mark_resonances(ax, res)
    finish_ripple_axes(ax, f"Velocity ripple, {suite}: {motor.name}, seed {seed}")
    save_figure(fig, path)


def trace_run(spec: str, motor: ProtocolMotor, knowledge: MotorKnowledge, suite: str,
              speed_rps: float, seed: int, protocol: Protocol,
              span_s: float | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """(time in the window (s), velocity error w_cmd - w (rad/s)) at every PWM
    period of the measuring window (its first ``span_s`` if given)."""

    def sample(env: Any, obs: np.ndarray, start: float) -> np.ndarray:
        tr = env.step_trace
        return tr[tr[:, K.TRACE.T] >= start - 1e-12]

    start, length = episode_window(motor.system, speed_rps, protocol.accel_rps2,
                                   protocol.window_s, motor.settle_s(suite))
    result = run_episode(resolve_policy(spec).make(), knowledge, motor.system,
                         mode=SUITE_MODE[suite],
                         speed_rps=speed_rps, seed=seed, accel_rps2=protocol.accel_rps2,
                         window_s=protocol.window_s, settle_s=motor.settle_s(suite),
                         until_s=None if span_s is None else start + span_s,
                         lag_limit_steps=protocol.lag_limit(),
                         on_step=sample, pwm_trace=True)
    rows = np.concatenate(result.trace) if result.trace else np.zeros((0, len(K.TRACE)))
    end = start + (length if span_s is None else span_s)
    rows = rows[rows[:, K.TRACE.T] < end]
    return rows[:, K.TRACE.T] - start, rows[:, K.TRACE.OMEGA_CMD] - rows[:, K.TRACE.OMEGA]


def _speed_title(label: str) -> str:
    """A v1 speed label as a panel title: "h4" -> "h = 4 resonance", "s0.1" -> "0.1 x f4"."""
    if label.startswith("h"):
        return f"h = {label[1:]} resonance"
    if label.startswith("m"):
        return f"{label[1:]} through the predicted mid-band"
    return f"{label[1:]} x f4"


def plot_resonance_traces(board: Mapping[str, Any], suite: str, path: str,
                          protocol: Protocol) -> None:
    """Velocity error against time over the whole measuring window at the three
    resonant speeds (v1 servo: at its grid speeds), sampled every PWM period:
    ``none`` against the best entry (patent Figs. 4-7 style), representative
    motor and seed."""
    rows = _suite_rows(board, suite)
    best = best_eligible(rows)
    shown = [e for e in rows if e["spec"] == REFERENCE_POLICY] + ([best] if best else [])
    styles = policy_styles([e["name"] for e in rows])
    motor = protocol_motors(protocol)[0].for_suite(suite)
    seed = protocol.eval_seeds[0]
    knowledge = _knowledge(board, motor, seed, protocol)
    if motor.split is None:                 # v0: the three resonances, in both suites
        points = [(f"h = {h} resonance", v)
                  for h, v in motor.system.predicted_resonances_rps().items()]
    else:                                   # v1: the suite's headline speeds
        speeds, labels = motor.speeds(suite)
        points = [(_speed_title(lb), v) for v, lb in zip(speeds, labels)
                  if not lb.startswith("off")]        # v3: "off-..." too
    plt = pyplot()
    fig, axes = plt.subplots(len(points), 1, squeeze=False, sharex=motor.split is None,
                             figsize=(9, 7 if motor.split is None else 2.3 * len(points) + 0.4))
    for ax, (title, v) in zip(axes[:, 0], points):
        for e in shown:
            t, err = trace_run(e["spec"], motor, knowledge, suite, v, seed, protocol)
            what = f"RMS {float(np.sqrt(np.mean(err ** 2))):.3g} rad/s" if err.size else \
                "lost steps before the window"
            ax.plot(t * 1e3, err, lw=0.7, color=styles[e["name"]][0],
                    label=f"{e['name']} ({what})")
        ax.set_ylabel("w_cmd - w (rad/s)", fontsize=8)
        ax.set_title(f"{title}: {v:.3g} rev/s", fontsize=9, loc="left")
        ax.grid(True, alpha=0.3)
        legend_outside(ax, fontsize=7)
    axes[-1, 0].set_xlabel("time in the measuring window (ms), one sample per PWM period")
    what = "the resonances" if suite == "open-loop" or motor.split is None else \
        {"servo": "the low-speed grid", "mid-band": "the mid-band (voltage mode)"}[suite]
    fig.suptitle(f"Velocity error at {what}: {motor.name}, {suite}, seed {seed}", fontsize=10)
    save_figure(fig, path)


def plot_performance_profile(board: Mapping[str, Any], path: str) -> None:
    """Performance profiles (v1): per suite and split, the fraction of an entry's
    cells whose headline is at or below tau, against tau (log axis); higher and
    further left is better. Oracles dashed, ``none`` (1 everywhere) left out."""
    p = board["protocol"]
    panels = [(suite, split) for suite in p["suites"] for split in p["splits"]]
    names = sorted({e["name"] for e in board["entries"]})
    styles = policy_styles(names)
    plt = pyplot()
    fig, axes = plt.subplots(len(p["suites"]), len(p["splits"]), squeeze=False,
                             figsize=(5.2 * len(p["splits"]) + 2.6, 3.6 * len(p["suites"])))
    for ax, (suite, split) in zip(axes.ravel(), panels):
        rows = [e for e in entry_rows(board, suite, split) if e["name"] != REFERENCE_POLICY]
        values = [np.sort([s["headline"] for s in e["scores"]]) for e in rows]
        finite = np.concatenate([v[np.isfinite(v)] for v in values] + [np.zeros(0)])
        if not finite.size:             # no entry scored here (e.g. `none` lost every run)
            finite = np.ones(1)
            ax.text(0.5, 0.5, "no scores in this suite and split", transform=ax.transAxes,
                    ha="center", fontsize=8)
        taus = np.geomspace(max(finite.min() * 0.8, 1e-4), max(finite.max() * 1.25, 1.1), 300)
        for e, v in zip(rows, values):
            colour, marker = styles[e["name"]]
            frac = np.searchsorted(v, taus, side="right") / max(v.size, 1)
            ax.semilogx(taus, frac, color=colour, lw=1.3, ls="--" if e.get("oracle") else "-",
                        marker=marker, ms=3, markevery=(names.index(e["name"]) * 7 % 30, 30),
                        label=f"{e['name']} ({score_label(e)})")
        ax.set_title(f"{suite}, {split}", fontsize=9, loc="left")
        ax.set_xlabel("headline tau (ripple over undamped)")
        ax.set_ylabel("fraction of cells <= tau")
        ax.set_ylim(-0.02, 1.02)
        ax.grid(True, which="both", alpha=0.3)
        legend_outside(ax, fontsize=6)
    fig.suptitle(f"Performance profiles, {p['name']} {p['version']} ({p['variant']}): "
                 "legend gives the IQM", fontsize=10)
    save_figure(fig, path)


def _split(board: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """(leaderboard.json without the per-run data, the runs file's content)."""
    compact = {k: v for k, v in board.items() if k != "entries"}
    compact["runs_file"] = RUNS_FILE
    compact["entries"] = [{k: v for k, v in e.items() if k not in _RAW_KEYS}
                          for e in board["entries"]]
    raw = {"entries": [{"name": e["name"], "suite": e["suite"],
                        **({"split": e["split"]} if "split" in e else {}),
                        **{k: e[k] for k in _RAW_KEYS}} for e in board["entries"]]}
    return compact, raw


def write_outputs(board: Mapping[str, Any], out_dir: str, protocol: Protocol,
                  plots: bool = True) -> list[str]:
    """Write leaderboard.json, its runs file, LEADERBOARD.md and the figures into
    ``out_dir``, each atomically; returns the file names written."""
    os.makedirs(out_dir, exist_ok=True)
    compact, raw = _split(board)
    written = ["leaderboard.json", RUNS_FILE, "LEADERBOARD.md"]
    write_json(os.path.join(out_dir, written[0]), compact)
    with atomic_path(os.path.join(out_dir, RUNS_FILE)) as tmp:
        # xz stores no time: the same board gives the same bytes.
        with lzma.open(tmp, "wb", preset=1) as fh:
            fh.write(json.dumps(raw, separators=(",", ":"), allow_nan=True).encode())
    write_text(os.path.join(out_dir, written[2]), render_markdown(board))
    if scored_in_db(board):
        for suite in board["protocol"]["suites"]:
            write_text(os.path.join(out_dir, suite_page(suite)), render_suite_page(board, suite))
            written.append(suite_page(suite))
    if plots:
        if has_splits(board):
            plot_performance_profile(board, os.path.join(out_dir, "performance_profile.png"))
            written.append("performance_profile.png")
        if "open-loop" in board["protocol"]["suites"]:
            plot_overview(board, os.path.join(out_dir, "overview.png"), protocol)
            written.append("overview.png")
        for suite in board["protocol"]["suites"]:
            for name, plot in ((f"ripple_vs_speed_{suite}.png", plot_ripple),
                               (f"velocity_error_resonances_{suite}.png", None)):
                if plot is None:
                    plot_resonance_traces(board, suite, os.path.join(out_dir, name), protocol)
                else:
                    plot(board, suite, os.path.join(out_dir, name))
                written.append(name)
    return written
