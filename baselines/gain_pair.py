"""``tuned-gain-pair``: StepperDamp-v1's damping law on ``ff-delay-comp`` at a
constant pair (``kv``, ``kp``) per suite, the best of a grid on stepdamp-bench
v3's dev split.

``tuned-constant-gain`` sets one ``kv`` (0.5), picked on training motors by a
reward. This entry is the same law with its velocity gain ``kv`` and its
high-passed position gain ``kp`` (``(kv, kp) = (cos phi, -sin phi)`` leads by
about phi at wn) tuned where the agents are selected: on the dev motors, by the
attenuation the board scores (``python scripts/gain_pair_grid.py --suite S``,
grids of 0.05-0.2 steps; docs/baselines.md gives the runs). The resonant gains
are 0. It is the classical reference a learned gain schedule must beat to have
learned more than two numbers per suite.
"""

from __future__ import annotations

import math
from types import MappingProxyType
from typing import Mapping

import numpy as np

from stepdamp_env.bench.policy import PolicyCard, PolicyContext
from stepdamp_env.bench.suites import nearest_suite, tuned_suite
from stepdamp_env.env.registration import ENV_ID_V1
from stepdamp_env.params import ParameterError

from stepdamp_env.bench.firmware import FirmwareLaw

from .feedback import TunedConstantGain, gains_law

__all__ = ["TunedGainPair", "DEV_GAIN_PAIRS"]

#: (kv, kp) per suite, normalised gains (no unit): kv scales Kv = 2*J*wn/Km (A*s/rad)
#: of the nominal model on the velocity error, kp scales Kv*wn (A/rad) on the
#: high-passed position error. The best dev attenuation (IQM) of
#: scripts/gain_pair_grid.py's grids: open loop 38.7 dB (kv at the action's bound
#: 1), servo 29.3 dB, mid-band 28.8 dB (a narrow ridge: one grid step off it
#: loses 5 dB).
DEV_GAIN_PAIRS: Mapping[str, tuple[float, float]] = MappingProxyType({
    "open-loop": (1.0, -0.7), "servo": (0.3, -0.05), "mid-band": (0.5, -0.9)})


class TunedGainPair:
    """The damping law at a constant (``kv``, ``kp``) per suite (the run's
    ``PolicyContext.suite``; a run of no suite, the servo on the voltage-mode
    drive, takes the mid-band's), gains
    normalised as in :data:`DEV_GAIN_PAIRS`. Senses the encoder (velocity
    estimate, position error) and currents; model: nominal (law units),
    identified (feedforward)."""

    env_id = ENV_ID_V1
    card = PolicyCard(sensors="encoder (velocity estimate, position error), currents",
                      model="nominal (law), identified (feedforward)")

    def __init__(self, pairs: Mapping[str, tuple[float, float]] = DEV_GAIN_PAIRS) -> None:
        for suite, pair in pairs.items():
            try:
                ok = len(pair) == 2 and all(math.isfinite(g) and -1.0 <= g <= 1.0 for g in pair)
            except TypeError:
                ok = False
            if not ok:
                raise ValueError(f"pairs[{suite!r}]={pair!r}: two gains (kv, kp) in [-1, 1]")
        self.name = "tuned-gain-pair"
        self.pairs = {k: (float(v[0]), float(v[1])) for k, v in pairs.items()}
        self.action: np.ndarray | None = None     # the run's gains, set by reset

    # The same law, run the same way as tuned-constant-gain's.
    env_options = TunedConstantGain.env_options

    def reset(self, context: PolicyContext) -> None:
        self.action = self._gains(context)

    def _gains(self, context: PolicyContext) -> np.ndarray:
        """The float32 damping-gains action of ``context``'s suite."""
        drive = context.knowledge.nominal.drive.drive_mode
        suite = tuned_suite(context.suite or nearest_suite(context.mode, drive), self.pairs)
        if suite not in self.pairs:
            raise ParameterError(f"{self.name}: no gains for suite {suite!r} (tuned for "
                                 f"{sorted(self.pairs)})")
        action = np.zeros(8, dtype=np.float32)
        action[:2] = self.pairs[suite]
        return action

    def firmware_law(self, context: PolicyContext) -> FirmwareLaw:
        """The law this entry runs in ``context``: ff-delay-comp's table plus the
        kernel's feedback at the suite's (kv, kp) (:func:`.feedback.gains_law`)."""
        return gains_law(self.name, self._gains(context), self.env_options(context.knowledge),
                         context)

    def act(self, observation: np.ndarray) -> np.ndarray:
        if self.action is None:
            raise RuntimeError(f"{self.name}: reset(context) first (it picks the suite's gains)")
        return self.action
