"""What the PyBullet tasks share. Each task is one file under mimicgen_pipe/tasks/pybullet/
(``<task>.py`` defines ``TASK``, a PyBulletTask), found by name (mimicgen_pipe.backends.load_task).
Free of simulator imports.

World frame: z up, the table top is the plane z = 0, every robot base sits at
``ROBOT_BASE_XY`` on it facing +x. Object poses are their body frames (box centres; a
fixture's frame is the centre of its base on the table).

Reset variants: drawn by mimicgen_pipe.core.reset_variants (each object uniform in its box, its
yaw right after it, objects in spec order, each redrawn while its centre is closer than the
variant's ``min_distance`` to one placed before it, or farther than its ``max_reach`` from
the robot base). PyBullet has no reset of its own: no variant is ``native``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from mimicgen_pipe.core.taskspec import ObjectBounds, TaskSpec

ROBOT_BASE_XY = (-0.5, 0.0)
FULL_YAW = (0.0, 2 * math.pi)
CUBE_HALF = 0.02
RED, GREEN, BLUE = (0.9, 0.1, 0.1, 1.0), (0.1, 0.8, 0.1, 1.0), (0.1, 0.2, 0.9, 1.0)


@dataclass(frozen=True)
class Box:
    """One box of a body: half extents [m] and centre offset [m] in the body frame."""

    half_extents: tuple[float, float, float]
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class ObjectShape:
    """A rigid body of boxes. mass [kg] (0: fixed to the world). z: height [m] of the body
    frame above the table when resting. rgba: colour."""

    boxes: tuple[Box, ...]
    mass: float
    z: float
    rgba: tuple[float, float, float, float]


@dataclass(frozen=True)
class PyBulletTask:
    """Everything task-specific on the PyBullet back end.

    spec: the generator's view. shapes: object name -> body.
    signals: (env) -> {signal name: bool}, from env.object_poses() (world) and
        env.grasped(name) (both fingers touch the object).
    success: (signals) -> the task's success.
    demonstrate: (op, env) -> None: the scripted source demo, moving ``op``
        (mimicgen_pipe.backends.pybullet.demos.Teleop) through the task from the env's reset scene.
    """

    spec: TaskSpec
    shapes: dict[str, ObjectShape]
    signals: Callable[[Any], dict[str, bool]]
    success: Callable[[dict[str, bool]], bool]
    demonstrate: Callable[[Any, Any], None]

    def __post_init__(self) -> None:
        native = [name for name, v in self.spec.reset_variants.items() if v.native]
        if native:
            raise ValueError(
                f"task {self.spec.name}: variants {native} are native, but PyBullet has no "
                "reset of its own to draw them: give them bounds to draw from instead"
            )


def cube(rgba: tuple[float, float, float, float]) -> ObjectShape:
    """A 4 cm cube of 50 g."""
    return ObjectShape((Box((CUBE_HALF,) * 3),), 0.05, CUBE_HALF, rgba)


def bounds(objects, x, y) -> dict[str, ObjectBounds]:
    """The same box and a full turn of yaw for every object."""
    return {o: ObjectBounds(x, y, FULL_YAW) for o in objects}


def on_top(upper: np.ndarray, lower: np.ndarray) -> bool:
    """Cube ``upper`` rests on cube ``lower`` (world poses): centres within 2 cm
    horizontally and one cube height (+-1 cm) apart vertically."""
    d = upper[:3, 3] - lower[:3, 3]
    return bool(np.linalg.norm(d[:2]) < 0.02 and abs(d[2] - 2 * CUBE_HALF) < 0.01)


def on(lower: np.ndarray, gap: float) -> np.ndarray:
    """A cube's goal pose resting ``gap`` [m] above cube ``lower`` (world)."""
    goal = lower.copy()
    goal[2, 3] += 2 * CUBE_HALF + gap
    return goal
