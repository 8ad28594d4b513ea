"""Drive logs: a run as the drive would log it (CSV), read and written
(docs/drivelogs.md); :mod:`.logfit` identifies the detent model from them.

A drive log holds what a drive sees, one row per sample: the encoder angle,
the command currents, the current sensors' readings and the applied winding
voltages (:data:`TRACE_COLUMNS`). :func:`trace_table` turns a simulated run
into one, :func:`write_trace` and :func:`read_trace` move it through a CSV
file.
"""

from __future__ import annotations

import math
import os
from io import StringIO
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from . import fixedmath as fm
from .io import check_regular_file, write_text
from .limits import LIMITS
from .params import ParameterError, SystemParams
from .simulation import MODES, RunResult

__all__ = ["Column", "TRACE_COLUMNS", "trace_table", "write_trace", "read_trace"]


class Column(NamedTuple):
    """One column of a drive log: its SI unit and what it holds."""

    unit: str
    meaning: str


#: The columns of a drive log, in file order: name -> (unit, meaning).
TRACE_COLUMNS: dict[str, Column] = {
    "time_s": Column("s", "time of the sample (the start of a PWM period), from the run's start"),
    "position_rad": Column("rad", "shaft angle as the encoder reads it: floored to whole "
                                  "counts of 2*pi/encoder_cpr, positive forwards"),
    "command_current_a_A": Column("A", "the drive's current command, phase a: the inverse Park "
                                       "transform of (id_cmd, iq_cmd) at its Park angle"),
    "command_current_b_A": Column("A", "the drive's current command, phase b"),
    "phase_current_a_A": Column("A", "phase a current as its sensor reads it (noise, offset)"),
    "phase_current_b_A": Column("A", "phase b current as its sensor reads it"),
    "phase_voltage_a_V": Column("V", "winding a voltage applied during the period from time_s on"),
    "phase_voltage_b_V": Column("V", "winding b voltage applied during the period"),
}
_TRACE_NEEDED = ("t", "theta_fb", "theta_cmd", "id", "iq", "iq_cmd", "va", "vb")


# --------------------------------------------------------------------------- tables
def trace_table(run: RunResult | Mapping[str, np.ndarray], system: SystemParams | None = None,
                *, mode: str | None = None) -> dict[str, np.ndarray]:
    """A drive log (columns :data:`TRACE_COLUMNS`, SI) of a traced run.

    ``run`` is a :class:`~stepdamp_env.simulation.RunResult` simulated with
    ``trace=True`` (its system and mode are used), or its ``trace`` mapping
    (``kernel.TRACE_NAMES`` channels), then with ``system`` and ``mode``
    (``"open-loop"`` or ``"servo"``). The currents are the sensors' readings
    and the commands in the phase frame, both turned back from the d/q frame
    at the drive's own Park angle (servo: Nr times the centre of the encoder
    count; open loop: Nr times the microstep-quantised command angle).
    """
    if isinstance(run, RunResult):
        if run.trace is None:
            raise ParameterError("the run holds no trace: simulate it with trace=True")
        trace = run.trace
        system = run.system if system is None else system
        mode = run.settings.mode if mode is None else mode
    else:
        trace = run
        if system is None or mode is None:
            raise ParameterError("a trace mapping needs its system and mode "
                                 f"(one of {sorted(MODES)})")
    if mode not in MODES:
        raise ParameterError(f"mode={mode!r} is not one of {sorted(MODES)}")
    missing = [k for k in _TRACE_NEEDED if k not in trace]
    if missing:
        raise ParameterError(f"the trace lacks channel(s) {missing}; a simulate() trace has them")
    m, d = system.motor, system.drive
    theta_fb = np.asarray(trace["theta_fb"], dtype=float)
    # The kernel's own arithmetic (simulation.build_config, kernel.current_command),
    # so the phase-frame values turn back into the d/q ones it used.
    if mode == "servo":
        angle = m.Nr * (theta_fb + 0.5 * (2.0 * math.pi / system.servo.encoder_cpr))
        id_cmd = np.zeros_like(theta_fb)
    else:
        step = m.full_step_rad / d.microsteps
        angle = m.Nr * (np.floor(np.asarray(trace["theta_cmd"], dtype=float) * (1.0 / step))
                        * step)
        id_cmd = np.full_like(theta_fb, d.holding_current)
    s, c = fm.sincos_array(np.ascontiguousarray(angle))
    iq_cmd = np.asarray(trace["iq_cmd"], dtype=float)
    i_d, i_q = np.asarray(trace["id"], dtype=float), np.asarray(trace["iq"], dtype=float)
    return {"time_s": np.asarray(trace["t"], dtype=float).copy(),
            "position_rad": theta_fb.copy(),
            "command_current_a_A": id_cmd * c - iq_cmd * s,
            "command_current_b_A": id_cmd * s + iq_cmd * c,
            "phase_current_a_A": i_d * c - i_q * s,
            "phase_current_b_A": i_d * s + i_q * c,
            "phase_voltage_a_V": np.asarray(trace["va"], dtype=float).copy(),
            "phase_voltage_b_V": np.asarray(trace["vb"], dtype=float).copy()}


def write_trace(path: str | os.PathLike[str], table: Mapping[str, np.ndarray], *,
                comments: Sequence[str] = ()) -> None:
    """Write a drive log as CSV, atomically: ``#`` comment lines (``comments``),
    a header row of the column names, then one row per sample.

    The :data:`TRACE_COLUMNS` come first in their order, then any other
    columns of ``table``; numbers in 17 significant digits, so a file reads
    back to the same floats.
    """
    missing = [k for k in TRACE_COLUMNS if k not in table]
    if missing:
        raise ParameterError(f"the drive log table lacks column(s) {missing}")
    names = list(TRACE_COLUMNS) + [k for k in table if k not in TRACE_COLUMNS]
    columns = [np.asarray(table[k], dtype=float) for k in names]
    n = columns[0].shape
    if len(n) != 1 or n[0] < 1 or any(col.shape != n for col in columns):
        raise ParameterError(f"the drive log table's columns must be 1-D, of one length >= 1; "
                             f"got shapes {[col.shape for col in columns]}")
    for name in names:
        if "," in name or "\n" in name or not name.strip():
            raise ParameterError(f"drive log column name {name!r} must be non-empty, with no "
                                 "comma or line break")
    buf = StringIO()
    for line in [comments] if isinstance(comments, str) else comments:
        for part in str(line).splitlines() or [""]:
            buf.write(f"# {part}\n")
    buf.write(",".join(names) + "\n")
    np.savetxt(buf, np.column_stack(columns), fmt="%.17g", delimiter=",")
    write_text(path, buf.getvalue())


def read_trace(path: str | os.PathLike[str], *,
               required: Sequence[str] | None = None) -> dict[str, np.ndarray]:
    """Read a CSV drive log: column name -> float array (every column of the file).

    ``required`` (default: all :data:`TRACE_COLUMNS`) must be present. Lines
    starting with ``#`` and blank lines are skipped. Raises a one-line
    ``ParameterError`` naming the file and the missing column or the bad line:
    a field that is not a finite number, a row of the wrong length, fewer than
    two rows, a ``time_s`` that does not increase.
    """
    name = os.fspath(path)
    label = f"drive log {name!r}"
    check_regular_file(name, label)         # a pipe or /dev/zero would never end
    try:
        with open(name, encoding="utf-8") as fh:
            text = fh.read(LIMITS.json_bytes + 1)
        if len(text) > LIMITS.json_bytes:
            raise ParameterError(f"{label} is over {LIMITS.json_bytes} bytes; allowed at most "
                                 "that (a log of a few seconds is a few MB)")
    except UnicodeDecodeError:
        raise ParameterError(f"{label} is not UTF-8 text (a CSV drive log)") from None
    except OSError as exc:
        raise ParameterError(f"{label} cannot be read: {exc.strerror or exc}") from None
    lines = [(no, line) for no, line in enumerate(text.splitlines(), 1)
             if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        raise ParameterError(f"{label} is empty: no header row")
    header_no, header = lines[0]
    names = [h.strip() for h in header.split(",")]
    repeated = sorted({h for h in names if names.count(h) > 1})
    if repeated or "" in names:
        raise ParameterError(f"{label}: the header (line {header_no}) has "
                             f"{'repeated' if repeated else 'empty'} column name(s) "
                             f"{repeated or ['']}")
    for column in (TRACE_COLUMNS if required is None else required):
        if column not in names:
            raise ParameterError(f"{label}: missing column {column!r} (header, line "
                                 f"{header_no}: {', '.join(names)})")
    rows = lines[1:]
    if len(rows) < 2:
        raise ParameterError(f"{label} has {len(rows)} data row(s); at least 2 needed")
    try:
        data = np.array([r.split(",") for _, r in rows], dtype=float)
        if data.ndim != 2 or data.shape[1] != len(names):
            raise ValueError
    except ValueError:
        _raise_bad_row(label, names, rows)
        raise                                           # not reached
    bad = np.argwhere(~np.isfinite(data))
    if len(bad):
        r, col = bad[0]
        raise ParameterError(f"{label}: line {rows[r][0]}, column {names[col]}: "
                             f"{rows[r][1].split(',')[col].strip()!r} is not finite")
    table = {h: np.ascontiguousarray(data[:, i]) for i, h in enumerate(names)}
    if "time_s" in table:
        step = np.diff(table["time_s"])
        back = np.flatnonzero(~(step > 0))
        if len(back):
            raise ParameterError(f"{label}: time_s does not increase at line "
                                 f"{rows[back[0] + 1][0]}")
    return table


def _raise_bad_row(label: str, names: list[str], rows: list[tuple[int, str]]) -> None:
    for no, line in rows:
        fields = line.split(",")
        if len(fields) != len(names):
            raise ParameterError(f"{label}: line {no} has {len(fields)} field(s), the header "
                                 f"{len(names)}")
        for column, text in zip(names, fields):
            try:
                float(text)
            except ValueError:
                raise ParameterError(f"{label}: line {no}, column {column}: {text.strip()!r} "
                                     "is not a number") from None
    raise ParameterError(f"{label}: the rows cannot be read as numbers")


