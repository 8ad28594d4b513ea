"""The benchmark's commands: leaderboard, report, train."""

from __future__ import annotations

import argparse
import os
from typing import Any, Callable

from ..io import check_output_dir, output_lock, staged_directory
from ..params import ParameterError
from ..ray_backend import backend_map
from .options import add_pool_run_args, number, register_policies, renamed

__all__ = ["add_commands"]


def add_commands(sub: Any, command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """The benchmark's commands on the subparsers ``sub`` (``command`` adds one)."""
    from ..bench.protocols import DEFAULT_VERSION, known_suites, protocol_about, protocol_versions

    p = command("leaderboard", f"run the stepdamp-bench protocol ({DEFAULT_VERSION} by "
                               "default) on the baselines, the reference agents and given "
                               "policies")
    p.add_argument("--protocol", choices=protocol_versions(), default=DEFAULT_VERSION,
                   help="protocol version, each specified in docs/protocols.md: " +
                        "; ".join(f"{v} ({protocol_about(v)})" for v in protocol_versions()))
    p.add_argument("--quick", action="store_true",
                   help="the protocol's reduced CI variant: " + "; ".join(
                       f"{v}: {protocol_about(v, quick=True)}" for v in protocol_versions()))
    p.add_argument("--motors", metavar="FILE.json", default=None,
                   help="the protocol on your own motors (split 'custom'): a motor file (a "
                        "datasheet file or model fields, docs/motors.md) or a JSON list of "
                        "them and preset names; the nominal model is the file's values")
    p.add_argument("--policy", action="append", nargs="+", default=[], metavar="SPEC",
                   help="extra policy: package.module:attr or path/file.py:attr (a Policy "
                        "class, factory or instance), a model `stepdamp train` wrote "
                        "(DIR/best.zip) or an SB3 .zip; repeatable. Loading runs its code "
                        "(an SB3 .zip unpickles): use trusted files only")
    p.add_argument("--entries", dest="entries", action="append", nargs="+",
                   default=None, metavar="NAME",
                   help="run only these registered entries, baselines and reference agents "
                        "(default: all; 'none' always runs)")
    p.add_argument("--suite", choices=[*known_suites(), "all"], default="all",
                   help="one suite's ranked table; 'all' (default): every entry's headline "
                        "in each suite beside its knowledge (docs/results.md's tables)")
    p.add_argument("--split", choices=["dev", "interpolation", "extrapolation", "catalogue"],
                   default=None,
                   help="v3 or later: run one split; 'dev' is the split for tuning, ablations "
                        "and model selection (never scored); 'catalogue' (v4): real "
                        "motors from public datasheets. Default: the protocol's scored splits")
    p.add_argument("--eval-seeds", type=number(int, 1, 20), default=None, metavar="N",
                   help="v4 or later: how many evaluation (noise) seeds each run is repeated "
                        "with, from 1000000 on (default: the protocol's, 3; v5 needs 2 or "
                        "more for its bound)")
    add_pool_run_args(p)
    p.add_argument("--no-plots", action="store_true", help="skip the figures")
    p.add_argument("--no-resume", action="store_true",
                   help="run every batch again, ignoring the finished batches an interrupted "
                        "run left in DIR/.resume (a run resumes by default)")
    p.set_defaults(func=_cmd_leaderboard)

    p = command("report", "print a result table from a leaderboard directory")
    p.add_argument("dir", metavar="DIR", help="a directory `stepdamp leaderboard` wrote")
    p.add_argument("--suite", choices=[*known_suites(), "all"], default="all",
                   help="one suite's ranked table; 'all' (default): every entry's headline "
                        "in each suite beside its knowledge (docs/results.md's tables)")
    p.add_argument("--full", action="store_true", help="the whole LEADERBOARD.md table")
    p.add_argument("--check", action="store_true",
                   help="re-run a sample of the board's cells here and say, per cell, whether "
                        "it reproduces bit for bit (exit status 1 if any does not)")
    p.add_argument("--sample", type=number(int, 1, 100000), default=12, metavar="N",
                   help="cells --check re-runs, spread over every entry, suite and split")
    p.add_argument("--no-verify", action="store_true",
                   help="show a board whose numbers do not match its fingerprint (edited or "
                        "damaged files; by default that is an error), or the scores of a "
                        "board published without its runs file")
    p.set_defaults(func=_cmd_report)

    from stepdamp_agents.train import ALGO_CHOICES, add_arguments

    p = command("train", f"train residual RL agents ({', '.join(ALGO_CHOICES)}) on "
                "StepperDamp-v1 (or the v0 gain selector)")

    add_arguments(p)
    renamed(p, "--set", "--hyperparam")
    renamed(p, "--motors", "--presets")
    renamed(p, "--envs-per-motor", "--envs-per-preset")
    p.set_defaults(func=_cmd_train)


def _cmd_leaderboard(args: argparse.Namespace) -> int:
    from ..bench import default_policy_names, run_leaderboard, write_outputs
    from ..bench.protocols import protocol_class, protocol_for, protocol_versions
    from ..bench.protocols.v1 import load_motors_file
    from ..bench.report import RESULT_FILES, entry_line, entry_rows, render_per_motor, splits

    from ..bench.leaderboard import (RESUME_DIR, clear_resume_dir, finish_resume_dir,
                                    open_resume_dir)

    args.out = check_output_dir(args.out, "--out", own_dirs=(RESUME_DIR,))
    protocol = protocol_for(args.protocol, quick=args.quick)
    if args.motors is not None:
        protocol = protocol.with_custom_motors(load_motors_file(args.motors, protocol))
    register_policies()
    if args.suite != "all":
        if args.suite not in protocol.known_suites:
            has = [v for v in protocol_versions() if args.suite in protocol_class(v).known_suites]
            raise ParameterError(f"--suite {args.suite}: {protocol.name} {protocol.version} has "
                                 f"{list(protocol.known_suites)}; --protocol {' or '.join(has)} "
                                 f"has {args.suite}")
        protocol = protocol.with_suites((args.suite,))
    if args.split is not None:
        if args.motors is not None:
            raise ParameterError("--split: give --split or --motors (the custom split), not both")
        protocol = protocol.with_splits((args.split,))
    if args.eval_seeds is not None:
        protocol = protocol.with_eval_seeds(args.eval_seeds)
    named = default_policy_names()
    chosen = protocol.default_entries(named) if args.entries is None else \
        [b for g in args.entries for b in g]
    unknown = sorted(set(chosen) - set(named))
    if unknown:
        raise ParameterError(f"--entries: unknown {unknown}; choose from {list(named)}")
    extra = [p for group in args.policy for p in group]
    resume = os.path.join(args.out, RESUME_DIR)
    # One run writes an output directory at a time: its kept batches are the run's.
    with output_lock(args.out, "--out"):
        open_resume_dir(resume)         # refused before any work if it is a link or not ours
        if args.no_resume:
            clear_resume_dir(resume)
        board = run_leaderboard(protocol, chosen + extra, workers=args.workers,
                                progress=not args.no_progress, resume_dir=resume,
                                backend=backend_map(args.backend, args.ray_address),
                                fingerprint=False)
        with staged_directory(args.out, RESULT_FILES,
                              own_dirs={RESUME_DIR: finish_resume_dir}) as stage:
            written = write_outputs(board, stage, protocol, plots=not args.no_plots)
    for suite in protocol.suites:
        for split in splits(board):
            where = suite if split is None else f"{suite}, {split}"
            print(f"{protocol.name} {protocol.version} ({protocol.variant}), {where}:")
            for e in entry_rows(board, suite, split):
                print("  " + entry_line(e))
            if split == "custom":
                print(render_per_motor(board, suite, split), end="")
    print(f"wall {board['wall_seconds']:.1f} s, simulated {board['simulated_seconds']:.0f} s")
    print("wrote " + ", ".join(os.path.join(args.out, n) for n in written))
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    from ..bench.report import (load_leaderboard, render_ladder, render_markdown, render_results,
                               render_suite_page, scored_in_db, verify_fingerprint)

    path = os.path.join(args.dir, "leaderboard.json")
    if not os.path.isfile(path):
        raise ParameterError(f"DIR {args.dir!r} holds no leaderboard.json (write one with "
                             "`stepdamp leaderboard --out DIR`)")
    # --no-verify shows a board published without its runs file (its scores);
    # --check needs the runs.
    board = load_leaderboard(args.dir, runs=None if args.no_verify and not args.check else True)
    if not (args.no_verify or args.check):      # --check says so among its findings
        verify_fingerprint(board, args.dir)
    if args.check:
        return _check_report(board, args.dir, args.sample)
    pages = [render_suite_page(board, suite) for suite in board["protocol"]["suites"]] \
        if scored_in_db(board) else []
    if args.full:
        print("\n".join([render_markdown(board)] + pages), end="")
        return 0
    if args.suite == "all":
        print(render_ladder(board), end="")
        return 0
    if pages:
        print(render_suite_page(board, args.suite), end="")
        return 0
    print(render_results(board, args.suite), end="")
    return 0


def _check_report(board: dict, directory: str, sample: int) -> int:
    """``report --check``: re-run a sample of the board's cells; 1 if any differs."""
    from ..bench.check import check_board

    env = board.get("environment", {})
    print(f"{directory}: computed on {env.get('cpu', {}).get('model', 'an unrecorded CPU')} "
          f"({' '.join(env.get('cpu', {}).get('flags', []))}), re-run here on "
          f"{sample} cells", flush=True)
    results = check_board(board, sample=sample)
    for r in results:
        print(f"{'reproduces' if r['reproduces'] else 'DIFFERS   '}  {r['what']}"
              + (f"  ({r['detail']})" if r["detail"] else ""))
    bad = sum(not r["reproduces"] for r in results)
    print(f"{len(results) - bad} of {len(results)} checks reproduce")
    return 1 if bad else 0


def _cmd_train(args: argparse.Namespace) -> int:
    from stepdamp_agents.train import args_from_namespace, train_seeds

    train_seeds(args_from_namespace(args))
    return 0


