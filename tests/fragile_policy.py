"""A policy that cannot run on some motors, for the "no crash on any motor" test
(loaded as ``file.py:attr``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from stepdamp_env.params import ParameterError


class Fragile:
    """The patent feedforward with the nominal model, zero residual, whose law
    cannot be made above 1 rev/s (as a law whose design fails on a motor): those
    runs must be recorded as lost with the reason, and the board must render."""

    name = "test-fragile"

    def env_options(self, knowledge: Any) -> dict[str, Any]:
        return {"base_controller": "patent-ff", "estimate": "nominal", "action_mode": "harmonic"}

    def reset(self, context: Any) -> None:
        if context.speed_rps > 1.0:
            raise ParameterError(f"speed_rps={context.speed_rps:.3g} is outside this law's "
                                 "design range (0, 1] rev/s")
        self._zero = np.zeros(6, dtype=np.float32)

    def act(self, observation: np.ndarray) -> np.ndarray:
        return self._zero
