"""``plant-bound`` (privileged): stepdamp-bench v4's bound, a law chosen per run
on the true plant.

v3's ``privileged-bound`` runs one law per suite, tuned on v3's dev motors; on
motors far from them (an unloaded catalogue motor, a 0.9-degree rotor) its gain
is wrong and it scores below no damping. A bound may use the true plant: before
each run, ``plant-bound`` runs every law of :data:`PORTFOLIO` on the same true
plant, mode, suite, command speed, ramp and measuring window (settling, window,
lag limit: ``PolicyContext``) with a private sensor-noise seed
(:data:`SELECTION_SEED`, never an evaluation seed), and keeps the law whose run
held and had the smallest velocity-error RMS over its window (a tie goes to the
first in the portfolio). Then it runs that law.

The laws, each on ``privileged-bound``'s decision rate and feedforward of the
suite (``stepdamp_baselines.feedback.PRIVILEGED_SETTINGS``: 5 kHz; the exact
model through the true current path in open loop and servo, none in the
mid-band), read the true state:

* ``("zeta", z)``: oracle-floor's law designed for an added damping ratio ``z``
  at the true holding-spring frequency, softened at the rotor's load angle;
* ``("kv", k)``: feedback on the true speed error only,
  ``i = k * 2*J*wn/Km * e_w`` (A, wn of the unloaded spring: a gain scale),
  which needs no model of the loop's mode and so also damps where wn is not it
  (servo: the rotor moves in the servo loop).

**The harmonic table.** On top of the chosen law it then learns, on the same
true plant and seed, a table of harmonic torque (h = 1, 2, 4 of the drive's
angle, N*m) that cancels the periodic ripple the law leaves (the voltage-mode
drive's mid-band leaves ripple at the detent's second harmonic that no law
above removes). It measures each harmonic's response: the velocity error's
lock-in phasor (``RunMetrics.harmonic_phasor_rad_s``) with each sine and
cosine coefficient probed by :data:`PROBE_SHARE` of the action's scale; then
``table_steps`` times (2) it sets the table to zero each harmonic's phasor by
that response (a 2x2 solve per harmonic). The table is kept if its
rehearsal has less velocity ripple than the law alone (iterative learning
control on the true plant; no drive has it).

In open loop the feedforward and the design take the rotor's static lag from
all the torque it holds: friction, viscous drag and the load torque
(oracle-floor's exact model leaves the load out). A law that cannot run on
a motor (``ParameterError``) is not chosen.

The choice is a pure function of what the rehearsal reads (the plant, the
exact and nominal models, mode, suite, speed, ramp, measuring window, the
action's scales and the portfolio): it is cached per process, so the
evaluation seeds of one cell share one choice and a board's numbers do not
depend on how its runs are spread over workers, and kept on disk
(:class:`stepdamp_env.bench.kept.KeptResults`, docs/caches.md), so a later board
reads it back instead of rehearsing again.
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Any, Mapping, Sequence

import numpy as np

from stepdamp_env import fixedmath as fm
from stepdamp_env.bench.kept import KeptResults
from stepdamp_env.bench.policy import PolicyCard, PolicyContext
from stepdamp_env.bench.runner import EpisodeSpec, run_episodes
from stepdamp_env.params import DETENT_HARMONICS, ParameterError, SystemParams
from stepdamp_env.response import current_path, phasors

from .feedback import PrivilegedBound
from .harmonic import harmonic_actions

__all__ = ["PlantBound", "PortfolioLaw", "PORTFOLIO", "SELECTION_SEED", "PROBE_SHARE"]

Law = tuple[str, float]

#: The laws ``plant-bound`` chooses from (module docstring), in tie-break order.
#: Chosen on v4's dev split: of nine laws (zeta 0, 0.05, 0.1, 0.5, 2; kv 0.05,
#: 0.2, 0.5, 1), leaving out zeta 0 and kv 0.2 costs at most 0.08 dB of
#: rehearsed ripple on each of its 336 cells; the best six leave one cell
#: 1.2 dB worse (scripts/bound_portfolio.py).
PORTFOLIO: tuple[Law, ...] = (
    ("zeta", 0.05), ("zeta", 0.1), ("zeta", 0.5), ("zeta", 2.0),
    ("kv", 0.05), ("kv", 0.5), ("kv", 1.0))
#: The sensor-noise seed of the selection runs: outside every seed a board
#: evaluates on (``stepdamp_env.bench.protocols.v4.evaluation_seeds``).
SELECTION_SEED = 2**31 - 1

#: The harmonic table's probe: a share of the action's scale (N*m).
PROBE_SHARE = 0.25

_CHOICES: dict[tuple[Any, ...], tuple[Law, tuple[float, ...] | None]] = {}


def _key(context: PolicyContext) -> tuple[Any, ...]:
    """Everything a rehearsal reads (the frozen models compare by value)."""
    k = context.knowledge
    return (k.plant, k.exact, k.nominal, context.mode, context.suite,
            float(context.speed_rps), float(context.accel_rps2), float(context.agent_hz),
            float(context.action_scale), float(context.current_scale_a), context.window_s,
            context.settle_s, context.lag_limit_steps, context.profile,
            float(context.distance_rev), context.ramp)


class PortfolioLaw(PrivilegedBound):
    """One law of the portfolio (``("zeta", z)`` or ``("kv", k)``, module
    docstring), run as ``plant-bound`` runs it; ``tables``: a harmonic torque
    table (N*m: s1, c1, s2, c2, s4, c4 at the drive's angle) added to its
    feedforward per run, by :func:`_key` of the run's context."""

    def __init__(self, law: Law,
                 tables: Mapping[tuple[Any, ...], Sequence[float]] | None = None) -> None:
        super().__init__()
        self.law = law
        self.tables = dict(tables or {})
        self.name = f"plant-bound[{law[0]}={law[1]:g}]"

    def _zeta(self, context: PolicyContext) -> float:
        return self.law[1] if self.law[0] == "zeta" else 0.0

    @staticmethod
    def load_angle(context: PolicyContext, system: SystemParams) -> float:
        """Nr*delta (rad): how far the rotor trails its open-loop command in
        electrical angle while it holds its constant torque, friction, viscous
        drag and load, on the spring ``Km*I*sin(Nr*delta)`` (0 outside open loop;
        below 0 where the load drives the rotor ahead)."""
        if context.mode != "open-loop":
            return 0.0
        m = system.motor
        sign = 1.0 if context.speed_rps >= 0.0 else -1.0
        torque = m.Fs + m.D * 2.0 * math.pi * abs(context.speed_rps) + m.load_torque * sign
        s = max(-1.0, min(1.0, torque / (m.Km * system.drive.holding_current)))
        return fm.atan2(s, math.sqrt(1.0 - s * s))

    def _feedforward(self, context: PolicyContext, system: SystemParams) -> np.ndarray:
        """The exact detent model through the true current path, with the rotor's
        static lag from all the torque it holds (:meth:`load_angle`;
        oracle-floor's exact model takes friction and drag alone, linearised)."""
        model = context.knowledge.exact
        m = system.motor
        w = 2.0 * math.pi * abs(context.speed_rps)
        lag = self.load_angle(context, system) / m.Nr
        g = np.array([current_path(system, h * m.Nr * w) * fm.cexp(1j * h * m.Nr * lag)
                      for h in DETENT_HARMONICS])
        base = phasors(model)
        return harmonic_actions(base / g, base, context.action_scale)

    def _start(self, context: PolicyContext, system: SystemParams) -> float:
        """As oracle-floor's, with wn of the holding spring at the rotor's load
        angle: the spring softens by cos(Nr*delta) (open loop)."""
        wn = super()._start(context, system)
        c = fm.cos(self.load_angle(context, system))
        return wn * math.sqrt(max(c, 1e-6))

    def configure(self, context: PolicyContext) -> None:
        super().configure(context)
        if self.law[0] == "kv":
            plant = context.knowledge.plant
            m = plant.motor
            self.gains = (self.law[1] * 2.0 * m.J * plant.natural_frequency() / m.Km, 0.0)
        table = self.tables.get(_key(context))
        if table is not None:
            extra = np.asarray(table, dtype=np.float64) / context.action_scale
            self._action[:6] = np.clip(self._action[:6] + extra, -1.0, 1.0)


def _choice_from_json(content: Any) -> tuple[Law, tuple[float, ...] | None] | None:
    """A kept choice (law, table) as :class:`PlantBound` keeps it, or None if
    ``content`` is not one (then rehearsed again)."""
    try:
        kind, value = content["law"]
        table = content["table_nm"]
        law = (str(kind), float(value))
        if table is None:
            return law, None
        out = tuple(float(x) for x in table)
        return (law, out) if len(out) == 6 else None
    except (TypeError, KeyError, ValueError):
        return None


class _Rehearsal(PortfolioLaw):
    """Each run its own law and table (``plan``: ``id`` of the run's knowledge ->
    (law, table or None)): the rehearsals of many laws and tables step in one
    batch. Rows are independent, so each run's bits are those of its law run
    alone (``tests/test_plant_bound.py``)."""

    def __init__(self, plan: Mapping[int, tuple[Law, Sequence[float] | None]]) -> None:
        super().__init__(PORTFOLIO[0])
        self.plan = plan

    def configure(self, context: PolicyContext) -> None:
        self.law, table = self.plan[id(context.knowledge)]
        self.tables = {} if table is None else {_key(context): table}
        super().configure(context)


def _rehearse(specs: Sequence[EpisodeSpec], rows: Sequence[tuple[int, Law, Sequence[float] | None]],
              run: Mapping[str, Any]) -> list[Any]:
    """One batch: for each (spec index, law, table) of ``rows``, that spec run with
    that law and table. Each run gets its own copy of its knowledge (equal by value),
    by which :class:`_Rehearsal` finds its law."""
    plan: dict[int, tuple[Law, Sequence[float] | None]] = {}
    batch = []
    for i, law, table in rows:
        knowledge = dataclasses.replace(specs[i].knowledge)
        plan[id(knowledge)] = (law, table)
        batch.append(dataclasses.replace(specs[i], knowledge=knowledge))
    return run_episodes(lambda: _Rehearsal(plan), batch, **run)


class PlantBound(PortfolioLaw):
    """``plant-bound`` (privileged): per run, the best law of :data:`PORTFOLIO` on
    the true plant, with its harmonic table (module docstring). ``portfolio``:
    the laws to choose from; ``table_steps``: the table's corrections (0: no
    table); ``table_laws``: how many of the best laws get a table (the best
    with its table runs; on the dev split's mid-band, 3 instead of 1 gained
    0.5 dB for 60 % more time)."""

    card = PolicyCard(sensors="true state (position, speed)",
                      model="true plant (each law rehearsed on it per run)", oracle=True)

    def __init__(self, portfolio: Sequence[Law] = PORTFOLIO, table_steps: int = 2,
                 table_laws: int = 1) -> None:
        laws = tuple((str(kind), float(value)) for kind, value in portfolio)
        if not laws or any(kind not in ("zeta", "kv") or not (math.isfinite(value)
                                                              and value >= 0.0)
                           for kind, value in laws):
            raise ValueError(f"portfolio={portfolio!r}: one or more (kind, value), kind "
                             "'zeta' or 'kv', value finite and >= 0")
        for name, value in (("table_steps", table_steps), ("table_laws", table_laws)):
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 10:
                raise ValueError(f"{name}={value!r} is outside [0, 10] (integer)")
        super().__init__(laws[0])
        self.name = "plant-bound"
        self.portfolio = laws
        self.table_steps, self.table_laws = table_steps, table_laws

    def choice(self, context: PolicyContext) -> Law:
        """The law ``plant-bound`` runs in ``context`` (selected on first use)."""
        self._select([context])
        return _CHOICES[self._cache_key(context)][0]

    def table(self, context: PolicyContext) -> tuple[float, ...] | None:
        """The harmonic table (N*m) ``plant-bound`` adds in ``context``, or None."""
        self._select([context])
        return _CHOICES[self._cache_key(context)][1]

    def _cache_key(self, context: PolicyContext) -> tuple[Any, ...]:
        return (self.portfolio, self.table_steps, self.table_laws, *_key(context))

    def _select(self, contexts: Sequence[PolicyContext]) -> None:
        """Run the portfolio on the contexts whose choice is not yet known."""
        todo: dict[tuple[Any, ...], dict[tuple[Any, ...], PolicyContext]] = {}
        kept: KeptResults | None = None
        for c in contexts:
            if c.knowledge.plant is None:
                raise ValueError(f"{self.name} needs MotorKnowledge.plant (the true plant)")
            key = self._cache_key(c)
            if key in _CHOICES:
                continue
            if kept is None:
                kept = KeptResults("plant-bound", code_root=os.path.dirname(__file__))
            choice = _choice_from_json(kept.get(key))
            if choice is not None:
                _CHOICES[key] = choice
                continue
            todo.setdefault((c.mode, c.suite, float(c.accel_rps2), c.window_s,
                             c.lag_limit_steps), {})[key] = c
        for (mode, suite, accel, window_s, lag_limit), group in todo.items():
            keys = list(group)
            specs = [EpisodeSpec(group[k].knowledge, group[k].knowledge.plant,
                                 group[k].speed_rps, SELECTION_SEED, group[k].settle_s,
                                 profile=group[k].profile, distance_rev=group[k].distance_rev,
                                 ramp=group[k].ramp)
                     for k in keys]
            window = {} if window_s is None else {"window_s": window_s}
            run = dict(mode=mode, accel_rps2=accel, suite=suite, lag_limit_steps=lag_limit,
                       **window)
            # Per run, each law's (ripple, portfolio index, metrics) where it held.
            tried: list[list[tuple[float, int, dict[str, Any]]]] = [[] for _ in keys]
            for n_law, results in self._portfolio_runs(specs, run):
                for i, r in enumerate(results):
                    if not (r.failed or r.metrics is None):
                        tried[i].append((float(r.metrics["rms_velocity_error_rad_s"]), n_law,
                                         r.metrics))
            ranked = [sorted(t, key=lambda x: (x[0], x[1])) for t in tried]
            final = [(ranked[i][0][0], self.portfolio[ranked[i][0][1]], None) if ranked[i]
                     else (math.inf, self.portfolio[0], None) for i in range(len(keys))]
            for place in range(self.table_laws if self.table_steps else 0):
                laws = [self.portfolio[ranked[i][place][1]] if len(ranked[i]) > place
                        else self.portfolio[0] for i in range(len(keys))]
                held = [ranked[i][place][2] if len(ranked[i]) > place else None
                        for i in range(len(keys))]
                rms = [ranked[i][place][0] if len(ranked[i]) > place else math.inf
                       for i in range(len(keys))]
                got = self._tables([group[k] for k in keys], specs, laws, held, rms, run)
                for i, (table, table_rms) in enumerate(got):
                    if table is not None and table_rms < final[i][0]:
                        final[i] = (table_rms, laws[i], table)
            for k, (_, law, table) in zip(keys, final):
                _CHOICES[k] = (law, table)
                if kept is not None:
                    kept.put(k, {"law": list(law), "table_nm": None if table is None
                                 else list(table)})

    def _portfolio_runs(self, specs: Sequence[EpisodeSpec], run: Mapping[str, Any]
                        ) -> list[tuple[int, list[Any]]]:
        """(portfolio index, each spec's result) of every law that can run here: all
        laws in one batch, or, where one cannot (``ParameterError``), law by law,
        leaving out those that cannot."""
        n = len(specs)
        try:
            got = _rehearse(specs, [(i, law, None) for law in self.portfolio
                                    for i in range(n)], run)
            return [(k, got[k * n:(k + 1) * n]) for k in range(len(self.portfolio))]
        except ParameterError:
            pass
        out = []
        for k, law in enumerate(self.portfolio):
            try:
                out.append((k, _rehearse(specs, [(i, law, None) for i in range(n)], run)))
            except ParameterError:      # a law that cannot run here is not chosen
                continue
        return out

    def _tables(self, contexts: Sequence[PolicyContext], specs: Sequence[EpisodeSpec],
                chosen: Sequence[Law], held: Sequence[dict[str, Any] | None],
                best: Sequence[float], run: Mapping[str, Any]
                ) -> list[tuple[tuple[float, ...] | None, float]]:
        """Per run, the harmonic table that cancels the chosen law's remaining
        ripple at h = 1, 2, 4 (module docstring), or None where it does not
        lower the ripple, with the ripple it leaves. Each harmonic's response
        to a table is measured on the true plant (a probe of each sine and
        cosine coefficient), then ``table_steps`` corrections solve for its
        phasor's zero."""
        n = len(specs)
        todo = [i for i in range(n) if held[i] is not None]
        out: list[tuple[float, ...] | None] = [None] * n
        best = list(best)
        if not todo:
            return list(zip(out, best))

        def rehearse(tables: Mapping[int, Sequence[float]]) -> dict[int, Any]:
            """Each run of ``tables`` (index -> table) with its chosen law, in one batch."""
            rows = list(tables)
            return dict(zip(rows, _rehearse(specs, [(i, chosen[i], tables[i]) for i in rows],
                                            run)))

        def phasors(metrics: Mapping[str, Any]) -> list[float]:
            p = metrics["harmonic_phasor_rad_s"]
            return [float(x) for h in ("1", "2", "4") for x in p[h]]

        # The response: column j is d(phasors)/d(table[j]), one coefficient per
        # probe (probing the three harmonics together held the bound on 14 of the
        # dev split's 16 mid-band motors, one at a time on 15), on every run at once.
        base = {i: phasors(held[i]) for i in todo}
        delta = {i: PROBE_SHARE * contexts[i].action_scale for i in todo}
        response = {i: [[0.0] * 6 for _ in range(6)] for i in todo}
        probes = [(j, i) for j in range(6) for i in todo]
        lost = set()
        results = _rehearse(specs, [(i, chosen[i], tuple(delta[i] if m == j else 0.0
                                                         for m in range(6)))
                                    for j, i in probes], run)
        for (j, i), r in zip(probes, results):
            if r.failed or r.metrics is None:       # a probe it cannot take: no table
                lost.add(i)
                continue
            p = phasors(r.metrics)
            for m in range(6):
                response[i][m][j] = (p[m] - base[i][m]) / delta[i]
        todo = [i for i in todo if i not in lost]
        table = {i: [0.0] * 6 for i in todo}
        error = dict(base)
        for _ in range(self.table_steps):
            if not todo:
                break
            for i in todo:
                for h in range(3):      # each harmonic's 2x2 block (Cramer: the same bits anywhere)
                    (a, b), (c, d) = [response[i][2 * h + r][2 * h:2 * h + 2] for r in (0, 1)]
                    det = a * d - b * c
                    if det == 0.0 or not math.isfinite(det):
                        continue
                    e0, e1 = error[i][2 * h], error[i][2 * h + 1]
                    table[i][2 * h] -= (d * e0 - b * e1) / det
                    table[i][2 * h + 1] -= (a * e1 - c * e0) / det
            step = {i: tuple(table[i]) for i in todo}
            for i, r in rehearse(step).items():
                if r.failed or r.metrics is None:       # a table it cannot take: stop there
                    todo.remove(i)
                    continue
                error[i] = phasors(r.metrics)
                rms = float(r.metrics["rms_velocity_error_rad_s"])
                if rms < best[i]:
                    best[i], out[i] = rms, step[i]
        return list(zip(out, best))

    def reset_batch(self, contexts: Sequence[PolicyContext]) -> None:
        self._select(contexts)
        super().reset_batch(contexts)

    def configure(self, context: PolicyContext) -> None:
        self.law, table = _CHOICES[self._cache_key(context)]
        self.tables = {} if table is None else {_key(context): table}
        super().configure(context)
