"""``stepdamp`` command line: sweep, simulate, identify, leaderboard, train, presets.

The composition root: the only module of ``stepdamp_env`` that imports the
baselines and the agents (``stepdamp_baselines``, ``stepdamp_agents``); it
registers their policies with the leaderboard before any command runs.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Sequence

import numpy as np

from .io import check_writable
from .params import (FeedforwardModel, ParameterError, load_system, parse_set_overrides,
                     preset_names)
from .simulation import (DAMPINGS, DEFAULT_ACCEL_RPS2, MODES, RunSettings, SpeedProfile,
                         simulate)

__all__ = ["main"]


def _add_system_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--motor", default="patent",
                   help=f"preset ({', '.join(preset_names())}) or a motor .json file")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="FIELD=VALUE", help="override one parameter (SI units); repeatable")
    p.add_argument("--mode", choices=sorted(MODES), default="open-loop")
    p.add_argument("--damping", choices=DAMPINGS, default="none")
    p.add_argument("--estimate", default=None, metavar="NAME|FILE.json",
                   help="motor whose Km, Kd1/2/4, phi1/2, Fs the feedforward uses "
                        "(default: the plant's own, i.e. exact)")
    p.add_argument("--accel", type=float, default=DEFAULT_ACCEL_RPS2, metavar="RPS2",
                   help="command acceleration of the start-up ramp (rev/s^2)")
    p.add_argument("--substeps", type=int, default=1,
                   help="RK4 plant steps per PWM period")
    p.add_argument("--velocity-estimator", choices=("lowpass", "kalman"), default="lowpass",
                   help="servo velocity estimate: differenced encoder through a low-pass "
                        "(the patent's) or a steady-state Kalman filter")
    p.add_argument("--noise-seed", type=int, default=0, help="current-sensor noise seed")


def _settings(args: argparse.Namespace, system) -> RunSettings:
    estimate = None
    if args.estimate is not None:
        estimate = FeedforwardModel.from_motor(load_system(args.estimate).motor)
    return RunSettings(mode=args.mode, damping=args.damping, substeps=args.substeps,
                       estimate=estimate, velocity_estimator=args.velocity_estimator,
                       noise_seed=args.noise_seed)


def _cmd_sweep(args: argparse.Namespace) -> int:
    from .io import write_json
    from .plots import plot_sweep, plot_velocity_error_traces, trace_speeds
    from .sweep import parse_speed_range, run_sweep

    check_writable(args.out, "--out", directory=True)
    system = load_system(args.motor, parse_set_overrides(args.overrides))
    settings = _settings(args, system)
    speeds = parse_speed_range(args.speeds)
    result = run_sweep(system, speeds, settings, accel_rps2=args.accel,
                       workers=args.workers, progress=not args.no_progress)
    os.makedirs(args.out, exist_ok=True)
    write_json(os.path.join(args.out, "sweep.json"), result.to_dict())
    plot_sweep([result], os.path.join(args.out, "sweep.png"))
    plot_velocity_error_traces(system, settings, trace_speeds(system, speeds),
                               os.path.join(args.out, "velocity_error_traces.png"),
                               accel_rps2=args.accel)
    predicted = system.predicted_resonances_rps()
    print(f"motor {system.name}: {args.mode}, {args.damping}, {len(speeds)} speeds")
    for h, peak in result.peaks().items():
        print(f"  h={h}: predicted {predicted[h]:.4f} rev/s, ripple peak at "
              f"{peak['speed_rps']:.4f} rev/s ({peak['relative_offset']:+.1%}), "
              f"RMS {peak['ripple_rad_s']:.4g} rad/s")
    lost = int(np.sum(result.column("step_loss")))
    print(f"  step loss in {lost} of {len(speeds)} runs; wrote {args.out}/sweep.json, "
          "sweep.png, velocity_error_traces.png")
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    if args.trace is not None:
        check_writable(args.trace, "--trace", directory=False)
    system = load_system(args.motor, parse_set_overrides(args.overrides))
    settings = _settings(args, system)
    if args.move is not None:
        profile = SpeedProfile(speed_rps=args.speed, accel_rps2=args.accel, kind="move",
                               distance_rev=args.move)
    else:
        profile = SpeedProfile(speed_rps=args.speed, accel_rps2=args.accel)
    result = simulate(system, profile=profile, settings=settings,
                      duration_s=args.duration, trace=args.trace is not None)
    if args.trace is not None:
        from .io import write_npz

        write_npz(args.trace, **result.trace)
    out = {"motor": system.name, "mode": settings.mode, "damping": settings.damping,
           "duration_s": result.duration_s, "window_start_s": result.window_start_s,
           **result.metrics.to_dict()}
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        for key, value in out.items():
            if isinstance(value, float):
                value = f"{value:.6g}"
            print(f"{key:28s} {value}")
    return 0


def _cmd_identify(args: argparse.Namespace) -> int:
    from .identify import identify
    from .io import write_json

    check_writable(args.out, "--out", directory=True)
    system = load_system(args.motor, parse_set_overrides(args.overrides))
    result = identify(system, method=args.method, noise_seed=args.seed)
    model = result.model
    identified = system.replace(Kd1=model.Kd1, Kd2=model.Kd2, Kd4=model.Kd4,
                                phi1=model.phi1, phi2=model.phi2, Fs=model.Fs)
    motor_file = {**identified.to_dict(), "name": f"{system.name}-identified",
                  "source": f"stepdamp identify --method {args.method} on {system.name}"}
    os.makedirs(args.out, exist_ok=True)
    write_json(os.path.join(args.out, "identified_motor.json"), motor_file)
    write_json(os.path.join(args.out, "identification.json"),
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
    print(f"  wrote {args.out}/identified_motor.json, identification.json")
    return 0


def _cmd_presets(args: argparse.Namespace) -> int:
    for name in preset_names():
        system = load_system(name)
        res = system.predicted_resonances_rps()
        print(f"{name:24s} wn = {system.natural_frequency():7.1f} rad/s, resonances "
              + ", ".join(f"h={h}: {v:.3f}" for h, v in res.items()) + " rev/s")
    return 0


def _register_policies() -> None:
    import stepdamp_agents
    import stepdamp_baselines

    stepdamp_baselines.register_policies()
    stepdamp_agents.register_policies()


def _cmd_leaderboard(args: argparse.Namespace) -> int:
    from .bench import (SUITES, default_policy_names, full_protocol, quick_protocol,
                        run_leaderboard, write_outputs)
    from .bench.report import format_summary

    check_writable(args.out, "--out", directory=True)
    _register_policies()
    protocol = quick_protocol() if args.quick else full_protocol()
    suites = SUITES if args.suite == "all" else (args.suite,)
    protocol = protocol.with_suites(suites)
    named = default_policy_names()
    baselines = list(named) if args.baselines is None else \
        [b for group in args.baselines for b in group]
    unknown = sorted(set(baselines) - set(named))
    if unknown:
        raise ParameterError(f"--baselines: unknown {unknown}; choose from {list(named)}")
    extra = [p for group in args.policy for p in group]
    board = run_leaderboard(protocol, baselines + extra, workers=args.workers,
                            progress=not args.no_progress)
    written = write_outputs(board, args.out, protocol, plots=not args.no_plots)
    for suite in protocol.suites:
        print(f"{protocol.name} {protocol.version} ({protocol.variant}), {suite}:")
        rows = sorted((e for e in board["entries"] if e["suite"] == suite),
                      key=lambda e: e["rank"])
        for e in rows:
            print(f"  {e['rank']:2d}. {e['name']:28s} headline IQM "
                  f"{format_summary(e['headline']):28s} step losses "
                  f"{e['step_losses']['runs_lost']}/{e['step_losses']['runs']}")
    print("wrote " + ", ".join(written))
    return 0


def _cmd_train(args: argparse.Namespace) -> int:
    from stepdamp_agents.train import args_from_namespace, train

    train(args_from_namespace(args))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="stepdamp", description=__doc__)
    from .version import __version__

    parser.add_argument("--version", action="version", version=f"stepdamp {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("sweep", help="ripple against command speed (resonance sweep)")
    _add_system_args(p)
    p.add_argument("--speeds", default="0.2:3.5:0.02", metavar="START:STOP:STEP",
                   help="command speeds in rev/s")
    p.add_argument("--out", required=True, metavar="DIR")
    p.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_cmd_sweep)

    p = sub.add_parser("simulate", help="one run; prints its metrics")
    _add_system_args(p)
    p.add_argument("--speed", type=float, required=True, metavar="RPS",
                   help="command speed (rev/s); the top speed of a --move")
    p.add_argument("--move", type=float, default=None, metavar="REV",
                   help="point-to-point move of this many revolutions instead of constant speed")
    p.add_argument("--duration", type=float, default=None, metavar="SECONDS",
                   help="default: ramp + settle + measuring window")
    p.add_argument("--trace", default=None, metavar="FILE.npz",
                   help="write one sample per PWM period")
    p.add_argument("--json", action="store_true", help="print the metrics as JSON")
    p.set_defaults(func=_cmd_simulate)

    p = sub.add_parser("identify", help="identify the detent model in servo mode (claim 1)")
    p.add_argument("--motor", default="patent",
                   help=f"preset ({', '.join(preset_names())}) or a motor .json file")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="FIELD=VALUE", help="override one parameter (SI units); repeatable")
    p.add_argument("--method", choices=("iterative", "least-squares"), default="iterative")
    p.add_argument("--seed", type=int, default=0, help="current-sensor noise seed")
    p.add_argument("--out", required=True, metavar="DIR")
    p.set_defaults(func=_cmd_identify)

    p = sub.add_parser("leaderboard", help="run the stepdamp-bench v0 protocol on the "
                                           "baselines and given policies")
    p.add_argument("--quick", action="store_true",
                   help="reduced CI protocol: presets, one seed, resonant speeds, 0.1 s window")
    p.add_argument("--policy", action="append", nargs="+", default=[], metavar="SPEC",
                   help="extra policy: package.module:attr or path/file.py:attr (Policy "
                        "class, factory or instance), a model `stepdamp train` wrote "
                        "(DIR/best.zip) or an SB3 .zip; repeatable. These run code when "
                        "loaded: use trusted sources only")
    p.add_argument("--baselines", action="append", nargs="+", default=None, metavar="NAME",
                   help="run only these baselines and reference agents (default: all; "
                        "'none' always runs)")
    p.add_argument("--suite", choices=["open-loop", "servo", "all"], default="all")
    p.add_argument("--out", required=True, metavar="DIR")
    p.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--no-plots", action="store_true", help="skip the figures")
    p.set_defaults(func=_cmd_leaderboard)

    p = sub.add_parser("train", help="train a residual RL agent (SAC, TD3, PPO) on "
                                     "StepperDamp-v0; see agents/train.py")
    from stepdamp_agents.train import add_arguments

    add_arguments(p)
    p.set_defaults(func=_cmd_train)

    p = sub.add_parser("presets", help="list the motor presets")
    p.set_defaults(func=_cmd_presets)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except ParameterError as exc:
        print(f"stepdamp: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
