"""The leaderboard's report: LEADERBOARD.md and the figures, written atomically."""

from __future__ import annotations

import os
from typing import Any, Mapping

import numpy as np

from .. import kernel as K
from ..io import atomic_path, write_json
from ..params import FeedforwardModel
from ..plots import pyplot, save_figure
from .motors import ProtocolMotor, protocol_motors
from .policy import MotorKnowledge
from .protocol import REFERENCE_POLICY, Protocol
from .registry import resolve_policy
from .runner import episode_window, run_episode

__all__ = ["format_summary", "render_markdown", "plot_ripple", "plot_resonance_traces", "trace_run",
           "write_outputs"]


def format_summary(s: Mapping[str, Any]) -> str:
    """``IQM [low, high]`` to four significant digits; the IQM alone where the
    interval has no width (one run per motor, as in ``--quick``): there is none."""
    lo, hi = s["ci95"]
    if not lo < hi:
        return f"{s['iqm']:#.4g} (no interval)"
    return f"{s['iqm']:#.4g} [{lo:#.4g}, {hi:#.4g}]"


def render_markdown(board: Mapping[str, Any]) -> str:
    """``LEADERBOARD.md``: one ranked table per suite."""
    p = board["protocol"]
    lines = [f"# Leaderboard: {p['name']} {p['version']} ({p['variant']})", "",
             f"{len(p['motors'])} motors x {len(p['eval_seeds'])} seeds; "
             f"window {p['window_s']} s, ramp {p['accel_rps2']} rev/s^2, current noise "
             f"{p['current_noise_a']} A, encoder {p['encoder_cpr']} counts/rev.",
             "Headline: mean RMS velocity ripple at the three resonant speeds over that of "
             "`none` (lower is better); IQM over motors x seeds with a 95 % stratified "
             "bootstrap interval. `oracle` entries use the plant's exact detent model.", ""]
    for suite in p["suites"]:
        rows = sorted((e for e in board["entries"] if e["suite"] == suite),
                      key=lambda e: e["rank"])
        lines += [f"## {suite}", "",
                  "| rank | policy | headline IQM [95 % CI] | sweep mean ratio | "
                  "sweep worst (IQM / max) | step losses | RMS injected current (A) |",
                  "|---|---|---|---|---|---|---|"]
        for e in rows:
            name = e["name"] + (" (oracle)" if e.get("oracle") else "")
            sw = e["sweep_worst_ratio"]
            sl = e["step_losses"]
            lines.append(f"| {e['rank']} | {name} | {format_summary(e['headline'])} | "
                         f"{format_summary(e['sweep_mean_ratio'])} | "
                         f"{sw['iqm']:.4g} / {sw['max']:.4g} | {sl['runs_lost']}/{sl['runs']} | "
                         f"{e['rms_injected_current_a']['iqm']:.4g} |")
        lines.append("")
    v = board["versions"]
    lines.append("Versions: " + ", ".join(f"{k} {val}" for k, val in v.items()))
    return "\n".join(lines) + "\n"


def _representative(board: Mapping[str, Any]) -> tuple[str, int]:
    p = board["protocol"]
    return p["motors"][0]["name"], p["eval_seeds"][0]


def plot_ripple(board: Mapping[str, Any], suite: str, path: str) -> None:
    """RMS ripple against speed per entry, for the representative motor and seed."""
    plt = pyplot()
    motor, seed = _representative(board)
    info = board["protocol"]["motors"][0]
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for e in sorted((e for e in board["entries"] if e["suite"] == suite), key=lambda e: e["rank"]):
        rs = sorted((r for r in e["runs"] if r["motor"] == motor and r["seed"] == seed
                     and r["metrics"] is not None), key=lambda r: r["speed_rps"])
        ax.semilogy([r["speed_rps"] for r in rs],
                    [r["metrics"]["rms_velocity_error_rad_s"] for r in rs], marker="o",
                    label=e["name"])
    for h, v in info["predicted_resonances_rps"].items():
        ax.axvline(v, color="grey", ls="--", lw=0.8)
        ax.text(v, 1.0, f" h={h}", transform=ax.get_xaxis_transform(), va="top",
                fontsize=8, color="grey")
    ax.set_xlabel("command speed (rev/s)")
    ax.set_ylabel("RMS velocity error (rad/s)")
    ax.set_title(f"{suite}: {motor}, seed {seed}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def trace_run(spec: str, motor: ProtocolMotor, knowledge: MotorKnowledge, suite: str,
              speed_rps: float, seed: int, protocol: Protocol, span_s: float = 0.1
              ) -> tuple[np.ndarray, np.ndarray]:
    """(time in the window (s), velocity error w_cmd - w (rad/s)) at the agent rate,
    over the first ``span_s`` of the measuring window."""

    def sample(env: Any, obs: np.ndarray, start: float) -> tuple[float, float] | None:
        if env.time_s < start:
            return None
        s = env.drive_state
        return env.time_s - start, s[K.S_OMEGA_CMD] - s[K.S_OMEGA]

    start, _ = episode_window(motor.system, speed_rps, protocol.accel_rps2, protocol.window_s)
    result = run_episode(resolve_policy(spec).make(), knowledge, motor.system, mode=suite,
                         speed_rps=speed_rps, seed=seed, accel_rps2=protocol.accel_rps2,
                         window_s=protocol.window_s, until_s=start + span_s, on_step=sample)
    rows = np.asarray(result.trace, dtype=float).reshape(-1, 2)
    return rows[:, 0], rows[:, 1]


def plot_resonance_traces(board: Mapping[str, Any], suite: str, path: str,
                          protocol: Protocol) -> None:
    """Velocity error against time at the three resonances: none vs the best entry
    (patent Figs. 4-7 style), representative motor and seed."""
    rows = sorted((e for e in board["entries"] if e["suite"] == suite), key=lambda e: e["rank"])
    best = next((e for e in rows if e["spec"] != REFERENCE_POLICY), None)
    specs = [(REFERENCE_POLICY, REFERENCE_POLICY)] + ([(best["spec"], best["name"])] if best else [])
    motors = protocol_motors(protocol)
    motor = motors[0]
    seed = protocol.eval_seeds[0]
    ident = next(x["model"] for x in board["identification"]
                 if x["motor"] == motor.name and x["seed"] == seed)
    knowledge = MotorKnowledge(nominal=motor.nominal,
                               identified=FeedforwardModel(**ident) if ident else None,
                               exact=FeedforwardModel.from_motor(motor.system.motor))
    res = motor.system.predicted_resonances_rps()
    plt = pyplot()
    fig, axes = plt.subplots(len(res), 1, figsize=(8, 6.5), sharex=True, squeeze=False)
    for ax, (h, v) in zip(axes[:, 0], res.items()):
        for spec, name in specs:
            t, err = trace_run(spec, motor, knowledge, suite, v, seed, protocol)
            ax.plot(t * 1e3, err, lw=0.8, label=name)
        ax.set_ylabel("rad/s", fontsize=8)
        ax.text(0.99, 0.92, f"h={h}: {v:.3g} rev/s", transform=ax.transAxes, ha="right",
                va="top", fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(fontsize=8, loc="upper left")
    axes[-1, 0].set_xlabel("time in the measuring window (ms; sampled at the agent rate)")
    fig.suptitle(f"Velocity error w_cmd - w at the resonances: {motor.name}, {suite}",
                 fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def write_outputs(board: Mapping[str, Any], out_dir: str, protocol: Protocol,
                  plots: bool = True) -> list[str]:
    """Write leaderboard.json, LEADERBOARD.md and the figures (atomically)."""
    os.makedirs(out_dir, exist_ok=True)
    written = [os.path.join(out_dir, "leaderboard.json"), os.path.join(out_dir, "LEADERBOARD.md")]
    write_json(written[0], board)
    with atomic_path(written[1]) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(render_markdown(board))
    if plots:
        for suite in board["protocol"]["suites"]:
            p1 = os.path.join(out_dir, f"ripple_vs_speed_{suite}.png")
            p2 = os.path.join(out_dir, f"velocity_error_resonances_{suite}.png")
            plot_ripple(board, suite, p1)
            plot_resonance_traces(board, suite, p2, protocol)
            written += [p1, p2]
    return written
