"""``stepdamp`` command line: sweep, simulate, identify, leaderboard, report, train, presets.

The composition root: the only module of ``stepdamp_env`` that imports the
baselines and the agents (``stepdamp_baselines``, ``stepdamp_agents``); it
registers their policies with the leaderboard before any command runs. Every
user mistake ends with exit status 2 and one line naming the option; Ctrl-C
with one line and status 130. Output directories are written as a whole
(:func:`stepdamp_env.io.staged_directory`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
from typing import Any, Sequence

import numpy as np

from . import numba_cache
from .io import check_output_dir, check_writable, output_lock, staged_directory
from .parallel import WorkerLostError
from .ray_backend import backend_map
from .limits import LIMITS
from .params import FeedforwardModel, ParameterError, load_system, parse_set_overrides
from .presets import preset_names
from .simulation import (BASE_CONTROLLERS, DEFAULT_ACCEL_RPS2, MAX_DURATION_S, MIN_ACCEL_RPS2,
                         MODES, TRACE_ROW_BYTES, RunSettings, SpeedProfile, check_trace_memory,
                         measuring_window, run_length_error, simulate)
from .sweep import MAX_SPEED_RPS, MIN_SPEED_RPS, resolving_spacing

__all__ = ["main"]


DESCRIPTION = """\
StepperDamp: simulate a hybrid stepper drive, measure its velocity ripple and
rank damping policies (stepdamp-bench). SI units unless named: speeds in rev/s,
accelerations in rev/s^2. `stepdamp COMMAND --help` lists a command's options."""

SWEEP_FILES = ("sweep.json", "sweep_*.json", "sweep.png", "velocity_error_traces.png")
IDENTIFY_FILES = ("identified_motor.json", "identification.json")


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the description's line breaks; appends an option's default unless its
    help already says it or there is none to state."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if "default" in text or action.default in (None, False, argparse.SUPPRESS, []) \
                or not action.option_strings:
            return text
        default = action.default
        if isinstance(default, (list, tuple)):
            default = " ".join(map(str, default))
        return f"{text} (default: {default})"


def _number(kind: type, low: float | None = None, high: float | None = None,
            low_open: bool = False, name: str = "") -> Any:
    """An argparse type: a finite ``kind`` in [low, high] (low excluded if
    ``low_open``); the message names the range."""

    def bounds() -> str:
        lo = "-inf" if low is None else f"{low:g}"
        hi = "inf" if high is None else f"{high:g}"
        return f"{'(' if low_open or low is None else '['}{lo}, {hi}{')' if high is None else ']'}"

    def parse(text: str) -> Any:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number; allowed {bounds()}") \
                from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} is not finite; allowed {bounds()}")
        if kind is int:
            if value != int(value):
                raise argparse.ArgumentTypeError(f"{text!r} is not an integer; allowed {bounds()}")
            value = int(value)
        if (low is not None and (value < low or (low_open and value == low))) or \
                (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"{text} is outside the allowed range {bounds()}")
        return value

    parse.__name__ = name or kind.__name__
    return parse


def _add_system_args(p: argparse.ArgumentParser, *, base_many: bool = False) -> None:
    p.add_argument("--motor", default="patent",
                   help=f"preset ({', '.join(preset_names())}) or a motor .json file")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="FIELD=VALUE",
                   help="override one parameter (SI units, see `stepdamp presets`); repeatable")
    p.add_argument("--mode", choices=sorted(MODES), default="open-loop",
                   help="open-loop microstepping or encoder servo")
    if base_many:
        p.add_argument("--base-controller", choices=BASE_CONTROLLERS, nargs="+",
                       default=["none"], help="the drive's own controller: the patent's "
                       "feedforward, or none; several are overlaid on one figure")
    else:
        p.add_argument("--base-controller", choices=BASE_CONTROLLERS, default="none",
                       help="the drive's own controller: the patent's feedforward, or none")
    p.add_argument("--estimate", default=None, metavar="NAME|FILE.json",
                   help="motor whose Km, Kd1/2/4, phi1/2, Fs the feedforward uses "
                        "(default: the plant's own, i.e. exact)")
    p.add_argument("--accel", type=_number(float, MIN_ACCEL_RPS2, 1e6), default=DEFAULT_ACCEL_RPS2,
                   metavar="RPS2", help="command acceleration of the start-up ramp (rev/s^2)")
    p.add_argument("--substeps", type=_number(int, 1, 1000), default=1,
                   help="RK4 plant steps per PWM period (a system too stiff for one is "
                        "refused with the number it needs)")
    p.add_argument("--velocity-estimator", choices=("lowpass", "kalman"), default="lowpass",
                   help="servo velocity estimate: differenced encoder through a low-pass "
                        "(the patent's) or a steady-state Kalman filter")
    p.add_argument("--noise-seed", type=_number(int, 0, 2 ** 53 - 1), default=0,
                   help="current-sensor noise seed")


def _settings(args: argparse.Namespace, base: str | None = None) -> RunSettings:
    estimate = None
    if args.estimate is not None:
        estimate = FeedforwardModel.from_motor(load_system(args.estimate).motor)
    return RunSettings(mode=args.mode, base_controller=base or args.base_controller,
                       substeps=args.substeps,
                       estimate=estimate, velocity_estimator=args.velocity_estimator,
                       noise_seed=args.noise_seed)


def _cmd_sweep(args: argparse.Namespace) -> int:
    from .io import write_json
    from .plots import plot_sweep, plot_velocity_error_traces, trace_speeds
    from .sweep import parse_speed_range, prominent_peaks, run_sweep

    speeds = parse_speed_range(args.speeds)     # the arguments first, then the disk
    system = load_system(args.motor, parse_set_overrides(args.overrides))
    entries = [e for g in args.damping for e in g] + [p for g in args.policy for p in g]
    if entries:
        return _sweep_entries(args, system, speeds, entries)
    bases = list(dict.fromkeys(args.base_controller))
    settings = [_settings(args, b) for b in bases]
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
    """``sweep --damping``: each entry as stepdamp-bench v3 runs it."""
    from .bench.entry_sweep import plot_entry_sweeps, sweep_entry
    from .bench.registry import default_policy_names
    from .io import write_json

    if args.base_controller != ["none"] or args.estimate is not None:
        raise ParameterError("--damping/--policy: an entry brings its own base controller "
                             "and model; leave out --base-controller and --estimate")
    _register_policies()
    named = default_policy_names()
    unknown = [e for e in entries if e not in named and ":" not in e
               and not e.endswith(".zip") and not os.path.isdir(e)]
    if unknown:
        raise ParameterError(f"--damping: unknown {unknown}; choose from {list(named)} "
                             "(or give a policy file with --policy)")
    args.out = check_output_dir(args.out, "--out")
    results = [sweep_entry(e, system, speeds, mode=args.mode, seed=args.noise_seed,
                           workers=args.workers, progress=not args.no_progress)
               for e in dict.fromkeys(entries)]
    names = [f"sweep_{_file_stem(r.entry)}.json" for r in results]
    with staged_directory(args.out, SWEEP_FILES) as stage:
        for name, result in zip(names, results):
            write_json(os.path.join(stage, name), result.to_dict())
        plot_entry_sweeps(results, os.path.join(stage, "sweep.png"))
    predicted = system.predicted_resonances_rps()
    print(f"motor {system.name}: {args.mode}, {len(speeds)} speeds "
          f"{speeds[0]:g}..{speeds[-1]:g} rev/s; predicted resonances "
          + ", ".join(f"h={h}: {v:.3f}" for h, v in predicted.items()) + " rev/s")
    for r in results:
        finite = r.ripple_rad_s[np.isfinite(r.ripple_rad_s)]
        print(f"  {r.entry}: lost steps in {int(r.failed.sum())} of {len(speeds)} runs; "
              f"RMS ripple mean {float(np.mean(finite)) if finite.size else math.nan:.4g} "
              "rad/s over the runs that held")
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


def _cmd_export(args: argparse.Namespace) -> int:
    from .bench.firmware import entry_law, export_law, firmware_knowledge

    system = load_system(args.motor, parse_set_overrides(args.overrides))
    _register_policies()
    law = entry_law(args.entry, firmware_knowledge(system), mode=args.mode,
                    speed_rps=args.speed)
    check_writable(args.out, "--out", directory=True)
    paths = export_law(law, args.format, args.out, args.prefix)
    print(f"{args.entry} on {system.name}, {args.mode} at {law.speed_rps:.4g} rev/s: "
          f"{len(law.harmonics)} harmonics, velocity gain {law.velocity_gain_a_s_per_rad:.4g} "
          f"A*s/rad; wrote {', '.join(paths)}")
    return 0


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
    settings = _settings(args)
    if args.move is not None:
        step_rev = 1.0 / (4 * system.motor.Nr)
        if abs(args.move) < step_rev:
            raise ParameterError(f"--move {args.move:g}: shorter than one full step, nothing to "
                                 f"measure; allowed |move| >= {step_rev:g} rev")
        profile = SpeedProfile(speed_rps=args.speed, accel_rps2=args.accel, kind="move",
                               distance_rev=args.move)
    else:
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
        from .drivelog import trace_table, write_trace

        write_trace(args.trace, trace_table(result), comments=[
            f"stepdamp simulate: motor {system.name}, mode {settings.mode}, speed "
            f"{args.speed:g} rev/s; columns and units: docs/drivelogs.md"])
    elif args.trace is not None:
        from .io import write_npz
        from .kernel import TRACE_UNITS

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
            print(f"{key:28s} {_fmt(value)}")
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
            "move_rev": args.move, "substeps": s.substeps, "noise_seed": s.noise_seed,
            "duration_s": result.duration_s, "window_start_s": result.window_start_s,
            **{k: v for k, v in result.metrics.to_dict().items() if k != "speed_rps"},
            "parameters": system.to_dict()}


def _fmt(value: Any) -> str:
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.6g}"
    if isinstance(value, dict):
        return ", ".join(f"{k}: {_fmt(v)}" for k, v in value.items())
    return str(value)


def _identified_name(name: str) -> str:
    """The identified motor's name: the motor's with a suffix, within the name bound."""
    suffix = "-identified"
    return name[:LIMITS.name_chars - len(suffix)] + suffix


def _cmd_identify(args: argparse.Namespace) -> int:
    from .identify import identify
    from .io import write_json

    args.out = check_output_dir(args.out, "--out")
    system = load_system(args.motor, parse_set_overrides(args.overrides))
    if args.log:
        return _identify_logs(args, system)
    result = identify(system, method=args.method, noise_seed=args.seed)
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


def _identify_logs(args: argparse.Namespace, system: Any) -> int:
    """``identify --log``: the detent model from drive logs, ``system`` the prior."""
    from .drivelog import identify_from_logs
    from .io import write_json

    result = identify_from_logs(system, args.log, method=args.log_method,
                                settle_s=args.settle)
    identified = result.apply_to(system)
    motor_file = {**identified.to_dict(), "name": _identified_name(system.name),
                  "source": f"stepdamp identify --log-method {args.log_method} on "
                            + ", ".join(args.log)}
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
    print(f"  {'':6s} {'identified':>12s} {'prior':>12s}")
    for name in ("Kd1", "Kd2", "Kd4", "phi1", "phi2", "Fs"):
        print(f"  {name:6s} {getattr(model, name):12.6g} {getattr(m, name):12.6g}")
    print(f"  {'J':6s} {result.J:12.6g} {m.J:12.6g}" + ("" if "J" in result.fitted
                                                         else " (prior)"))
    print(f"  {'D':6s} {result.D:12.6g} {m.D:12.6g}" + ("" if "D" in result.fitted
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
    from .analysis import bridge_limit_rps, midband

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
    from .motorfile import describe_spec

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
                f"{k}={_fmt(v)}" for k, v in r["assumed"].items()))
    return 0


def _cmd_analyse(args: argparse.Namespace) -> int:
    from .analysis import midband

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


def _register_policies() -> None:
    import stepdamp_agents
    import stepdamp_baselines

    stepdamp_baselines.register_policies()
    stepdamp_agents.register_policies()


def _cmd_leaderboard(args: argparse.Namespace) -> int:
    from .bench import default_policy_names, run_leaderboard, write_outputs
    from .bench.protocols import protocol_class, protocol_for, protocol_versions
    from .bench.protocols.v1 import load_motors_file
    from .bench.report import RESULT_FILES, entry_line, entry_rows, render_per_motor, splits

    from .bench.leaderboard import (RESUME_DIR, clear_resume_dir, finish_resume_dir,
                                    open_resume_dir)

    args.out = check_output_dir(args.out, "--out", own_dirs=(RESUME_DIR,))
    protocol = protocol_for(args.protocol, quick=args.quick)
    if args.motors is not None:
        protocol = protocol.with_custom_motors(load_motors_file(args.motors, protocol))
    _register_policies()
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
                                backend=backend_map(args.backend, args.ray_address))
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
    from .bench.report import (load_leaderboard, render_ladder, render_markdown, render_results,
                               render_suite_page, scored_in_db, verify_fingerprint)

    path = os.path.join(args.dir, "leaderboard.json")
    if not os.path.isfile(path):
        raise ParameterError(f"DIR {args.dir!r} holds no leaderboard.json (write one with "
                             "`stepdamp leaderboard --out DIR`)")
    board = load_leaderboard(args.dir)
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
    from .bench.check import check_board

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


def _add_pool_run_args(p: argparse.ArgumentParser) -> None:
    """--out, --workers and --no-progress of the commands that run a process pool."""
    p.add_argument("--out", required=True, metavar="DIR",
                   help="result directory (replaced as a whole when the run is done)")
    p.add_argument("--workers", type=_number(int, 1, 4096), default=None,
                   help="processes (default: every core)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    _add_backend_args(p)


def _add_backend_args(p: argparse.ArgumentParser) -> None:
    """--backend and --ray-address (``stepdamp train`` has them too)."""
    p.add_argument("--backend", choices=("local", "ray"), default="local",
                   help="where the runs go: this machine's process pool, or Ray (extra "
                        "[ray]; docs/performance.md, 'Running on a cluster (Ray)')")
    p.add_argument("--ray-address", default=None, metavar="ADDR",
                   help="with --backend ray: a running cluster ('auto' or HOST:PORT); "
                        "default: a local Ray on this machine's cores (loopback only)")


def build_parser() -> argparse.ArgumentParser:
    from .version import __version__

    parser = argparse.ArgumentParser(prog="stepdamp", description=DESCRIPTION,
                                     formatter_class=_Formatter)
    parser.add_argument("--version", action="version", version=f"stepdamp {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def command(name: str, text: str) -> argparse.ArgumentParser:
        return sub.add_parser(name, help=text, description=text, formatter_class=_Formatter)

    p = command("motors", "describe motors (presets or motor files): model values, "
                "resonances, mid-band, top speed and what a file left to defaults")
    p.add_argument("motors", nargs="*", metavar="NAME|FILE",
                   help="a preset or a motor .json file (a datasheet file, a model file or "
                        "a --motors list); default: every preset")
    p.add_argument("--json", action="store_true", help="print the records as JSON")
    p.set_defaults(func=_cmd_motors)
    p = sub.add_parser("presets", help="the same as `stepdamp motors` (older name)",
                       formatter_class=_Formatter)
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
    _add_system_args(p)
    p.add_argument("--speed", type=_number(float, -1000, 1000), required=True, metavar="RPS",
                   help="command speed (rev/s, signed); the top speed of a --move")
    p.add_argument("--move", type=_number(float, -1e6, 1e6), default=None, metavar="REV",
                   help="point-to-point move of this many revolutions, measured from its start "
                        "through its settling (default: constant speed)")
    p.add_argument("--duration", type=_number(float, 0, MAX_DURATION_S, low_open=True),
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
    _add_system_args(p, base_many=True)
    p.add_argument("--speeds", default="0.2:3.5:0.02", metavar="START:STOP:STEP",
                   help="command speeds (rev/s)")
    p.add_argument("--damping", action="append", nargs="+", default=[], metavar="ENTRY",
                   help="sweep leaderboard entries (e.g. none tuned-constant-gain), each run "
                        "as stepdamp-bench v3 runs it: the drive identifies the motor first; "
                        "replaces --base-controller")
    p.add_argument("--policy", action="append", nargs="+", default=[], metavar="SPEC",
                   help="sweep a policy as `stepdamp leaderboard --policy` takes it (a model "
                        "`stepdamp train` wrote, DIR/best.zip, or module:attr); trusted files only")
    _add_pool_run_args(p)
    p.set_defaults(func=_cmd_sweep)

    p = command("identify", "identify the detent model in servo mode (patent claim 1)")
    p.add_argument("--motor", default="patent",
                   help=f"preset ({', '.join(preset_names())}) or a motor .json file")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="FIELD=VALUE", help="override one parameter (SI units); repeatable")
    p.add_argument("--method", choices=("iterative", "least-squares"), default="iterative",
                   help="the patent's iteration, or one least-squares fit")
    p.add_argument("--seed", type=_number(int, 0, 2 ** 53 - 1), default=0,
                   help="current-sensor noise seed")
    p.add_argument("--log", action="append", default=None, metavar="FILE.csv",
                   help="identify from drive logs instead of simulating: constant-speed "
                        "logs (columns in docs/drivelogs.md); --motor is then the prior "
                        "(R, L, Km, Nr, J, D); repeatable")
    p.add_argument("--log-method", choices=("torque-balance", "effort"),
                   default="torque-balance",
                   help="with --log: the rotor's torque balance sample by sample (any "
                        "mode), or the servo effort as patent claim 1 (servo logs)")
    p.add_argument("--settle", type=_number(float, 0.0, 1e4), default=0.1, metavar="SECONDS",
                   help="with --log: the start of each log left out of the fit (s)")
    p.add_argument("--out", required=True, metavar="DIR", help="result directory")
    p.set_defaults(func=_cmd_identify)

    p = command("export", "write an entry's damping law for a drive's firmware: harmonic "
                "table, per-microstep table and gains as JSON, or C99 source and header")
    p.add_argument("entry", metavar="ENTRY",
                   help="a leaderboard entry with a fixed law (patent-ff-identified, "
                        "ff-delay-comp, calibrated-table, tuned-constant-gain)")
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
    p.add_argument("--speed", type=_number(float, 1e-3, 1e3), default=None, metavar="RPS",
                   help="held command speed the delay-compensated table is computed for "
                        "(rev/s; default: the motor's h=4 resonance)")
    p.add_argument("--prefix", default=None,
                   help="file and C symbol prefix (default: the entry's name, - as _)")
    p.add_argument("--out", default=".", metavar="DIR", help="output directory")
    p.set_defaults(func=_cmd_export)

    from .bench.protocols import DEFAULT_VERSION, known_suites, protocol_about, protocol_versions

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
                        "in each suite beside its knowledge (the README's table)")
    p.add_argument("--split", choices=["dev", "interpolation", "extrapolation"], default=None,
                   help="v3: run one split; 'dev' is the split for tuning, ablations and "
                        "model selection (never scored). Default: interpolation and "
                        "extrapolation")
    _add_pool_run_args(p)
    p.add_argument("--no-plots", action="store_true", help="skip the figures")
    p.add_argument("--no-resume", action="store_true",
                   help="run every batch again, ignoring the finished batches an interrupted "
                        "run left in DIR/.resume (a run resumes by default)")
    p.set_defaults(func=_cmd_leaderboard)

    p = command("report", "print a result table from a leaderboard directory")
    p.add_argument("dir", metavar="DIR", help="a directory `stepdamp leaderboard` wrote")
    p.add_argument("--suite", choices=[*known_suites(), "all"], default="all",
                   help="one suite's ranked table; 'all' (default): every entry's headline "
                        "in each suite beside its knowledge (the README's table)")
    p.add_argument("--full", action="store_true", help="the whole LEADERBOARD.md table")
    p.add_argument("--check", action="store_true",
                   help="re-run a sample of the board's cells here and say, per cell, whether "
                        "it reproduces bit for bit (exit status 1 if any does not)")
    p.add_argument("--sample", type=_number(int, 1, 100000), default=12, metavar="N",
                   help="cells --check re-runs, spread over every entry, suite and split")
    p.add_argument("--no-verify", action="store_true",
                   help="show a board whose numbers do not match its fingerprint (edited or "
                        "damaged files; by default that is an error)")
    p.set_defaults(func=_cmd_report)

    from stepdamp_agents.train import ALGO_CHOICES, add_arguments

    p = command("train", f"train residual RL agents ({', '.join(ALGO_CHOICES)}) on "
                "StepperDamp-v1 (or the v0 gain selector)")

    add_arguments(p)
    p.set_defaults(func=_cmd_train)
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
        # A second Ctrl-C during the interpreter's shutdown would print a traceback.
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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
