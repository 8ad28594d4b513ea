"""``stepdamp`` command line: motors, analyse, simulate, sweep, identify, export,
leaderboard, report, train.

The composition root: the only package of ``stepdamp_env`` that imports the
baselines and the agents (``stepdamp_baselines``, ``stepdamp_agents``); it
registers their policies with the leaderboard before any command runs. Every
user mistake ends with exit status 2 and one line naming the option; Ctrl-C
with one line and status 130. Output directories are written as a whole
(:func:`stepdamp_env.io.staged_directory`). The drive's commands are in
:mod:`.drive`, the benchmark's in :mod:`.bench`, what they share in
:mod:`.options`; docs/cli.md has every flag's one meaning.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
from typing import Any, Sequence

from .. import numba_cache
from ..params import ParameterError
from ..parallel import WorkerLostError
from . import bench, drive, firmware
from .options import DESCRIPTION, HelpFormatter

__all__ = ["main", "run", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    """The ``stepdamp`` parser: every command and its options."""
    from ..version import __version__

    parser = argparse.ArgumentParser(prog="stepdamp", description=DESCRIPTION,
                                     formatter_class=HelpFormatter)
    parser.add_argument("--version", action="version", version=f"stepdamp {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def command(name: str, text: str) -> argparse.ArgumentParser:
        return sub.add_parser(name, help=text, description=text, formatter_class=HelpFormatter)

    drive.add_commands(sub, command)
    firmware.add_commands(sub, command)
    bench.add_commands(sub, command)
    return parser


def _terminate(signum: int, frame: Any) -> None:
    raise SystemExit(128 + signum)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status (2 for a user mistake,
    130 after Ctrl-C, 143 after SIGTERM)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    previous = signal.getsignal(signal.SIGTERM)
    try:
        # SIGTERM unwinds like Ctrl-C, so staging directories and temporary files go.
        signal.signal(signal.SIGTERM, _terminate)
    except ValueError:              # not the main thread: leave signals alone
        previous = None
    try:
        # Room on the frame stack: numba compiles at whatever depth a command calls it.
        return int(numba_cache.call_with_frame_room(args.func, args))
    except ParameterError as exc:
        print(f"stepdamp {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except WorkerLostError as exc:
        print(f"stepdamp {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        where = f" {exc.filename!r}" if exc.filename else ""
        print(f"stepdamp {args.command}: error:{where} {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        # A second Ctrl-C during the interpreter's shutdown would print a traceback; a
        # caller in the same process (argv given) keeps its own Ctrl-C.
        if argv is None:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        resume = " (run the same command again to resume)" if args.command == "leaderboard" \
            else ""
        # On a line of its own: a progress bar may hold the cursor at the end of its line.
        print(f"\nstepdamp {args.command}: interrupted; earlier results are unchanged{resume}",
              file=sys.stderr)
        return 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def run() -> None:
    """The ``stepdamp`` executable: :func:`main` on the process's arguments, then
    exit with its status. After Ctrl-C (130) the process leaves without the
    interpreter's shutdown: under load, with Ctrl-C pressed twice, that shutdown
    was seen to end the process by SIGINT (status -2) after main had returned
    130 (about 1 run in 10 of tests/test_hardening.py's double Ctrl-C). Nothing
    is left to tear down then: the workers are gone, result files are whole."""
    status = main()
    if status != 130:
        sys.exit(status)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        numba_cache.remove_private_folders()
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(130)
