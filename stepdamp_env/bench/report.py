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
import os
import queue
import threading
from typing import Any, Callable, Mapping

from ..io import atomic_path, read_json, write_json, write_text
from ..params import ParameterError

# The text and the figures live in .tables and .figures; their names are kept here too.
from .figures import (HIGHLIGHTED, highlighted_rows, plot_move_traces, plot_overview,
                      plot_performance_profile,
                      plot_resonance_traces, plot_ripple, policy_styles, trace_run)
from .protocol import Protocol
from .provenance import board_fingerprint
from .suites import get_suite
from .tables import (best_eligible, entry_knowledge, entry_line, entry_rows, format_summary,
                     has_splits, render_ladder, render_markdown, render_per_motor, render_results,
                     render_suite_page, row_notes, scored_in_db, splits, suite_page)

__all__ = ["RESULT_FILES", "RUNS_FILE", "GZIP_RUNS_FILE", "open_runs_file", "format_summary",
           "render_markdown", "render_results", "render_ladder", "render_suite_page", "suite_page",
           "row_notes", "best_eligible", "scored_in_db", "highlighted_rows", "entry_knowledge",
           "entry_rows", "render_per_motor", "has_splits", "splits", "plot_performance_profile",
           "load_leaderboard", "verify_fingerprint", "policy_styles", "plot_ripple",
           "plot_overview", "plot_resonance_traces", "trace_run", "write_outputs", "HIGHLIGHTED",
           "entry_line"]

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


def open_runs_file(path: str | os.PathLike[str]) -> Any:
    """A runs file opened for reading as text: xz, or gzip (boards before 0.13.0)."""
    opener = lzma.open if os.fspath(path).endswith(".xz") else gzip.open
    return opener(path, "rt", encoding="utf-8")


def load_leaderboard(directory: str | os.PathLike[str], runs: bool | None = True
                     ) -> dict[str, Any]:
    """The board as :func:`~.leaderboard.run_leaderboard` returned it, read from
    ``leaderboard.json`` and its runs file. ``runs`` False: the scores only
    (the entries without their ``scores`` and ``runs``; a published board may
    leave its runs file out, as v4's does); None: the runs where the runs file
    is there. A missing runs file is a one-line ``ParameterError`` otherwise."""
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
    if runs is None:
        runs = os.path.exists(path)
    if not runs:
        board.pop("runs_file", None)
        return board
    if not os.path.exists(path):
        version = protocol.get("version")
        quick = " --quick" if protocol.get("variant") == "quick" else ""
        raise ParameterError(
            f"board {os.fspath(directory)!r} holds its scores but not its runs file {runs_file} "
            "(a published board may leave it out): the command that made it (`stepdamp "
            f"leaderboard --protocol {version}{quick} --out DIR` and its options) writes the "
            "runs again with the same fingerprint; --no-verify shows the scores")
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


def write_outputs(board: dict[str, Any], out_dir: str, protocol: Protocol,
                  plots: bool = True) -> list[str]:
    """Write leaderboard.json, its runs file, LEADERBOARD.md and the figures into
    ``out_dir``, each atomically; returns the file names written. A board without
    its ``"fingerprint"`` (``run_leaderboard(..., fingerprint=False)``) gets it,
    computed while the runs file compresses."""
    os.makedirs(out_dir, exist_ok=True)
    raw = _split(board)[1]
    written = ["leaderboard.json", RUNS_FILE, "LEADERBOARD.md"]

    def pages() -> None:
        if "fingerprint" not in board:
            board["fingerprint"] = board_fingerprint(board)
        write_json(os.path.join(out_dir, written[0]), _split(board)[0])
        write_text(os.path.join(out_dir, written[2]), render_markdown(board))
        if scored_in_db(board):
            for suite in board["protocol"]["suites"]:
                write_text(os.path.join(out_dir, suite_page(suite)),
                           render_suite_page(board, suite))
                written.append(suite_page(suite))
        if plots:
            written.extend(_write_figures(board, out_dir, protocol))

    _write_runs_file(os.path.join(out_dir, RUNS_FILE), raw, meanwhile=pages)
    return written


def _write_runs_file(path: str, raw: Mapping[str, Any], meanwhile: Callable[[], None]) -> None:
    """The runs file, atomically: the JSON of ``raw`` into xz at preset 1, the
    bytes of one ``write(json.dumps(raw))`` (xz stores no time: the same board
    gives the same bytes). A thread compresses (lzma lets go of the GIL) while
    this one encodes the entries, then runs ``meanwhile`` (the queue is not
    bounded: the JSON waits in it, as ``json.dumps`` held it whole before)."""
    chunks: queue.Queue[bytes | None] = queue.Queue()
    failed: list[BaseException] = []
    with atomic_path(path) as tmp, lzma.open(tmp, "wb", preset=1) as fh:
        def compress() -> None:
            while (chunk := chunks.get()) is not None:
                if not failed:
                    try:
                        fh.write(chunk)
                    except BaseException as exc:    # noqa: BLE001 - raised again below
                        failed.append(exc)

        worker = threading.Thread(target=compress, name="runs-file", daemon=True)
        worker.start()
        try:
            if set(raw) != {"entries"}:
                chunks.put(json.dumps(raw, separators=(",", ":"), allow_nan=True).encode())
            else:
                chunks.put(b'{"entries":[')
                for i, entry in enumerate(raw["entries"]):
                    text = json.dumps(entry, separators=(",", ":"), allow_nan=True)
                    chunks.put(("," + text if i else text).encode())
                chunks.put(b"]}")
            meanwhile()
        finally:
            chunks.put(None)            # the thread ends when it has written the rest
            worker.join()
        if failed:
            raise failed[0]


def _write_figures(board: Mapping[str, Any], out_dir: str, protocol: Protocol) -> list[str]:
    """The board's figures into ``out_dir``; returns their file names."""
    written: list[str] = []
    if has_splits(board):
        plot_performance_profile(board, os.path.join(out_dir, "performance_profile.png"))
        written.append("performance_profile.png")
    if "open-loop" in board["protocol"]["suites"]:
        plot_overview(board, os.path.join(out_dir, "overview.png"), protocol)
        written.append("overview.png")
    for suite in board["protocol"]["suites"]:
        if get_suite(suite).profile == "move":      # v4's moves: through each move
            plot_move_traces(board, suite, os.path.join(out_dir, f"velocity_error_{suite}.png"),
                             protocol)
            written.append(f"velocity_error_{suite}.png")
            continue
        for name, plot in ((f"ripple_vs_speed_{suite}.png", plot_ripple),
                           (f"velocity_error_resonances_{suite}.png", None)):
            if plot is None:
                plot_resonance_traces(board, suite, os.path.join(out_dir, name), protocol)
            else:
                plot(board, suite, os.path.join(out_dir, name))
            written.append(name)
    return written
