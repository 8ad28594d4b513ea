"""The drive's commands: motors (presets), analyse, simulate, sweep, identify
(export and recommend: :mod:`.firmware`)."""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
from typing import Any, Callable

import numpy as np

from ..io import check_output_dir, check_writable, staged_directory
from ..limits import LIMITS
from ..motorfile import load_system, parse_set_overrides
from ..params import ParameterError
from ..presets import preset_names
from ..ray_backend import backend_map
from ..simulation import (MAX_DURATION_S, TRACE_ROW_BYTES, SpeedProfile,
                          check_trace_memory, measuring_window, run_length_error, simulate)
from ..sweep import MAX_SPEED_RPS, MIN_SPEED_RPS, resolving_spacing
from .options import (HelpFormatter, add_pool_run_args, add_system_args, fmt_value, number,
                      register_policies, renamed, run_settings)

__all__ = ["add_commands", "motor_record", "SWEEP_FILES", "IDENTIFY_FILES"]

SWEEP_FILES = ("sweep.json", "sweep_*.json", "sweep.png", "velocity_error_traces.png")
IDENTIFY_FILES = ("identified_motor.json", "identification.json")


def add_commands(sub: Any, command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """The drive's commands on the subparsers ``sub`` (``command`` adds one)."""
    p = command("motors", "describe motors (presets or motor files): model values, "
                "resonances, mid-band, top speed and what a file left to defaults")
    p.add_argument("motors", nargs="*", metavar="NAME|FILE",
                   help="a preset or a motor .json file (a datasheet file, a model file or "
                        "a --motors list); default: every preset")
    p.add_argument("--json", action="store_true", help="print the records as JSON")
    p.set_defaults(func=_cmd_motors)
    p = sub.add_parser("presets", help="the same as `stepdamp motors` (older name)",
                       formatter_class=HelpFormatter)
    p.add_argument("motors", nargs="*", metavar="NAME|FILE")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=_cmd_motors)

    p = command("analyse", "the predicted mid-band (unstable speed band) per motor and "
                "drive mode, from the eigenvalues of the linearised drive")
    p.add_argument("--motor", action="append", default=None, metavar="NAME|FILE.json",
                   help="a preset or motor file; repeatable (default: every preset)")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="FIELD=VALUE", help="override one parameter (SI units); repeatable")
    p.add_argument("--json", action="store_true", help="print the bands as JSON")
    p.set_defaults(func=_cmd_analyse)

    p = command("simulate", "one run at one speed (or one move); prints its metrics")
    add_system_args(p)
    p.add_argument("--speed", type=number(float, -1000, 1000), required=True, metavar="RPS",
                   help="command speed (rev/s, signed); the top speed of a --move")
    p.add_argument("--move", type=number(float, -1e6, 1e6), default=None, metavar="REV",
                   help="point-to-point move of this many revolutions, measured from its start "
                        "through its settling (default: constant speed)")
    p.add_argument("--ramp", choices=("trapezoid", "s-curve"), default="trapezoid",
                   help="a --move's ramps: trapezoid (constant acceleration --accel) or "
                        "s-curve (half-cosine ramps of peak acceleration --accel: bounded jerk)")
    p.add_argument("--duration", type=number(float, 0, MAX_DURATION_S, low_open=True),
                   default=None,
                   metavar="SECONDS", help="simulated time (default: ramp + settle + 0.5 s window)")
    p.add_argument("--trace", default=None, metavar="FILE.npz|FILE.csv",
                   help="write one sample per PWM period: FILE.csv a drive log (columns in "
                        "docs/drivelogs.md, what `identify --log` reads), FILE.npz every "
                        "state of the simulation (units and settings inside)")
    p.add_argument("--json", action="store_true", help="print the settings and metrics as JSON")
    p.set_defaults(func=_cmd_simulate)

    p = command("sweep", "ripple against command speed, one or several base controllers on "
                         "one figure")
    add_system_args(p, base_many=True)
    p.add_argument("--speeds", default=None, metavar="START:STOP:STEP",
                   help="command speeds (rev/s); default: the motor's own, from half its "
                        "h=4 resonance to 1.25x its h=1 resonance (at most its top speed), "
                        "about 166 steps")
    p.add_argument("--entries", action="append", nargs="+", default=[], metavar="ENTRY",
                   help="sweep leaderboard entries (e.g. none tuned-constant-gain), each run "
                        "as stepdamp-bench v3 runs it: the drive identifies the motor first; "
                        "replaces --base-controller")
    p.add_argument("--policy", action="append", nargs="+", default=[], metavar="SPEC",
                   help="sweep a policy as `stepdamp leaderboard --policy` takes it (a model "
                        "`stepdamp train` wrote, DIR/best.zip, or module:attr); trusted files only")
    add_pool_run_args(p)
    renamed(p, "--damping", "--entries")
    p.set_defaults(func=_cmd_sweep)

    p = command("identify", "identify the detent model in servo mode (patent claim 1)")
    p.add_argument("--motor", default="patent",
                   help=f"preset ({', '.join(preset_names())}) or a motor .json file")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="FIELD=VALUE", help="override one parameter (SI units); repeatable")
    p.add_argument("--method", choices=("iterative", "least-squares"), default="iterative",
                   help="the patent's iteration, or one least-squares fit")
    p.add_argument("--noise-seed", type=number(int, 0, 2 ** 53 - 1), default=0,
                   help="current-sensor noise seed")
    renamed(p, "--seed", "--noise-seed")
    p.add_argument("--log", action="append", default=None, metavar="FILE.csv",
                   help="identify from drive logs instead of simulating: constant-speed "
                        "logs (columns in docs/drivelogs.md); --motor is then the prior "
                        "(R, L, Km, Nr, J, D); repeatable")
    p.add_argument("--log-method", choices=("torque-balance", "effort"),
                   default="torque-balance",
                   help="with --log: the rotor's torque balance sample by sample (any "
                        "mode), or the servo effort as patent claim 1 (servo logs)")
    p.add_argument("--settle", type=number(float, 0.0, 1e4), default=0.1, metavar="SECONDS",
                   help="with --log: the start of each log left out of the fit (s)")
    p.add_argument("--plan", nargs="?", const="", default=None, metavar="MOTOR",
                   help="print the drive logs to record for --log on MOTOR (or --motor): "
                        "speeds, durations, sampling; nothing is run")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="result directory (required unless --plan)")
    p.set_defaults(func=_cmd_identify)


def _cmd_sweep(args: argparse.Namespace) -> int:
    from ..io import write_json
    from ..plots import plot_sweep, plot_velocity_error_traces, trace_speeds
    from ..sweep import default_speed_range, parse_speed_range, prominent_peaks, run_sweep

    if args.speeds is not None:
        speeds = parse_speed_range(args.speeds)     # the arguments first, then the disk
    system = load_system(args.motor, parse_set_overrides(args.overrides))
    if args.speeds is None:
        args.speeds = default_speed_range(system)
        speeds = parse_speed_range(args.speeds)
        print(f"speeds {args.speeds} rev/s (the motor's resonances; --speeds to choose)")
    entries = [e for g in args.entries for e in g] + [p for g in args.policy for p in g]
    if entries:
        return _sweep_entries(args, system, speeds, entries)
    bases = list(dict.fromkeys(args.base_controller))
    settings = [run_settings(args, b) for b in bases]
    args.out = check_output_dir(args.out, "--out")
    backend = backend_map(args.backend, args.ray_address)
    results = [run_sweep(system, speeds, st, accel_rps2=args.accel, workers=args.workers,
                         backend=backend,
                         progress=not args.no_progress) for st in settings]
    names = ["sweep.json"] if len(results) == 1 else [f"sweep_{b}.json" for b in bases]
    with staged_directory(args.out, SWEEP_FILES) as stage:
        for name, result in zip(names, results):
            write_json(os.path.join(stage, name), result.to_dict())
        plot_sweep(results, os.path.join(stage, "sweep.png"))
        plot_velocity_error_traces(system, settings, trace_speeds(system, speeds),
                                   os.path.join(stage, "velocity_error_traces.png"),
                                   accel_rps2=args.accel)
    predicted = system.predicted_resonances_rps()
    print(f"motor {system.name}: {args.mode}, {len(speeds)} speeds "
          f"{speeds[0]:g}..{speeds[-1]:g} rev/s")
    for result in results:
        lost = int(np.sum(result.column("step_loss")))
        print(f"  {result.settings.base_controller}: step loss in {lost} of {len(speeds)} runs")
        for h, peak in result.peaks().items():
            where = f"h={h}: predicted {predicted[h]:.4f} rev/s, "
            if peak["is_resonance"]:
                step = resolving_spacing(system) * peak["speed_rps"]
                coarse = "" if peak["resolved"] else (
                    f" (coarse grid: a --speeds step of at most {step:.2g} rev/s would tell "
                    "it from an aliasing spike)" if step > 0 else
                    " (without damping D no grid tells it from an aliasing spike)")
                print(f"    {where}ripple peak at {peak['speed_rps']:.4f} rev/s "
                      f"({peak['relative_offset']:+.1%}), RMS {peak['ripple_rad_s']:.4g} rad/s"
                      + coarse)
            else:
                print(f"    {where}no resonance peak (highest RMS nearby "
                      f"{peak['ripple_rad_s']:.4g} rad/s at {peak['speed_rps']:.4f} rev/s)")
        humps = prominent_peaks(speeds, result.column("rms_velocity_error_rad_s"))
        print("    peaks by prominence: " + (", ".join(
            f"{p['speed_rps']:.4g} rev/s ({p['prominence']:.2f}x{', lone' if p['lone'] else ''})"
            for p in humps) or "none"))
    print(f"wrote {', '.join(os.path.join(args.out, n) for n in names)}, "
          f"{os.path.join(args.out, 'sweep.png')}, "
          f"{os.path.join(args.out, 'velocity_error_traces.png')}")
    return 0


def _sweep_entries(args: argparse.Namespace, system: Any, speeds: np.ndarray,
                   entries: list[str]) -> int:
    """``sweep --entries``: each entry as stepdamp-bench v3 runs it."""
    from ..bench.entry_sweep import decibel_summary, plot_entry_sweeps, sweep_entry
    from ..bench.protocols.decibels import FAILURE_DB
    from ..bench.registry import default_policy_names
    from ..io import write_json

    if args.base_controller != ["none"] or args.estimate is not None:
        raise ParameterError("--entries/--policy: an entry brings its own base controller "
                             "and model; leave out --base-controller and --estimate")
    register_policies()
    named = default_policy_names()
    unknown = [e for e in entries if e not in named and ":" not in e
               and not e.endswith(".zip") and not os.path.isdir(e)]
    if unknown:
        raise ParameterError(f"--entries: unknown {unknown}; choose from {list(named)} "
                             "(or give a policy file with --policy)")
    args.out = check_output_dir(args.out, "--out")
    # The dB summary's reference: no damping, swept too where not asked for.
    order = list(dict.fromkeys(entries))
    with_none = order if "none" in order else ["none"] + order
    results = [sweep_entry(e, system, speeds, mode=args.mode, seed=args.noise_seed,
                           workers=args.workers, progress=not args.no_progress)
               for e in with_none]
    none = results[with_none.index("none")]
    summaries = [None if r is none else decibel_summary(r, none) for r in results]
    names = [f"sweep_{_file_stem(r.entry)}.json" for r in results]
    with staged_directory(args.out, SWEEP_FILES) as stage:
        for name, result, summary in zip(names, results, summaries):
            data = result.to_dict()
            if summary is not None:
                data["against_none"] = summary
            write_json(os.path.join(stage, name), data)
        plot_entry_sweeps(results, os.path.join(stage, "sweep.png"))
    predicted = system.predicted_resonances_rps()
    print(f"motor {system.name}: {args.mode}, {len(speeds)} speeds "
          f"{speeds[0]:g}..{speeds[-1]:g} rev/s; predicted resonances "
          + ", ".join(f"h={h}: {v:.3f}" for h, v in predicted.items()) + " rev/s")
    if "none" not in order:
        print("  (none, no damping, swept too: the reference of the dB figures)")
    for r, summary in zip(results, summaries):
        finite = r.ripple_rad_s[np.isfinite(r.ripple_rad_s)]
        print(f"  {r.entry}: lost steps in {int(r.failed.sum())} of {len(speeds)} runs; "
              f"RMS ripple mean {float(np.mean(finite)) if finite.size else math.nan:.4g} "
              "rad/s over the runs that held")
        if summary is not None and summary["speeds_scored"]:
            humps = summary["humps_rps"]
            print(f"    against none: mean {summary['mean_db']:+.1f} dB, median "
                  f"{summary['median_db']:+.1f} dB, worst {summary['worst_db']:+.1f} dB at "
                  f"{summary['worst_speed_rps']:.4g} rev/s over {summary['speeds_scored']} "
                  f"speeds (a lost run {FAILURE_DB:g} dB); "
                  + (f"HUMPS (ripple above none's by > {summary['hump_db']:g} dB) at "
                     + ", ".join(f"{v:.4g}" for v in humps) + " rev/s" if humps else
                     "no humps (nowhere above none's ripple by more than "
                     f"{summary['hump_db']:g} dB)"))
        for peak in r.peaks():
            h = min(predicted, key=lambda k: abs(predicted[k] / peak["speed_rps"] - 1))
            near = (f" (h={h} predicted {predicted[h]:.3f})"
                    if abs(predicted[h] / peak["speed_rps"] - 1) <= 0.15 else "")
            lone = " (one speed only: likely aliasing, not a resonance)" if peak["lone"] else ""
            print(f"    peak at {peak['speed_rps']:.4g} rev/s{near}: RMS {peak['ripple']:.4g} "
                  f"rad/s, {peak['prominence']:.2f}x above its surroundings{lone}")
        if not r.peaks():
            print("    no peak stands out (prominence below 1.5x)")
    print(f"wrote {', '.join(os.path.join(args.out, n) for n in names + ['sweep.png'])}")
    return 0


def _file_stem(spec: str) -> str:
    """A file-name part for an entry name or a policy path."""
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in spec).strip("_")[-60:]


def _cmd_simulate(args: argparse.Namespace) -> int:
    if args.trace is not None:
        if not args.trace.strip() or args.trace.endswith(os.sep):
            raise ParameterError(f"--trace {args.trace!r}: give a file name (FILE.npz or "
                                 "FILE.csv)")
        check_writable(args.trace, "--trace", directory=False)
    if not MIN_SPEED_RPS <= abs(args.speed):
        raise ParameterError(f"--speed {args.speed:g}: the ripple metrics are relative to a "
                             f"moving command; allowed {MIN_SPEED_RPS:g} <= |speed| <= "
                             f"{MAX_SPEED_RPS:g} rev/s")
    system = load_system(args.motor, parse_set_overrides(args.overrides))
    settings = run_settings(args)
    if args.move is not None:
        step_rev = 1.0 / (4 * system.motor.Nr)
        if abs(args.move) < step_rev:
            raise ParameterError(f"--move {args.move:g}: shorter than one full step, nothing to "
                                 f"measure; allowed |move| >= {step_rev:g} rev")
        profile = SpeedProfile(speed_rps=args.speed, accel_rps2=args.accel, kind="move",
                               ramp=args.ramp, distance_rev=args.move)
    else:
        if args.ramp != "trapezoid":
            raise ParameterError(f"--ramp {args.ramp}: only a --move has ramps to shape "
                                 "(a constant speed ramps at --accel)")
        profile = SpeedProfile(speed_rps=args.speed, accel_rps2=args.accel)
    # Bounded work, checked before anything runs: the run lasts at most --duration's cap.
    start, length = measuring_window(system, profile, settings)
    if not start < MAX_DURATION_S or (args.duration is None
                                      and not start + length <= MAX_DURATION_S):
        raise ParameterError(run_length_error(system, profile, settings, {
            "distance_rev": "--move", "speed_rps": "--speed", "accel_rps2": "--accel",
            "duration_s": "--duration"}))
    if args.duration is not None and not args.duration > start:
        raise ParameterError(f"--duration {args.duration:g}: must end after the measuring "
                             f"window opens at {start:.6g} s (ramp + settle): allowed "
                             f"({start:.6g}, {MAX_DURATION_S:g}] s")
    if args.trace is not None:
        # Memory estimated before any is allocated: the run's buffer, its copies and
        # the writer's (a CSV's text about twice the rest).
        per_row = (6 if args.trace.endswith(".csv") else 4) * TRACE_ROW_BYTES
        n_periods = round((args.duration or start + length) * system.drive.pwm_hz)
        check_trace_memory(n_periods, 1, system.drive.pwm_hz, row_bytes=per_row,
                           option=f"--trace {args.trace}", duration="--duration", every=None)
    result = simulate(system, profile=profile, settings=settings,
                      duration_s=args.duration, trace=args.trace is not None)
    if args.trace is not None and args.trace.endswith(".csv"):
        from ..drivelog import trace_table, write_trace

        write_trace(args.trace, trace_table(result), comments=[
            f"stepdamp simulate: motor {system.name}, mode {settings.mode}, speed "
            f"{args.speed:g} rev/s; columns and units: docs/drivelogs.md"])
    elif args.trace is not None:
        from ..io import write_npz
        from ..kernel import TRACE_UNITS

        write_npz(args.trace, **result.trace,
                  units=np.array(json.dumps({k: TRACE_UNITS[k] for k in result.trace})),
                  settings=np.array(json.dumps(_run_record(args, system, result))))
    out = _run_record(args, system, result)
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        for key, value in out.items():
            if key in ("parameters",):
                continue
            print(f"{key:28s} {fmt_value(value)}")
        if args.trace is not None:
            what = ("a drive log, docs/drivelogs.md" if args.trace.endswith(".csv")
                    else "units and settings inside")
            print(f"wrote {args.trace} (one row per PWM period; {what})")
    return 0


def _run_record(args: argparse.Namespace, system: Any, result: Any) -> dict[str, Any]:
    """What ``simulate`` reports: the run's settings and metrics (SI, JSON-ready)."""
    s = result.settings
    return {"motor": system.name, "mode": s.mode, "base_controller": s.base_controller,
            "speed_rps": result.profile.speed_rps, "accel_rps2": result.profile.accel_rps2,
            "move_rev": args.move, "profile": result.profile.kind,
            "ramp": result.profile.ramp, "substeps": s.substeps, "noise_seed": s.noise_seed,
            "duration_s": result.duration_s, "window_start_s": result.window_start_s,
            **{k: v for k, v in result.metrics.to_dict().items() if k != "speed_rps"},
            "parameters": system.to_dict()}


def _identified_name(name: str) -> str:
    """The identified motor's name: the motor's with a suffix, within the name bound."""
    suffix = "-identified"
    return name[:LIMITS.name_chars - len(suffix)] + suffix


def _cmd_identify(args: argparse.Namespace) -> int:
    from ..identify import identify
    from ..io import write_json

    if args.plan is not None:
        if args.log or args.out is not None:
            raise ParameterError("--plan prints the logs to record and runs nothing: give it "
                                 "without --log and --out")
        return _identify_plan(args)
    if args.out is None:
        raise ParameterError("--out DIR is required (unless --plan)")
    args.out = check_output_dir(args.out, "--out")
    system = load_system(args.motor, parse_set_overrides(args.overrides))
    if args.log:
        return _identify_logs(args, system)
    result = identify(system, method=args.method, noise_seed=args.noise_seed)
    model = result.model
    identified = system.replace(Kd1=model.Kd1, Kd2=model.Kd2, Kd4=model.Kd4,
                                phi1=model.phi1, phi2=model.phi2, Fs=model.Fs)
    motor_file = {**identified.to_dict(), "name": _identified_name(system.name),
                  "source": f"stepdamp identify --method {args.method} on {system.name}"}
    with staged_directory(args.out, IDENTIFY_FILES) as stage:
        write_json(os.path.join(stage, "identified_motor.json"), motor_file)
        write_json(os.path.join(stage, "identification.json"),
                   {"motor": system.name, **result.to_dict(),
                    "truth": {k: getattr(system.motor, k)
                              for k in ("Kd1", "Kd2", "Kd4", "phi1", "phi2", "Fs", "D")}})
    m = system.motor
    print(f"motor {system.name}: {args.method}, {result.iterations} round(s) at "
          f"{', '.join(f'{v:g}' for v in result.speeds_rps)} rev/s")
    print(f"  {'':6s} {'identified':>12s} {'truth':>12s} {'error':>9s}")
    for name in ("Kd1", "Kd2", "Kd4", "Fs"):
        print(f"  {name:6s} {getattr(model, name):12.6g} {getattr(m, name):12.6g} "
              f"{result.errors[name]:+9.2%}")
    for name in ("phi1", "phi2"):
        print(f"  {name:6s} {getattr(model, name):12.6g} {getattr(m, name):12.6g} "
              f"{result.errors[name]:+9.4f} rad")
    print(f"wrote {os.path.join(args.out, 'identified_motor.json')}, "
          f"{os.path.join(args.out, 'identification.json')}")
    return 0


def _identify_plan(args: argparse.Namespace) -> int:
    """``identify --plan``: the logs to record for ``identify --log``."""
    from ..logfit import DEFAULT_SETTLE_S
    from ..logplan import PRIOR_J_UNCERTAINTY, log_plan

    motor = args.plan or args.motor
    system = load_system(motor, parse_set_overrides(args.overrides))
    plan = log_plan(system, settle_s=args.settle)
    print(f"drive logs to record for {system.name} (the prior): its h=4 resonance is at "
          f"{plan.f4_rps:.4g} rev/s (J {system.motor.J:.4g} kg*m^2 from the prior)")
    for k, (v, d) in enumerate(zip(plan.speeds_rps, plan.durations_s)):
        print(f"  {k + 1}. {v:.4g} rev/s, {d:.3g} s from when it reaches the speed")
    print("  each at constant speed in open loop, either direction; columns time_s, "
          "position_rad, phase_current_a_A, phase_current_b_A (docs/drivelogs.md)")
    stick = [str(k + 1) for k, s in enumerate(plan.servo_stick_slip) if s]
    print("  open loop: on the catalogue's real motors servo logs identified the detent less "
          "well (docs/drivelogs.md)"
          + (f"; in servo this motor stalls and reverses (stick-slip) at log "
             f"{', '.join(stick)} in simulation, which biases the fit by tens of per cent"
             if stick else ""))
    print(f"  sample at {plan.min_sample_rate_hz:.4g} Hz or faster (once per PWM period is best)")
    print("  below the resonance the harmonics hardly depend on J, and three distinct "
          "speeds give J, D and Fs apart; above it J trades against them, and with one "
          f"speed J is the prior's (+-{PRIOR_J_UNCERTAINTY:.0%} assumed)")
    logs = " ".join(f"--log log{k + 1}.csv" for k in range(len(plan.speeds_rps)))
    extra = "".join(f" --set {shlex.quote(o)}" for o in args.overrides)
    if args.settle != DEFAULT_SETTLE_S:
        extra += f" --settle {args.settle:g}"
    print(f"then: stepdamp identify --motor {shlex.quote(motor)}{extra} {logs} --out DIR")
    return 0


def _identify_logs(args: argparse.Namespace, system: Any) -> int:
    """``identify --log``: the detent model from drive logs, ``system`` the prior."""
    from ..logfit import identify_from_logs
    from ..io import write_json

    result = identify_from_logs(system, args.log, method=args.log_method,
                                settle_s=args.settle)
    identified = result.apply_to(system, mechanics=True)
    prior = [n for n in ("J", "D") if n not in result.fitted]
    motor_file = {**identified.to_dict(), "name": _identified_name(system.name),
                  "source": f"stepdamp identify --log-method {args.log_method} on "
                            + ", ".join(args.log),
                  "notes": "fitted from the logs: Kd1, Kd2, Kd4, phi1, phi2, Fs"
                           + "".join(f", {n}" for n in result.fitted)
                           + (f"; from the prior motor {system.name!r}: "
                              + ", ".join(prior) if prior else "")
                           + "; every other value is the prior's"}
    with staged_directory(args.out, IDENTIFY_FILES) as stage:
        write_json(os.path.join(stage, "identified_motor.json"), motor_file)
        write_json(os.path.join(stage, "identification.json"),
                   {"motor": system.name, **result.to_dict()})
    model, m = result.model, system.motor
    print(f"motor {system.name} (prior): {args.log_method} on {len(args.log)} log(s)")
    for fit in result.logs:
        print(f"  {fit.label}: {fit.speed_rps:.4g} rev/s, {fit.electrical_periods:.1f} "
              f"electrical periods, residual {fit.residual_rms_a:.3g} A "
              f"({fit.residual_fraction:.1%})")
    unc = result.uncertainty
    print(f"  {'':6s} {'identified':>12s} {'+- (1 sd)':>10s} {'':>6s} {'prior':>12s}")
    for name in ("Kd1", "Kd2", "Kd4", "phi1", "phi2", "Fs"):
        rel = (f"{result.relative_uncertainty(name):6.1%}" if name not in ("phi1", "phi2")
               else "   rad")
        print(f"  {name:6s} {getattr(model, name):12.6g} {unc[name]:10.3g} {rel} "
              f"{getattr(m, name):12.6g}")
    for name in ("J", "D"):
        value = getattr(result, name)
        u = (f"{unc[name]:10.3g} {result.relative_uncertainty(name):6.1%}" if name in unc
             else f"{'':10s} {'':6s}")
        print(f"  {name:6s} {value:12.6g} {u} {getattr(m, name):12.6g}"
              + ("" if name in result.fitted else " (prior; +- assumed)" if name in unc
                 else " (prior)"))
    print(f"  residual {result.residual_rms_a:.3g} A ({result.residual_fraction:.1%} of the "
          "current's RMS)")
    for w in result.warnings:
        print(f"warning: {w}")
    print(f"wrote {os.path.join(args.out, 'identified_motor.json')}, "
          f"{os.path.join(args.out, 'identification.json')}")
    return 0


def motor_record(description: Any) -> dict[str, Any]:
    """What ``stepdamp motors --json`` prints for one motor (SI units; speeds rev/s)."""
    from ..analysis import bridge_limit_rps, midband

    system = description.system
    parameters = system.to_dict()
    parameters.setdefault("drive_mode", system.drive.drive_mode)
    bands = {mode: midband(system.replace(drive_mode=mode)) for mode in ("current", "voltage")}
    return {"name": system.name, "source": description.source, "parameters": parameters,
            "derived": system.derived_dict(),
            "resonances_rps": {str(h): v for h, v in
                               sorted(system.predicted_resonances_rps().items())},
            "midband_rps": {m: (list(b.unstable_rps) if b.unstable_rps else None)
                            for m, b in bands.items()},
            "max_speed_rps": bridge_limit_rps(system),
            "assumed": description.assumed}


def _cmd_motors(args: argparse.Namespace) -> int:
    from ..motorfile import describe_spec

    specs = args.motors or list(preset_names())
    records = [motor_record(d) for spec in specs for d in describe_spec(spec)]
    if args.json:
        print(json.dumps(records, indent=2))
        return 0
    for r in records:
        p = r["parameters"]
        res = r["resonances_rps"]
        print(f"{r['name']} ({r['source']})")
        print(f"  R {p['R']:.4g} Ohm, L {p['L']:.4g} H, Km {p['Km']:.4g} N*m/A, Nr {p['Nr']}, "
              f"J {p['J']:.4g} kg*m^2, D {p['D']:.4g} N*m*s/rad, Kd1/Kd2/Kd4 "
              f"{p['Kd1']:.3g}/{p['Kd2']:.3g}/{p['Kd4']:.3g} N*m, Fs {p['Fs']:.3g} N*m")
        print(f"  holding current {p['holding_current']:.4g} A, Vdc {p['Vdc']:.4g} V, "
              f"encoder {p['encoder_cpr']} counts/rev, drive mode {p['drive_mode']}")
        top = r["max_speed_rps"]
        print("  resonances " + ", ".join(f"h={h}: {res[h]:.3f}" for h in ("4", "2", "1"))
              + f" rev/s; top speed the bus allows {top:.2f} rev/s (bridge circle Vdc/sqrt(2))")
        print("  mid-band " + "; ".join(
            f"{m}: " + (f"{b[0]:.2f}-{b[1]:.2f} rev/s" if b else "none")
            + (" (reaches past the top speed: the linear analysis holds below it)"
               if b and b[1] > top else "")
            for m, b in r["midband_rps"].items()))
        if top <= 0.0:
            print(f"  warning: R * holding current = {p['R'] * p['holding_current']:.3g} V "
                  f"already exceeds the bridge circle Vdc/sqrt(2) = "
                  f"{p['Vdc'] / math.sqrt(2.0):.3g} V: the drive cannot push the holding "
                  "current at any speed")
        if r["assumed"]:
            print("  assumed (not in the file): " + ", ".join(
                f"{k}={fmt_value(v)}" for k, v in r["assumed"].items()))
    return 0


def _cmd_analyse(args: argparse.Namespace) -> int:
    from ..analysis import midband

    motors = args.motor or list(preset_names())
    overrides = parse_set_overrides(args.overrides)
    if "drive_mode" in overrides:
        raise ParameterError("--set drive_mode: analyse prints both drive modes; leave it out")
    rows = []
    for spec in motors:
        base = load_system(spec, overrides)
        for mode in ("current", "voltage"):
            rows.append(midband(base.replace(drive_mode=mode)))
    if args.json:
        print(json.dumps([r.to_dict() for r in rows], indent=2))
        return 0
    print("Predicted mid-band of the open-loop drive (linearised at constant speed, "
          "0.25-30 rev/s; current mode: its PI loops in continuous time, without the "
          "bridge's limit, so valid below the bridge circle):")
    for r in rows:
        band = (f"unstable {r.unstable_rps[0]:.2f}-{r.unstable_rps[1]:.2f} rev/s"
                if r.unstable_rps else "no unstable band")
        stall = f", no steady state from {r.stall_rps:.2f}" if r.stall_rps else ""
        print(f"{r.motor:24s} {r.drive_mode:8s} {band:30s} least damping ratio "
              f"{r.min_damping_ratio:+.4f} at {r.at_rps:.2f} rev/s; bridge circle at "
              f"{r.bridge_limit_rps:.2f} rev/s{stall}")
    return 0


