"""Follows the scene through the evaluate stage's own rollout
(:func:`mimicgen_pipe.learn.evaluation.rollout`), step by step: the scripts here hand that
rollout a :class:`Followed` env instead of copying its loop, so their rollouts are the
stage's."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


class Followed:
    """``env``, with ``read(env)`` called after its reset and after each of its steps; every
    other attribute is ``env``'s. ``read`` only reads the scene: the rollout is unchanged."""

    def __init__(self, env: Any, read: Callable[[Any], None]) -> None:
        self.env = env
        self.read = read

    def reset(self, *args: Any, **kwargs: Any) -> Any:
        out = self.env.reset(*args, **kwargs)
        self.read(self.env)
        return out

    def step(self, action: Any) -> Any:
        out = self.env.step(action)
        self.read(self.env)
        return out

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)
