"""``EpisodeGuard``: no step after an episode ended without a reset."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

__all__ = ["EpisodeGuard"]


class EpisodeGuard(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Raise ``gymnasium.error.ResetNeeded`` on ``step()`` after ``terminated`` or
    ``truncated`` until ``reset()``.

    Put it outside the ``TimeLimit`` (``EpisodeGuard(gym.make("StepperDamp-v0"))``):
    truncation is known only to gymnasium's time limit, which lets an env step
    on past it. The scalar env itself refuses steps after its own termination.
    (It cannot be in v0's registered spec: gymnasium's ``make_vec`` refuses a
    native vector entry point when the spec lists additional wrappers.)
    """

    def __init__(self, env: gym.Env) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        self._ended: str | None = None

    def reset(self, **kwargs: Any):
        self._ended = None
        return self.env.reset(**kwargs)

    def step(self, action: Any):
        if self._ended is not None:
            raise gym.error.ResetNeeded(f"the episode was {self._ended}; call reset() "
                                        "before step()")
        obs, reward, terminated, truncated, info = self.env.step(action)
        if terminated:
            self._ended = "terminated"
        elif truncated:
            self._ended = "truncated (time limit)"
        return obs, reward, terminated, truncated, info
