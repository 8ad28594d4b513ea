"""What the commands share: the help formatter, number options with their
ranges, the drive's options (motor, mode, controller, estimate, seeds), the
process-pool options, renamed flags and the registration of the baselines' and
agents' policies."""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np

from ..motorfile import load_system
from ..params import FeedforwardModel
from ..presets import preset_names
from ..simulation import BASE_CONTROLLERS, DEFAULT_ACCEL_RPS2, MIN_ACCEL_RPS2, MODES, RunSettings

__all__ = ["DESCRIPTION", "HelpFormatter", "number", "add_system_args", "run_settings",
           "add_pool_run_args", "add_backend_args", "register_policies", "fmt_value",
           "renamed"]

DESCRIPTION = """\
StepperDamp: simulate a hybrid stepper drive, measure its velocity ripple and
rank damping policies (stepdamp-bench). SI units unless named: speeds in rev/s,
accelerations in rev/s^2. `stepdamp COMMAND --help` lists a command's options."""


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
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


def number(kind: type, low: float | None = None, high: float | None = None,
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


def add_system_args(p: argparse.ArgumentParser, *, base_many: bool = False) -> None:
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
    p.add_argument("--accel", type=number(float, MIN_ACCEL_RPS2, 1e6), default=DEFAULT_ACCEL_RPS2,
                   metavar="RPS2", help="command acceleration of the start-up ramp (rev/s^2)")
    p.add_argument("--substeps", type=number(int, 1, 1000), default=1,
                   help="RK4 plant steps per PWM period (a system too stiff for one is "
                        "refused with the number it needs)")
    p.add_argument("--velocity-estimator", choices=("lowpass", "kalman"), default="lowpass",
                   help="servo velocity estimate: differenced encoder through a low-pass "
                        "(the patent's) or a steady-state Kalman filter")
    p.add_argument("--noise-seed", type=number(int, 0, 2 ** 53 - 1), default=0,
                   help="current-sensor noise seed")


def run_settings(args: argparse.Namespace, base: str | None = None) -> RunSettings:
    estimate = None
    if args.estimate is not None:
        estimate = FeedforwardModel.from_motor(load_system(args.estimate).motor)
    return RunSettings(mode=args.mode, base_controller=base or args.base_controller,
                       substeps=args.substeps,
                       estimate=estimate, velocity_estimator=args.velocity_estimator,
                       noise_seed=args.noise_seed)


def add_pool_run_args(p: argparse.ArgumentParser) -> None:
    """--out, --workers and --no-progress of the commands that run a process pool."""
    p.add_argument("--out", required=True, metavar="DIR",
                   help="result directory (replaced as a whole when the run is done)")
    p.add_argument("--workers", type=number(int, 1, 4096), default=None,
                   help="processes (default: every core)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    add_backend_args(p)


def add_backend_args(p: argparse.ArgumentParser) -> None:
    """--backend and --ray-address (``stepdamp train`` has them too)."""
    p.add_argument("--backend", choices=("local", "ray"), default="local",
                   help="where the runs go: this machine's process pool, or Ray (extra "
                        "[ray]; docs/performance.md, 'Running on a cluster (Ray)')")
    p.add_argument("--ray-address", default=None, metavar="ADDR",
                   help="with --backend ray: a running cluster ('auto' or HOST:PORT); "
                        "default: a local Ray on this machine's cores (loopback only)")


def register_policies() -> None:
    import stepdamp_agents
    import stepdamp_baselines

    stepdamp_baselines.register_policies()
    stepdamp_agents.register_policies()


def fmt_value(value: Any) -> str:
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.6g}"
    if isinstance(value, dict):
        return ", ".join(f"{k}: {fmt_value(v)}" for k, v in value.items())
    return str(value)


def renamed(p: argparse.ArgumentParser, old: str, new: str, since: str = "0.18.0") -> None:
    """``old`` is refused with one line naming ``new`` (kept for one release after
    ``since``, then dropped)."""

    class Renamed(argparse.Action):
        def __call__(self, parser: argparse.ArgumentParser, *_: Any) -> None:
            parser.exit(2, f"{parser.prog}: error: {old} was renamed to {new} in {since}\n")

    p.add_argument(old, nargs="*", action=Renamed, help=argparse.SUPPRESS)
