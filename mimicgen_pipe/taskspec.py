"""Task specifications: the ordered object-centric subtasks and each reset variant's bounds."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass


@dataclass(frozen=True)
class SubtaskSpec:
    """One object-centric subtask (paper 3.1, J.2).

    reference_object: the object the subtask's motion is relative to.
    term_signal: name of the boolean signal whose first 0->1 transition (after the previous
        subtask's end) ends this subtask in a source demo; None for the final subtask, which
        ends with the demo.
    term_offset_range: (lo, hi) steps, inclusive, added to the detected end; sampled per
        generation attempt as in the reference implementation.
    """

    name: str
    reference_object: str
    term_signal: str | None
    term_offset_range: tuple[int, int] = (0, 0)


@dataclass(frozen=True)
class ObjectBounds:
    """Reset bounds of one object: x, y [m] in the world frame, yaw [rad] about world z."""

    x: tuple[float, float]
    y: tuple[float, float]
    yaw: tuple[float, float]


@dataclass(frozen=True)
class TaskSpec:
    """A task as the generator sees it.

    objects: names of the objects whose poses are recorded.
    subtasks: ordered subtasks; all but the last have a term signal.
    reset_bounds: variant name (D0, D1, ...) -> object name -> bounds of its initial pose.
    horizon: maximum episode length [control steps] for policy evaluation.
    """

    name: str
    objects: tuple[str, ...]
    subtasks: tuple[SubtaskSpec, ...]
    reset_bounds: Mapping[str, Mapping[str, ObjectBounds]]
    horizon: int

    @property
    def variants(self) -> tuple[str, ...]:
        return tuple(self.reset_bounds)

    def __post_init__(self) -> None:
        if not self.subtasks:
            raise ValueError(f"task {self.name}: no subtasks")
        for sub in self.subtasks[:-1]:
            if sub.term_signal is None:
                raise ValueError(f"task {self.name}: subtask {sub.name} needs a term signal")
        if self.subtasks[-1].term_signal is not None:
            raise ValueError(f"task {self.name}: the final subtask ends with the demo")
        for sub in self.subtasks:
            if sub.reference_object not in self.objects:
                raise ValueError(f"task {self.name}: unknown object {sub.reference_object}")
            lo, hi = sub.term_offset_range
            if not 0 <= lo <= hi:
                raise ValueError(f"task {self.name}: bad offset range {sub.term_offset_range}")
