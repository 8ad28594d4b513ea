"""The board's figures in the style of the patent's Figs. 4-7: ripple against speed
per entry, the overview of the best entries, the traces at the resonant speeds and
the performance profile over motors."""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from .. import kernel as K
from ..params import FeedforwardModel
from ..plots import (POLICY_COLOURS, POLICY_MARKERS, finish_ripple_axes, finish_trace_axes,
                     legend_outside, mark_resonances, pyplot, save_figure)
from .leaderboard import protocol_knowledge
from .motors import ProtocolMotor, protocol_motors
from .policy import MotorKnowledge
from .protocol import REFERENCE_POLICY, SUITE_MODE, Protocol
from .registry import default_policy_names, resolve_policy
from .runner import episode_window, run_episode
from .tables import (PATENT_ENTRY, best_eligible, entry_rows, row_rank, score_label, scored_in_db,
                     suite_page)

__all__ = ["HIGHLIGHTED", "highlighted_rows", "plot_overview", "plot_performance_profile",
           "plot_resonance_traces", "plot_ripple", "policy_styles", "trace_run"]


def _representative(board: Mapping[str, Any]) -> tuple[str, int]:
    p = board["protocol"]
    return p["motors"][0]["name"], p["eval_seeds"][0]


def policy_styles(names: Sequence[str]) -> dict[str, tuple[str, str]]:
    """(colour, marker) per policy name, the same in every figure: registered
    default policies in registry order first, then the others sorted; ``none``
    is always black circles."""
    order = [n for n in default_policy_names() if n != REFERENCE_POLICY]
    order += sorted(set(names) - set(order) - {REFERENCE_POLICY})
    styles = {REFERENCE_POLICY: ("black", "o")}
    for k, name in enumerate(order):
        styles[name] = (POLICY_COLOURS[k % len(POLICY_COLOURS)],
                        POLICY_MARKERS[(k + k // len(POLICY_COLOURS)) % len(POLICY_MARKERS)])
    return styles


def _suite_rows(board: Mapping[str, Any], suite: str) -> list[Mapping[str, Any]]:
    """The suite's entries by rank, of the representative motor's split (v1)."""
    return [e for e in entry_rows(board, suite, board["protocol"]["motors"][0].get("split"))
            if not e.get("reference")]


def _first_model(runs: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """A learned entry's runs of its first training seed (all runs otherwise)."""
    seeds = sorted({r["training_seed"] for r in runs if "training_seed" in r})
    return [r for r in runs if r.get("training_seed") == (seeds[0] if seeds else None)]


#: Entries a ripple figure highlights at most (the reference line included).
HIGHLIGHTED = 6


def highlighted_rows(rows: Sequence[Mapping[str, Any]], reference: bool
                     ) -> list[Mapping[str, Any]]:
    """The rows a ripple figure draws in colour: ``none``, the patent's
    feedforward, then the best eligible entries, at most :data:`HIGHLIGHTED`
    lines with the reference's (if ``reference``)."""
    room = HIGHLIGHTED - int(reference)
    shown = [e for e in rows if e["spec"] in (REFERENCE_POLICY, PATENT_ENTRY)]
    shown += [e for e in sorted((e for e in rows if e.get("rank") is not None
                                 and not e.get("oracle") and e not in shown),
                                key=lambda e: e["rank"])][:max(room - len(shown), 0)]
    return shown[:room]


def plot_ripple(board: Mapping[str, Any], suite: str, path: str) -> None:
    """RMS ripple against speed for the representative motor and seed (a learned
    entry: its first training seed's model): ``none``, the patent's feedforward
    and the best eligible entries in colour (:func:`highlighted_rows`), every
    other entry as a thin grey line. Markers shrink with rank so that equal
    curves stay visible. Resonances are marked in open loop only (the servo loop
    has no peak there)."""
    plt = pyplot()
    motor, seed = _representative(board)
    info = board["protocol"]["motors"][0]
    rows = _suite_rows(board, suite)
    split = board["protocol"]["motors"][0].get("split")
    refs = [e for e in entry_rows(board, suite, split) if e.get("reference")]
    shown = highlighted_rows(rows, reference=bool(refs))
    styles = policy_styles([e["name"] for e in rows])
    fig, ax = plt.subplots(figsize=(9, 4.8))

    def curve(e: Mapping[str, Any]) -> tuple[list[float], list[float]]:
        rs = sorted((r for r in _first_model(e["runs"]) if r["motor"] == motor
                     and r["seed"] == seed and r["metrics"] is not None),
                    key=lambda r: r["speed_rps"])
        return ([r["speed_rps"] for r in rs],
                [r["metrics"]["rms_velocity_error_rad_s"] for r in rs])

    others = [e for e in rows if e not in shown]
    where = suite_page(suite) if scored_in_db(board) else "LEADERBOARD.md"
    for k, e in enumerate(others):
        ax.semilogy(*curve(e), color="0.75", lw=0.7, zorder=1,
                    label=f"{len(others)} other entries ({where})" if k == 0 else None)
    n = len(shown)
    shown.sort(key=lambda e: rows.index(e))
    for k, e in enumerate(shown):
        colour, marker = styles[e["name"]]
        ax.semilogy(*curve(e), color=colour, marker=marker, ms=4 + 1.2 * k, mfc="none",
                    lw=1.0, zorder=3 + n - k, label=f"{row_rank(e)}. {e['name']}")
    for e in refs:                                # v3: the motor without the phenomenon
        if e.get("reference"):
            rs = sorted((r for r in e["runs"] if r["motor"] == motor and r["seed"] == seed
                         and r["metrics"] is not None), key=lambda r: r["speed_rps"])
            ax.semilogy([r["speed_rps"] for r in rs],
                        [r["metrics"]["rms_velocity_error_rad_s"] for r in rs], "k--", lw=1.2,
                        zorder=2, label="reference (no phenomenon)")
    if suite == "open-loop":
        mark_resonances(ax, info["predicted_resonances_rps"])
    finish_ripple_axes(ax, f"{suite}: {motor}, seed {seed}")
    save_figure(fig, path)


def _knowledge(board: Mapping[str, Any], motor: ProtocolMotor, seed: int,
               protocol: Protocol) -> MotorKnowledge:
    ident = next(x["model"] for x in board["identification"]
                 if x["motor"] == motor.name and x["seed"] == seed)
    return protocol_knowledge(motor, seed, FeedforwardModel(**ident) if ident else None,
                              protocol)


#: The patent's method as a user has it (identified model), drawn in the overview.


def _best(board: Mapping[str, Any], suite: str) -> Mapping[str, Any] | None:
    """The best-ranked eligible entry other than the patent's own feedforward
    (:func:`best_eligible`)."""
    rows = _suite_rows(board, suite)
    return best_eligible(rows, skip=(PATENT_ENTRY,)) or best_eligible(rows)


def plot_overview(board: Mapping[str, Any], path: str, protocol: Protocol,
                  points: int = 41, suite: str = "open-loop") -> None:
    """The README's figure: RMS ripple against speed on the representative motor,
    undamped, the patent's feedforward and the best other entry, on one axis.

    ``points`` speeds, log-spaced from 0.6x the lowest to 1.3x the highest
    predicted resonance, each one run as the protocol runs it.
    """
    motor = protocol_motors(protocol)[0]
    seed = protocol.eval_seeds[0]
    knowledge = _knowledge(board, motor, seed, protocol)
    res = motor.system.predicted_resonances_rps()
    speeds = np.geomspace(0.6 * min(res.values()), 1.3 * max(res.values()), points)
    rows = _suite_rows(board, suite)
    by_spec = {e["spec"]: e for e in rows}
    shown = [by_spec[s] for s in (REFERENCE_POLICY, PATENT_ENTRY) if s in by_spec]
    best = _best(board, suite)
    if best is not None:
        shown.append(best)
    styles = policy_styles([e["name"] for e in rows])
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.5))
    for e in shown:
        ripple = []
        for v in speeds:
            r = run_episode(resolve_policy(e["spec"]).make(), knowledge, motor.system,
                            mode=suite, speed_rps=float(v), seed=seed,
                            accel_rps2=protocol.accel_rps2, window_s=protocol.window_s,
                            settle_s=motor.settle_s(suite),
                            lag_limit_steps=protocol.lag_limit())
            ripple.append(r.metrics["rms_velocity_error_rad_s"] if r.metrics and not r.failed
                          else math.nan)
        colour, marker = styles[e["name"]]
        ax.semilogy(speeds, ripple, color=colour, marker=marker, ms=4, mfc="none", lw=1.2,
                    label=f"{e['name']}\n({score_label(e)})")
    mark_resonances(ax, res)
    finish_ripple_axes(ax, f"Velocity ripple, {suite}: {motor.name}, seed {seed}")
    save_figure(fig, path)


def trace_run(spec: str, motor: ProtocolMotor, knowledge: MotorKnowledge, suite: str,
              speed_rps: float, seed: int, protocol: Protocol,
              span_s: float | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """(time in the window (s), velocity error w_cmd - w (rad/s)) at every PWM
    period of the measuring window (its first ``span_s`` if given)."""

    def sample(env: Any, obs: np.ndarray, start: float) -> np.ndarray:
        tr = env.step_trace
        return tr[tr[:, K.TRACE.T] >= start - 1e-12]

    start, length = episode_window(motor.system, speed_rps, protocol.accel_rps2,
                                   protocol.window_s, motor.settle_s(suite))
    result = run_episode(resolve_policy(spec).make(), knowledge, motor.system,
                         mode=SUITE_MODE[suite],
                         speed_rps=speed_rps, seed=seed, accel_rps2=protocol.accel_rps2,
                         window_s=protocol.window_s, settle_s=motor.settle_s(suite),
                         until_s=None if span_s is None else start + span_s,
                         lag_limit_steps=protocol.lag_limit(),
                         on_step=sample, pwm_trace=True)
    rows = np.concatenate(result.trace) if result.trace else np.zeros((0, len(K.TRACE)))
    end = start + (length if span_s is None else span_s)
    rows = rows[rows[:, K.TRACE.T] < end]
    return rows[:, K.TRACE.T] - start, rows[:, K.TRACE.OMEGA_CMD] - rows[:, K.TRACE.OMEGA]


def _speed_title(label: str) -> str:
    """A v1 speed label as a panel title: "h4" -> "h = 4 resonance", "s0.1" -> "0.1 x f4"."""
    if label.startswith("h"):
        return f"h = {label[1:]} resonance"
    if label.startswith("m"):
        return f"{label[1:]} through the predicted mid-band"
    return f"{label[1:]} x f4"


def _trace_subjects(board: Mapping[str, Any], suite: str, protocol: Protocol
                    ) -> tuple[list[Mapping[str, Any]], dict[str, Any], ProtocolMotor, int,
                               MotorKnowledge]:
    """What a trace figure shows: ``none`` and the best entry (and every row's
    style), on the representative motor as the suite runs it, its first
    evaluation seed and the knowledge the board's runs had."""
    rows = _suite_rows(board, suite)
    best = best_eligible(rows)
    shown = [e for e in rows if e["spec"] == REFERENCE_POLICY] + ([best] if best else [])
    styles = policy_styles([e["name"] for e in rows])
    motor = protocol_motors(protocol)[0].for_suite(suite)
    seed = protocol.eval_seeds[0]
    return shown, styles, motor, seed, _knowledge(board, motor, seed, protocol)


def plot_resonance_traces(board: Mapping[str, Any], suite: str, path: str,
                          protocol: Protocol) -> None:
    """Velocity error against time over the whole measuring window at the three
    resonant speeds (v1 servo: at its grid speeds), sampled every PWM period:
    ``none`` against the best entry (patent Figs. 4-7 style), representative
    motor and seed."""
    shown, styles, motor, seed, knowledge = _trace_subjects(board, suite, protocol)
    if motor.split is None:                 # v0: the three resonances, in both suites
        points = [(f"h = {h} resonance", v)
                  for h, v in motor.system.predicted_resonances_rps().items()]
    else:                                   # v1: the suite's headline speeds
        speeds, labels = motor.speeds(suite)
        points = [(_speed_title(lb), v) for v, lb in zip(speeds, labels)
                  if not lb.startswith("off")]        # v3: "off-..." too
    plt = pyplot()
    fig, axes = plt.subplots(len(points), 1, squeeze=False, sharex=motor.split is None,
                             figsize=(9, 7 if motor.split is None else 2.3 * len(points) + 0.4))
    for ax, (title, v) in zip(axes[:, 0], points):
        for e in shown:
            t, err = trace_run(e["spec"], motor, knowledge, suite, v, seed, protocol)
            what = f"RMS {float(np.sqrt(np.mean(err ** 2))):.3g} rad/s" if err.size else \
                "lost steps before the window"
            ax.plot(t * 1e3, err, lw=0.7, color=styles[e["name"]][0],
                    label=f"{e['name']} ({what})")
        finish_trace_axes(ax, "w_cmd - w (rad/s)", f"{title}: {v:.3g} rev/s", title_size=9)
    axes[-1, 0].set_xlabel("time in the measuring window (ms), one sample per PWM period")
    what = "the resonances" if suite == "open-loop" or motor.split is None else \
        {"servo": "the low-speed grid", "mid-band": "the mid-band (voltage mode)"}[suite]
    fig.suptitle(f"Velocity error at {what}: {motor.name}, {suite}, seed {seed}", fontsize=10)
    save_figure(fig, path)


def plot_move_traces(board: Mapping[str, Any], suite: str, path: str,
                     protocol: Protocol) -> None:
    """Velocity error against time through each move of a moves suite (v4), from
    the start to the end of the settling, sampled every PWM period: ``none``
    against the best entry, representative motor and seed; the cruise (the
    scored window) shaded."""
    shown, styles, motor, seed, knowledge = _trace_subjects(board, suite, protocol)
    speeds, labels = motor.speeds(suite)
    plt = pyplot()
    fig, axes = plt.subplots(len(speeds), 1, squeeze=False,
                             figsize=(9, 2.3 * len(speeds) + 0.4))
    for j, ax in enumerate(axes[:, 0]):
        command = protocol.run_command(motor, suite, j)
        cruise = None
        moving_until, trace_end = 0.0, 0.0
        for e in shown:
            def sample(env: Any, obs: np.ndarray, start: float) -> np.ndarray:
                return env.step_trace.copy()

            r = run_episode(resolve_policy(e["spec"]).make(), knowledge, motor.system,
                            mode=SUITE_MODE[suite], speed_rps=float(speeds[j]), seed=seed,
                            window_s=protocol.window_s, settle_s=motor.settle_s(suite),
                            lag_limit_steps=protocol.lag_limit(), suite=suite,
                            on_step=sample, pwm_trace=True, **command)
            tr = np.concatenate(r.trace) if r.trace else np.zeros((0, len(K.TRACE)))
            err = tr[:, K.TRACE.OMEGA_CMD] - tr[:, K.TRACE.OMEGA]
            what = "lost steps" if r.failed else \
                f"cruise RMS {r.metrics['rms_velocity_error_rad_s']:.3g} rad/s"
            ax.plot(tr[:, K.TRACE.T] * 1e3, err, lw=0.7, color=styles[e["name"]][0],
                    label=f"{e['name']} ({what})")
            cruise = (r.window_start_s, r.window_start_s + r.window_s)
            moving = np.flatnonzero(tr[:, K.TRACE.OMEGA_CMD] != 0.0)
            if moving.size:
                moving_until = max(moving_until, float(tr[moving[-1], K.TRACE.T]))
            if len(tr):
                trace_end = max(trace_end, float(tr[-1, K.TRACE.T]))
        if cruise is not None:
            ax.axvspan(cruise[0] * 1e3, cruise[1] * 1e3, color="0.9", zorder=0)
        if 0.0 < moving_until < trace_end:
            # The rest after the move is flat: show half the move's length of it.
            ax.set_xlim(0.0, min(trace_end, 1.5 * moving_until) * 1e3)
        finish_trace_axes(ax, "w_cmd - w (rad/s)",
                          f"{labels[j]}: cruise {speeds[j]:.3g} rev/s, "
                          f"{command['accel_rps2']:.3g} rev/s^2 "
                          f"({'peak' if command['ramp'] == 's-curve' else 'constant'})",
                          title_size=9)
    axes[-1, 0].set_xlabel("time from the move's start (ms), to half the move's length past "
                           "its end; shaded: the cruise (scored)")
    fig.suptitle(f"Velocity error through the moves: {motor.name}, seed {seed}", fontsize=10)
    save_figure(fig, path)


def plot_performance_profile(board: Mapping[str, Any], path: str) -> None:
    """Performance profiles (v1): per suite and split, the fraction of an entry's
    cells whose headline is at or below tau, against tau (log axis); higher and
    further left is better. Oracles dashed, ``none`` (1 everywhere) left out."""
    p = board["protocol"]
    panels = [(suite, split) for suite in p["suites"] for split in p["splits"]]
    names = sorted({e["name"] for e in board["entries"]})
    styles = policy_styles(names)
    plt = pyplot()
    fig, axes = plt.subplots(len(p["suites"]), len(p["splits"]), squeeze=False,
                             figsize=(5.2 * len(p["splits"]) + 2.6, 3.6 * len(p["suites"])))
    for ax, (suite, split) in zip(axes.ravel(), panels):
        rows = [e for e in entry_rows(board, suite, split) if e["name"] != REFERENCE_POLICY]
        values = [np.sort([s["headline"] for s in e["scores"]]) for e in rows]
        finite = np.concatenate([v[np.isfinite(v)] for v in values] + [np.zeros(0)])
        if not finite.size:             # no entry scored here (e.g. `none` lost every run)
            finite = np.ones(1)
            ax.text(0.5, 0.5, "no scores in this suite and split", transform=ax.transAxes,
                    ha="center", fontsize=8)
        taus = np.geomspace(max(finite.min() * 0.8, 1e-4), max(finite.max() * 1.25, 1.1), 300)
        for e, v in zip(rows, values):
            colour, marker = styles[e["name"]]
            frac = np.searchsorted(v, taus, side="right") / max(v.size, 1)
            ax.semilogx(taus, frac, color=colour, lw=1.3, ls="--" if e.get("oracle") else "-",
                        marker=marker, ms=3, markevery=(names.index(e["name"]) * 7 % 30, 30),
                        label=f"{e['name']} ({score_label(e)})")
        ax.set_title(f"{suite}, {split}", fontsize=9, loc="left")
        ax.set_xlabel("headline tau (ripple over undamped)")
        ax.set_ylabel("fraction of cells <= tau")
        ax.set_ylim(-0.02, 1.02)
        ax.grid(True, which="both", alpha=0.3)
        legend_outside(ax, fontsize=6)
    fig.suptitle(f"Performance profiles, {p['name']} {p['version']} ({p['variant']}): "
                 "legend gives the IQM", fontsize=10)
    save_figure(fig, path)
