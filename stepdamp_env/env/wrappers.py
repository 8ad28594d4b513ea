"""``EpisodeGuard``: no step after an episode ended without a reset."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

__all__ = ["EpisodeGuard"]


class EpisodeGuard(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Raise ``gymnasium.error.ResetNeeded`` on ``step()`` after ``terminated`` or
    ``truncated`` until ``reset()``.

    ``gym.make`` puts it outside the ``TimeLimit`` wrapper (it is in the
    registered spec's ``additional_wrappers``), so it sees the truncation that
    only the time limit knows; the scalar env itself refuses steps after its
    own termination.
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
