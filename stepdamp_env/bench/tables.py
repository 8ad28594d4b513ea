"""The board as text: the ranked tables of LEADERBOARD.md, the per-suite and
per-motor pages, the ladder of knowledge and the results table of the docs."""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from .protocol import REFERENCE_POLICY
from .protocols import protocol_class
from .verdicts import render_table_facts, table_facts_line

#: The patent's own entry: drawn and listed beside the reference in every suite.
PATENT_ENTRY = "patent-ff-identified"

__all__ = ["PATENT_ENTRY", "best_eligible", "entry_knowledge", "entry_line", "entry_rows",
           "format_db", "format_summary", "has_splits", "render_ladder", "render_markdown",
           "render_per_motor", "render_results", "render_suite_page", "render_table_facts",
           "rank_rule", "row_notes", "row_rank", "table_facts_line",
           "score_label", "scored_in_db", "splits", "suite_page"]


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
    """Whether the board's protocol scores rows in dB against its reference row (v3
    and later: ``Protocol.headline_unit``)."""
    return protocol_class(board["protocol"]["version"]).headline_unit == "dB"


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
    att = e["attenuation_db"]["iqm"]
    sl = e["step_losses"]
    if "notes" in e:            # v4: the protocol stated them from the table's data
        notes = list(e["notes"])
    elif sl["runs"] and sl["runs_lost"] == sl["runs"]:
        notes = ["loses every run: the rotor falls behind the command at every speed "
                 "of this suite on these motors, with or without this entry's help"]
    else:
        notes = []
    if not math.isfinite(att) and not (sl["runs"] and sl["runs_lost"] == sl["runs"]):
        notes.append("no score: `none` lost every headline run on these motors, so there "
                     "is no undamped ripple to attenuate (a stalled rotor does not resonate)")
    errors = [r["error"] for r in e.get("runs", []) if r.get("error")]
    if errors and "notes" not in e:
        notes.append(f"could not run in {len(errors)} of {sl['runs']} runs, each counted as "
                     f"lost (first: {errors[0]})")
    if e.get("privileged") and math.isfinite(att) and att < 0.0:
        notes.append("privileged, yet worse than no damping: the exact model or true state "
                     "does not make this law right for this motor and suite (a privileged "
                     "row shows what that knowledge buys its law; it is no floor)")
    return notes


def rank_rule(protocol: Mapping[str, Any], before_v4: str, end: str = "") -> str:
    """How the board's ranks were made: what the protocol records (v4 on; a
    sentence where ``end`` ends one, else a clause), or ``before_v4`` (v3's
    words, as its published pages have them) followed by ``end``."""
    rule = protocol.get("rank_rule")
    if rule is None:
        return f"{before_v4}{end}"
    return _sentence(str(rule)) if end else str(rule)


def _sentence(clause: str) -> str:
    return clause[:1].upper() + clause[1:] + "."


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
    """Whether the board's protocol has rows per split of its motors (v1 and later:
    ``Protocol.rows_per_split``)."""
    return protocol_class(board["protocol"]["version"]).rows_per_split


def splits(board: Mapping[str, Any]) -> list[str | None]:
    """The board's splits in protocol order ([None] for a protocol without splits)."""
    return list(board["protocol"]["splits"]) if has_splits(board) else [None]


def render_markdown(board: Mapping[str, Any]) -> str:
    """``LEADERBOARD.md``: one ranked table per suite (v1: per split and suite,
    with the probability of improvement of every pair), then what ``stepdamp
    export`` writes per entry (:func:`render_firmware`, where the board says)."""
    from .firmware_board import render_firmware

    text = _render_tables(board)
    extra = render_firmware(board)
    if not extra:
        return text
    head, sep, versions = text.rpartition("\nVersions: ")
    return (head + "\n" + "\n".join(extra) + "\n" + sep + versions if sep
            else text + "\n" + "\n".join(extra) + "\n")


def _render_tables(board: Mapping[str, Any]) -> str:
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
                if e.get("learned") and "coverage" in e:
                    seeds += f" (covers {e['coverage']:.0%})"
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
             "the same motors without the phenomenon. "
             + rank_rule(p, "Rank 1 may be shared (overlapping intervals)", ".")
             + " Every entry, P(improvement), effect sizes, success and knowledge: "
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
    lines += render_table_facts(board)
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
             + rank_rule(p, "Rank: entries whose intervals overlap share a rank", ";")
             + " `ref`, `privileged` "
             + (f"(true state or exact model; `{p.get('bound_entry', 'privileged-bound')}` is "
                "the bound)" if "bound_rule" not in p else
                f"(true state or exact model, and `{p['bound_entry']}`, the bound: "
                f"{p['bound_rule'].split(': ', 1)[-1]})")
             + " and `zero-shot` "
             "(a learned entry outside its training coverage) rows are unranked. Effect: median over motors "
             "of the difference in dB against the best ranked entry, with its interval."
             + (" Position ripple: the same score of the RMS position error about its "
                "window mean (v4 on; ranks stay on the velocity)."
                if any("position_attenuation_db" in e for e in board["entries"]) else "")
             + (" Moves (v4): the attenuation is the velocity ripple over each move's "
                "cruise; the position column scores the RMS position error about the "
                "command over the whole move and its settling."
                if any(e.get("position_metric") == "run_position_error_steps"
                       for e in board["entries"]) else ""),
             ""]
    for suite in suites or p["suites"]:
        for split in p["splits"]:
            rows = entry_rows(board, suite, split)
            if not rows:
                continue
            best = next((e for e in rows if e.get("rank") == 1), None)
            facts = [t for t in board.get("tables", ())
                     if t["suite"] == suite and t["split"] == split]
            # v4 on: the position ripple's attenuation beside the velocity's.
            pos = any("position_attenuation_db" in e for e in rows)
            lines += [f"## {suite}, {split}", "", *(
                [table_facts_line(facts[0]), ""] if facts else []),
                      "| rank | entry | attenuation (dB) | "
                      + ((("position error over the move (dB) | "
                           if any(e.get("position_metric") == "run_position_error_steps"
                                  for e in rows) else "position ripple (dB) | ")) if pos else "")
                      + "gap closed | ratio | success | "
                      "full sweep mean / worst | effect vs "
                      f"{best['name'] if best else '-'} (dB) | P(better than it) | "
                      "training seeds | knowledge |",
                      "|---|---|---|---|---|---|---|---|---|---|---|" + ("---|" if pos else "")]
            for e in rows:
                fs = e["full_sweep"]
                eff = e.get("effect_db", {}).get(best["name"]) if best and e is not best \
                    else None
                poi = e.get("probability_of_improvement", {}).get(best["name"]) \
                    if best and e is not best else None
                seeds = ", ".join(str(k) for k in e.get("training_seeds", [])) or "-"
                if e.get("learned") and "coverage" in e:
                    seeds += f" (covers {e['coverage']:.0%})"
                effect = (f"{eff['median']:+.2f} [{eff['ci'][0]:+.2f}, {eff['ci'][1]:+.2f}]"
                          if eff else "-")
                know = ("policy none on the motor without the phenomenon"
                        if e.get("reference") else entry_knowledge(e))
                lines.append(
                    f"| {row_rank(e)} | {e['name']} | {format_db(e['attenuation_db'])} | "
                    + (f"{format_db(e['position_attenuation_db'])} | " if pos else "")
                    + f"{format_db(e['gap_closed'])} | {format_db(e['ratio'])} | "
                    f"{e['success_rate']:.2f} | {fs['mean']:.3g} / {fs['worst']:.3g} | "
                    f"{effect} | {'-' if poi is None else f'{poi:.2f}'} | {seeds} | {know} |")
            lines.append("")
            for e in rows:
                lines += [f"Note on `{e['name']}`: {n}." for n in row_notes(e)]
            if any(row_notes(e) for e in rows):
                lines.append("")
        lines += _not_run(board, suite)
    return _with_versions(board, lines)


#: A per-motor row no entry scores (v4 scores a table's common cells only).
NO_MOTOR_SCORE = ("no score: none of its cells is scored (all its speeds off the suite's "
                  "headline band, or outside a ranked learned entry's training coverage)")


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
            lines.append(f"| {motor} | " + (" | ".join(f"{n} {-v:.3g}" for v, n in ranked)
                                            if ranked else NO_MOTOR_SCORE) + " |")
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
    where = f"{p['name']} {p['version']} ({p['variant']})"
    if scored_in_db(board):             # v3: attenuation (dB), the reference row first
        title = (f"{where}: attenuation of the velocity ripple "
                 "at the headline speeds against no damping, dB (higher is better), IQM over "
                 "motors [95 % interval]; rank in parentheses ("
                 + rank_rule(p, "shared where intervals overlap") + "), "
                 "`ref`: the same motors without the phenomenon, `privileged`: true state or "
                 "exact model, "
                 "`zero-shot`: a learned entry outside its training coverage (unranked)")
        return _ladder(board, columns, by, title, "entry", lambda e: (
            f"{format_db(e['attenuation_db'])} ({row_rank(e)})"), oracle=False)
    if has_splits(board):
        title = (f"{where}: mean RMS ripple at the "
                 "headline speeds over undamped, IQM [95 % CI] over motor x seed x "
                 "training-seed cells, two-level bootstrap (lower is better)")
    else:
        title = (f"{where}: mean RMS ripple at the "
                 "resonances over undamped, IQM [95 % CI] over motors x seeds (lower is better)")
    return _ladder(board, columns, by, title, "policy",
                   lambda e: format_summary(e["headline"]), oracle=True)


def _ladder(board: Mapping[str, Any], columns: list[tuple[str, Any]],
            by: Mapping[tuple, Mapping[str, Any]], title: str, first: str,
            cell: Callable[[Mapping[str, Any]], str], oracle: bool) -> str:
    """The ladder's Markdown: a row per entry (ranked by the first column), a cell
    per (suite, split) column, its knowledge; " (oracle)" after an oracle's name."""
    names = [e["name"] for e in entry_rows(board, *columns[0])]
    names += sorted({e["name"] for e in board["entries"]} - set(names))
    heads = [f"{suite}, {split}" if has_splits(board) else suite for suite, split in columns]
    lines = [title, "", f"| {first} | " + " | ".join(heads) + " | knowledge |",
             "|---|" + "---|" * len(heads) + "---|"]
    for name in names:
        found = [by.get((name, *key)) for key in columns]
        cells = [cell(e) if e else "not run" for e in found]
        know = next((k for k in (_knowledge(e) for e in found if e) if k), "")
        mark = " (oracle)" if oracle and any(e.get("oracle") for e in found if e) else ""
        lines.append(f"| {name}{mark} | " + " | ".join(cells) + f" | {know} |")
    return "\n".join(lines) + "\n"


def _knowledge(e: Mapping[str, Any]) -> str:
    return ("policy none on the motor without the phenomenon" if e.get("reference")
            else entry_knowledge(e))


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
