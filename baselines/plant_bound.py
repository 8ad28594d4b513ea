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
  at the true holding-spring frequency, softened at the rotor's load angle
  (``z = 0``: the feedforward alone);
* ``("kv", k)``: feedback on the true speed error only,
  ``i = k * 2*J*wn/Km * e_w`` (A, wn of the unloaded spring: a gain scale),
  which needs no model of the loop's mode and so also damps where wn is not it
  (servo: the rotor moves in the servo loop).

In open loop the feedforward and the design take the rotor's static lag from
all the torque it holds: friction, viscous drag and the load torque
(oracle-floor's exact model leaves the load out). A law that cannot run on
a motor (``ParameterError``) is not chosen.

The choice is a pure function of what the rehearsal reads (the plant, the
exact and nominal models, mode, suite, speed, ramp, measuring window, the
action's scales and the portfolio): it is cached per process, so the
evaluation seeds of one cell share one choice and a board's numbers do not
depend on how its runs are spread over workers.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from stepdamp_env import fixedmath as fm
from stepdamp_env.bench.policy import PolicyCard, PolicyContext
from stepdamp_env.bench.runner import EpisodeSpec, run_episodes
from stepdamp_env.params import DETENT_HARMONICS, ParameterError, SystemParams
from stepdamp_env.response import current_path, phasors

from .feedback import PrivilegedBound
from .harmonic import harmonic_actions

__all__ = ["PlantBound", "PortfolioLaw", "PORTFOLIO", "SELECTION_SEED"]

Law = tuple[str, float]

#: The laws ``plant-bound`` chooses from (module docstring), in tie-break order.
PORTFOLIO: tuple[Law, ...] = (
    ("zeta", 0.0), ("zeta", 0.05), ("zeta", 0.1), ("zeta", 0.5), ("zeta", 2.0),
    ("kv", 0.05), ("kv", 0.2), ("kv", 0.5), ("kv", 1.0))
#: The sensor-noise seed of the selection runs: outside every seed a board
#: evaluates on (``stepdamp_env.bench.protocols.v4.evaluation_seeds``).
SELECTION_SEED = 2**31 - 1

_CHOICES: dict[tuple[Any, ...], Law] = {}


def _key(context: PolicyContext) -> tuple[Any, ...]:
    """Everything a rehearsal reads (the frozen models compare by value)."""
    k = context.knowledge
    return (k.plant, k.exact, k.nominal, context.mode, context.suite,
            float(context.speed_rps), float(context.accel_rps2), float(context.agent_hz),
            float(context.action_scale), float(context.current_scale_a), context.window_s,
            context.settle_s, context.lag_limit_steps, context.profile,
            float(context.distance_rev))


class PortfolioLaw(PrivilegedBound):
    """One law of the portfolio (``("zeta", z)`` or ``("kv", k)``, module
    docstring), run as ``plant-bound`` runs it."""

    def __init__(self, law: Law) -> None:
        super().__init__()
        self.law = law
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


class PlantBound(PortfolioLaw):
    """``plant-bound`` (privileged): per run, the best law of :data:`PORTFOLIO` on
    the true plant (module docstring). ``portfolio``: the laws to choose from."""

    card = PolicyCard(sensors="true state (position, speed)",
                      model="true plant (each law rehearsed on it per run)", oracle=True)

    def __init__(self, portfolio: Sequence[Law] = PORTFOLIO) -> None:
        laws = tuple((str(kind), float(value)) for kind, value in portfolio)
        if not laws or any(kind not in ("zeta", "kv") or not (math.isfinite(value)
                                                              and value >= 0.0)
                           for kind, value in laws):
            raise ValueError(f"portfolio={portfolio!r}: one or more (kind, value), kind "
                             "'zeta' or 'kv', value finite and >= 0")
        super().__init__(laws[0])
        self.name = "plant-bound"
        self.portfolio = laws

    def choice(self, context: PolicyContext) -> Law:
        """The law ``plant-bound`` runs in ``context`` (selected on first use)."""
        self._select([context])
        return _CHOICES[self._cache_key(context)]

    def _cache_key(self, context: PolicyContext) -> tuple[Any, ...]:
        return (self.portfolio, *_key(context))

    def _select(self, contexts: Sequence[PolicyContext]) -> None:
        """Run the portfolio on the contexts whose choice is not yet known."""
        todo: dict[tuple[Any, ...], dict[tuple[Any, ...], PolicyContext]] = {}
        for c in contexts:
            if c.knowledge.plant is None:
                raise ValueError(f"{self.name} needs MotorKnowledge.plant (the true plant)")
            key = self._cache_key(c)
            if key not in _CHOICES:
                todo.setdefault((c.mode, c.suite, float(c.accel_rps2), c.window_s,
                                 c.lag_limit_steps), {})[key] = c
        for (mode, suite, accel, window_s, lag_limit), group in todo.items():
            keys = list(group)
            specs = [EpisodeSpec(group[k].knowledge, group[k].knowledge.plant,
                                 group[k].speed_rps, SELECTION_SEED, group[k].settle_s,
                                 profile=group[k].profile, distance_rev=group[k].distance_rev)
                     for k in keys]
            window = {} if window_s is None else {"window_s": window_s}
            best = [math.inf] * len(keys)
            chosen: list[Law] = [self.portfolio[0]] * len(keys)
            for law in self.portfolio:
                try:
                    results = run_episodes(lambda law=law: PortfolioLaw(law), specs,
                                           mode=mode, accel_rps2=accel, suite=suite,
                                           lag_limit_steps=lag_limit, **window)
                except ParameterError:      # a law that cannot run here is not chosen
                    continue
                for i, r in enumerate(results):
                    rms = math.inf if r.failed or r.metrics is None else \
                        float(r.metrics["rms_velocity_error_rad_s"])
                    if rms < best[i]:
                        best[i], chosen[i] = rms, law
            for k, law in zip(keys, chosen):
                _CHOICES[k] = law

    def reset_batch(self, contexts: Sequence[PolicyContext]) -> None:
        self._select(contexts)
        super().reset_batch(contexts)

    def configure(self, context: PolicyContext) -> None:
        self.law = _CHOICES[self._cache_key(context)]
        super().configure(context)
