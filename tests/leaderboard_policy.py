"""A tiny policy module for the leaderboard tests (loaded as ``file.py:attr`` and as
``tests.leaderboard_policy:attr``)."""

from __future__ import annotations

from typing import Any

import numpy as np


class NominalFeedforward:
    """The patent feedforward with the datasheet (nominal) model, harmonic residual zero.

    For a preset the nominal model is the plant's, so it must score exactly as
    ``patent-ff-oracle`` (a zero action reproduces the base controller bit for bit).
    """

    name = "test-nominal-ff"

    def env_options(self, knowledge: Any) -> dict[str, Any]:
        return {"base_controller": "patent-ff", "estimate": "nominal", "action_mode": "harmonic"}

    def reset(self, context: Any) -> None:
        self._zero = np.zeros(6, dtype=np.float32)

    def act(self, observation: np.ndarray) -> np.ndarray:
        return self._zero


class Privileged(NominalFeedforward):
    """Asks for an option the protocol fixes: must be refused."""

    name = "test-privileged"

    def env_options(self, knowledge: Any) -> dict[str, Any]:
        return {**super().env_options(knowledge), "privileged": True}

