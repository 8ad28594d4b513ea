"""The firmware commands: export (an entry's law for a drive) and recommend (which
exportable law to flash on a motor)."""

from __future__ import annotations

import argparse
from typing import Any, Callable

from ..io import check_writable
from ..motorfile import load_system, parse_set_overrides
from ..params import ParameterError
from .options import number, register_policies

__all__ = ["add_commands"]


def add_commands(sub: Any, command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    p = command("export", "write an entry's damping law for a drive's firmware: harmonic "
                "table, per-microstep table and gains as JSON, or C99 source and header")
    p.add_argument("entry", metavar="ENTRY",
                   help="a leaderboard entry with a fixed law (patent-ff-identified, "
                        "ff-delay-comp, calibrated-table, tuned-constant-gain, "
                        "tuned-gain-pair; in open loop velocity-feedback, "
                        "sensorless-damping), adaptive-ff and repetitive-control (their "
                        "online table), or a learned entry (its policy network: "
                        "ppo-open-loop, ...)")
    p.add_argument("--motor", required=True, metavar="NAME|FILE.json",
                   help="what the drive knows: a preset or a motor file (to use the model "
                        "identified on your motor, export with `stepdamp identify`'s "
                        "identified_motor.json)")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="FIELD=VALUE", help="override one parameter (SI units); repeatable")
    p.add_argument("--format", choices=("c", "json"), default="c",
                   help="c: PREFIX.h and PREFIX.c (C99, libm's sin only); json: PREFIX.json")
    p.add_argument("--mode", choices=("open-loop", "servo"), default="open-loop",
                   help="the drive's mode the law is computed for")
    p.add_argument("--speed", type=number(float, 1e-3, 1e3), default=None, metavar="RPS",
                   help="held command speed the delay-compensated table is computed for "
                        "(rev/s; default: the motor's h=4 resonance)")
    p.add_argument("--speeds", default=None, metavar="START:STOP:STEP",
                   help="one law for a speed range: the table at each speed of this grid "
                        "(rev/s), interpolated over the command speed (instead of --speed)")
    p.add_argument("--prefix", default=None,
                   help="file and C symbol prefix (default: the entry's name, - as _)")
    p.add_argument("--out", default=".", metavar="DIR", help="output directory")
    p.set_defaults(func=_cmd_export)

    p = command("recommend", "which exportable damping law to flash on a motor: the entries "
                "export can write, ranked on a quick board of that motor, with the "
                "attenuation to expect")
    p.add_argument("motor", metavar="NAME|FILE.json", help="a preset or a motor file")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="FIELD=VALUE", help="override one parameter (SI units); repeatable")
    p.add_argument("--mode", choices=("open-loop", "servo"), default="open-loop",
                   help="the drive's mode (the suite it is ranked in)")
    p.add_argument("--workers", type=number(int, 1, 4096), default=None,
                   help="worker processes (default: the CPUs)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=_cmd_recommend)


def _export_schedule(args: argparse.Namespace) -> int:
    """``export --speeds``: one law over a speed range."""
    from ..bench.firmware import entry_law, firmware_knowledge
    from ..bench.firmware_schedule import (build_schedule, export_schedule,
                                           interpolation_error, multiply_adds_per_period)
    from ..bench.registry import resolve_policy
    from ..sweep import parse_speed_range

    if args.speed is not None:
        raise ParameterError("--speed and --speeds: give one (a held speed, or a grid of them)")
    speeds = parse_speed_range(args.speeds)
    if len(speeds) < 2:
        raise ParameterError(f"--speeds {args.speeds!r} gives {len(speeds)} speed; a schedule "
                             "needs at least 2")
    system = load_system(args.motor, parse_set_overrides(args.overrides))
    register_policies()
    policy = resolve_policy(args.entry).make()
    if callable(getattr(policy, "firmware_network", None)):
        raise ParameterError(f"--speeds: {args.entry!r} is a learned entry: its network's "
                             "command speed is one of its inputs, so one export covers every "
                             "speed (leave out --speeds)")
    if callable(getattr(policy, "firmware_online", None)):
        raise ParameterError(f"--speeds: {args.entry!r} adapts its table while it runs; "
                             "export it at one held speed (--speed)")
    knowledge = firmware_knowledge(system)

    def law_at(speed: float) -> Any:
        return entry_law(args.entry, knowledge, mode=args.mode, speed_rps=speed)

    schedule = build_schedule(law_at, float(speeds[0]), float(speeds[-1]), len(speeds))
    error_a, share = interpolation_error(schedule, law_at)
    check_writable(args.out, "--out", directory=True)
    paths = export_schedule(schedule, args.format, args.out, args.prefix)
    cost = multiply_adds_per_period(schedule)
    print(f"{args.entry} on {system.name}, {args.mode}, {len(speeds)} speeds "
          f"{speeds[0]:.4g}..{speeds[-1]:.4g} rev/s (step {schedule.step_rps:.4g}): table "
          f"of {cost['table_doubles']} doubles, per PWM period {cost['multiplications']} "
          f"multiplications, {cost['additions']} additions, {cost['sin_cos']} sin/cos"
          + (f", and every {cost['update_periods']} periods the feedback's update "
             f"({cost['update_multiplications']} multiplications, "
             f"{cost['update_additions']} additions)" if "update_periods" in cost else "")
          + "; "
          f"between the grid's speeds the interpolated table is off by at most "
          f"{error_a:.3g} A ({100 * share:.2g} % of the table; halve the step to shrink it); "
          f"wrote {', '.join(paths)}")
    return 0


def _cmd_recommend(args: argparse.Namespace) -> int:
    import shlex

    from ..bench.recommend import recommend
    from ..sweep import default_speed_range

    system = load_system(args.motor, parse_set_overrides(args.overrides))
    register_policies()
    rec = recommend(system, args.mode, workers=args.workers, progress=not args.no_progress)
    print(f"{system.name}, {rec.suite}: the exportable entries on a quick stepdamp-bench v4 "
          f"board of this motor alone (its headline speeds, its sensors, "
          f"{rec.eval_seeds} seeds); attenuation of the velocity ripple against no damping, "
          "mean over the headline runs [95 % interval over the seeds; zero wide where the "
          "runs do not depend on the seed] and per headline speed "
          + ", ".join(f"{v:.4g}" for v in rec.scores[0]["by_speed"]) + " rev/s:")
    for s in rec.scores:
        lost = f", {s['lost']} lost steps (-20 dB each)" if s["lost"] else ""
        per = " / ".join(f"{v:.1f}" for v in s["by_speed"].values())
        print(f"  {s['name']:24s} {s['mean']:6.1f} dB [{s['ci'][0]:.1f}, {s['ci'][1]:.1f}] "
              f"(per speed {per} dB; {s['runs']} runs{lost})")
    pick = rec.pick
    tied = (f"; the paired comparison does not tell it apart from {', '.join(rec.tied)}"
            if rec.tied else "")
    warn = (f" It lost steps in {pick['lost']} runs, as every exportable entry did here."
            if pick["lost"] else "")
    source = " ".join(shlex.quote(a) for a in [args.motor] + [x for o in args.overrides
                                                              for x in ("--set", o)])
    low, high, _ = (float(v) for v in default_speed_range(system).split(":"))
    # About 30 tables; the step in 6 digits, rounded down so the grid reaches the top.
    step = float(f"{(high - low) / 30:.6g}")
    if step > (high - low) / 30:
        step = float(f"{(high - low) / 30 * (1.0 - 1e-6):.6g}")
    print(f"flash {pick['name']}: expect {pick['mean']:.1f} dB [{pick['ci'][0]:.1f}, "
          f"{pick['ci'][1]:.1f}] less ripple than without damping at the motor's resonant "
          f"speeds in this simulation{tied}.{warn} Its law over the motor's speed range "
          "(the positive direction):\n"
          f"  stepdamp export {pick['name']} --motor {source} --mode {args.mode} "
          f"--speeds {low:g}:{high:g}:{step:g} --out firmware/")
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from ..bench.firmware import (FirmwareNetwork, KalmanTable, OnlineTableLaw, default_prefix,
                                  entry_export, export_any, firmware_knowledge)

    if args.speeds is not None:
        return _export_schedule(args)
    system = load_system(args.motor, parse_set_overrides(args.overrides))
    register_policies()
    law = entry_export(args.entry, firmware_knowledge(system), mode=args.mode,
                       speed_rps=args.speed)            # a law, an online table or a network
    check_writable(args.out, "--out", directory=True)
    paths = export_any(law, args.format, args.out, args.prefix)
    prefix = default_prefix(law.entry) if args.prefix is None else args.prefix
    if isinstance(law, OnlineTableLaw):
        how = ("a Kalman filter of the speed ripple" if isinstance(law, KalmanTable)
               else "learned once per electrical period")
        print(f"{args.entry} on {system.name}, {args.mode} at {law.speed_rps:.4g} rev/s: a "
              f"harmonic table that adapts while it runs ({how}, updated "
              f"{law.decision_hz:g} times a second"
              + (f"; the C's {prefix}_update, its state the caller's" if args.format == "c"
                 else "") + f"); wrote {', '.join(paths)}")
        return 0
    if isinstance(law, FirmwareNetwork):
        print(f"{args.entry} on {system.name}, {args.mode}: network "
              f"{'-'.join(map(str, law.sizes))} ({law.multiply_adds} multiply-adds per "
              f"decision at {law.decision_hz:g} Hz"
              + (f"; the C's {prefix}_policy_action" if args.format == "c" else "")
              + f"), its {law.sizes[0]} inputs and {law.sizes[-1]} outputs named, with "
              f"{system.name}'s units, in what it wrote: {', '.join(paths)}")
        return 0
    f = law.filtered_feedback
    feedback = (f"feedback from filters ({f.kind}) every {f.periods_per_update} PWM periods, "
                f"held in between (the C's {prefix}_feedback_update_a; its state the "
                "caller's)"
                if f is not None else
                f"velocity gain {law.velocity_gain_a_s_per_rad:.4g} A*s/rad"
                + (f", position gain {law.position_gain_a_per_rad:.4g} A/rad (high-passed: "
                   "the C function keeps one state, the caller's)" if law.stateful else ""))
    print(f"{args.entry} on {system.name}, {args.mode} at {law.speed_rps:.4g} rev/s: "
          f"{len(law.harmonics)} harmonics, {feedback}; wrote {', '.join(paths)}")
    return 0
