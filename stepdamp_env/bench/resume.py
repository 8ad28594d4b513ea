"""An interrupted leaderboard run's finished batches, kept in ``OUT/.resume``
(:data:`RESUME_DIR`) so that the same command started again runs only the rest.

The tool writes there its marker (``.stepdamp-resume``), one checksummed file per
finished batch (``<run>-<batch>.json``, the run named by the hash of the
protocol, motors, code and policies) and write_json's temporary files; it
deletes nothing else, and never through a link. A kept batch is read back only
if whole, matching its checksum and holding the batch's very runs."""

from __future__ import annotations

import hashlib
import json
import os
import re
import sys
from typing import TYPE_CHECKING, Any, Sequence

from ..io import read_checked_json, refuse_link, write_text
from ..params import ParameterError
from .motors import ProtocolMotor

if TYPE_CHECKING:              # the batch's fields are read, never its class
    from .leaderboard import LeaderboardBatch

__all__ = ["RESUME_DIR", "clear_resume_dir", "finish_resume_dir", "open_resume_dir",
           "resume_paths", "resumed_batch"]

# The directory inside a leaderboard's output directory that holds the finished
# batches of a run in progress (gone once the run has written its results).
RESUME_DIR = ".resume"


# What the tool writes in a resume directory: the marker, batch files
# (<run>-<batch>.json) and write_json's temporary files of them. Nothing else
# there is ever deleted.
_RESUME_MARKER = ".stepdamp-resume"
_RESUME_FILE = re.compile(r"\.?[0-9a-f]{16}-[0-9a-f]{24}(\.json|\.[a-z0-9_]{8}\.tmp\.json)")


def open_resume_dir(resume_dir: str) -> None:
    """Make (or adopt) the resume directory: never a link, and a directory the
    tool did not make (no marker) only if it holds nothing but batch files."""
    hint = "stepdamp deletes files there: remove the link"
    refuse_link(resume_dir, "resume directory", hint)
    if os.path.lexists(resume_dir) and not os.path.isdir(resume_dir):
        raise ParameterError(f"resume directory {resume_dir!r} is a file; move it away (stepdamp "
                             "keeps an interrupted run's batches there)")
    os.makedirs(resume_dir, exist_ok=True)
    marker = os.path.join(resume_dir, _RESUME_MARKER)
    if not os.path.lexists(marker):
        foreign = sorted(n for n in os.listdir(resume_dir) if not _RESUME_FILE.fullmatch(n))
        if foreign:
            raise ParameterError(
                f"resume directory {resume_dir!r} holds {foreign[0]!r}, which stepdamp did not "
                "write; move it away (the directory keeps an interrupted run's batches)")
        write_text(marker, "batches of an interrupted stepdamp leaderboard run\n")
    refuse_link(marker, "resume directory marker", hint)


def clear_resume_dir(resume_dir: str, keep_run: str | None = None) -> None:
    """Remove the batch files in ``resume_dir`` (those of run ``keep_run`` kept);
    only files the tool wrote (:data:`_RESUME_FILE`), never through a link."""
    if not os.path.lexists(resume_dir):
        return
    open_resume_dir(resume_dir)
    for name in os.listdir(resume_dir):
        if _RESUME_FILE.fullmatch(name) and \
                (keep_run is None or not name.lstrip(".").startswith(keep_run + "-")):
            try:
                os.remove(os.path.join(resume_dir, name))
            except OSError:
                pass


def finish_resume_dir(resume_dir: str) -> None:
    """After a run's results are written: its batch files and the marker go
    (the directory too, if nothing else is in it)."""
    clear_resume_dir(resume_dir)
    marker = os.path.join(resume_dir, _RESUME_MARKER)
    if os.path.isfile(marker) and not os.path.islink(marker):
        os.remove(marker)


def resume_paths(resume_dir: str, batches: Sequence[LeaderboardBatch], header: dict[str, Any]
                  ) -> list[str]:
    """One file per batch, named by the run's header and the batch; files of other
    runs (another protocol, policy, model file or package version) are removed."""
    run = hashlib.sha256(json.dumps(header, sort_keys=True, default=str).encode()
                         ).hexdigest()[:16]
    open_resume_dir(resume_dir)
    clear_resume_dir(resume_dir, keep_run=run)
    return [os.path.join(resume_dir, f"{run}-" + hashlib.sha256(
        repr((b.spec, b.suite, b.training_seed, b.runs)).encode()).hexdigest()[:24] + ".json")
        for b in batches]


# The keys of every run record (EpisodeResult.record), checked on a resumed batch.
_RECORD_KEYS = frozenset(("motor", "seed", "speed_rps", "speed_label", "terminated",
                          "termination", "failed", "steps", "window_start_s", "window_s",
                          "metrics", "calibration_s", "simulated_s"))


def resumed_batch(path: str, batch: LeaderboardBatch, motors: Sequence[ProtocolMotor]
             ) -> list[dict[str, Any]] | None:
    """A kept batch's records if they are whole, match their checksum and are the
    batch's very runs (motor, seed, speed and its label); else None (run again)."""
    key = os.path.basename(path)[:-len(".json")]
    records = read_checked_json(path, key, "resume batch")
    if not isinstance(records, list) or len(records) != len(batch.runs):
        return None
    for (i, seed, j), r in zip(batch.runs, records):
        if not (isinstance(r, dict) and _RECORD_KEYS <= r.keys()
                and isinstance(r["metrics"], (dict, type(None)))
                and r["motor"] == motors[i].name and r["seed"] == seed
                and r["speed_rps"] == motors[i].speeds(batch.suite).speeds_rps[j]
                and r["speed_label"] == motors[i].speeds(batch.suite).labels[j]):
            print(f"stepdamp: note: resume batch {path!r} does not hold its runs; running "
                  "them again", file=sys.stderr)
            return None
    return records
