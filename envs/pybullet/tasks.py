"""PyBullet tasks: objects built from box primitives, reset variants and subtask specs; free of
simulator imports.

World frame: z up, the table top is the plane z = 0, every robot base sits at
``ROBOT_BASE_XY`` on it facing +x. Object poses are their body frames (box centres; the hole
fixture's frame is the centre of its base on the table).

- stack: grasp cube A (4 cm), place it on cube B (4 cm).
- stack_three: stack A on B, then C on A (three 4 cm cubes).
- square_peg: grasp a standing square peg (25 x 25 x 80 mm) and insert it into the square
  hole (28 x 28 mm, 40 mm deep) of a fixture fixed to the table: 3 mm clearance, 1.5 mm a
  side, so the peg's yaw must match the hole's within ~6 degrees.

Reset variants (each object uniform in its box, yaw uniform over a full turn, resampled
while two objects' centres are closer than ``min_distance``):
- D0: the demonstrator's distribution, objects within +-8 cm (stack) / +-10 cm (three) of
  the table centre; the peg and fixture in two fixed 10 x 5 cm patches.
- D1: boxes 2.5x (stack) / 2x (three) / 3x (peg) wider in x, reaching 0.7 m from the robot
  base, where an arm's top-down workspace ends.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mimicgen_pipe.taskspec import ObjectBounds, SubtaskSpec, TaskSpec

ROBOT_BASE_XY = (-0.5, 0.0)
FULL_YAW = (0.0, 2 * math.pi)
CUBE_HALF = 0.02
PEG_HALF = 0.015
PEG_HALF_HEIGHT = 0.03
HOLE_HALF = 0.017
FIXTURE_HALF = 0.05
FIXTURE_HEIGHT = 0.04


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


def _cube(rgba: tuple[float, float, float, float]) -> ObjectShape:
    return ObjectShape((Box((CUBE_HALF,) * 3),), 0.05, CUBE_HALF, rgba)


def _fixture() -> ObjectShape:
    """Four walls around a square hole; the frame is the hole's centre on the table."""
    wall = (FIXTURE_HALF - HOLE_HALF) / 2  # half thickness
    mid = HOLE_HALF + wall
    h = FIXTURE_HEIGHT / 2
    return ObjectShape(
        (
            Box((wall, FIXTURE_HALF, h), (mid, 0.0, h)),
            Box((wall, FIXTURE_HALF, h), (-mid, 0.0, h)),
            Box((HOLE_HALF, wall, h), (0.0, mid, h)),
            Box((HOLE_HALF, wall, h), (0.0, -mid, h)),
        ),
        0.0,
        0.0,
        (0.6, 0.6, 0.65, 1.0),
    )


RED, GREEN, BLUE = (0.9, 0.1, 0.1, 1.0), (0.1, 0.8, 0.1, 1.0), (0.1, 0.2, 0.9, 1.0)


@dataclass(frozen=True)
class PyBulletTask:
    """spec: the generator's view. shapes: object name -> body. min_distance: the least
    distance [m] between two objects' centres at reset."""

    spec: TaskSpec
    shapes: dict[str, ObjectShape]
    min_distance: float


def _bounds(objects, x, y) -> dict[str, ObjectBounds]:
    return {o: ObjectBounds(x, y, FULL_YAW) for o in objects}


_CUBES2, _CUBES3 = ("cubeA", "cubeB"), ("cubeA", "cubeB", "cubeC")

STACK = PyBulletTask(
    spec=TaskSpec(
        name="stack",
        objects=_CUBES2,
        subtasks=(
            SubtaskSpec("grasp_cubeA", "cubeA", "grasp_cubeA", (15, 20)),
            SubtaskSpec("place_on_cubeB", "cubeB", None),
        ),
        reset_bounds={
            "D0": _bounds(_CUBES2, (-0.08, 0.08), (-0.08, 0.08)),
            "D1": _bounds(_CUBES2, (-0.2, 0.2), (-0.2, 0.2)),
        },
        horizon=200,
    ),
    shapes={"cubeA": _cube(RED), "cubeB": _cube(GREEN)},
    min_distance=0.07,
)

STACK_THREE = PyBulletTask(
    spec=TaskSpec(
        name="stack_three",
        objects=_CUBES3,
        subtasks=(
            SubtaskSpec("grasp_cubeA", "cubeA", "grasp_cubeA", (15, 20)),
            SubtaskSpec("place_on_cubeB", "cubeB", "cubeA_on_cubeB", (22, 26)),
            SubtaskSpec("grasp_cubeC", "cubeC", "grasp_cubeC", (15, 20)),
            SubtaskSpec("place_on_cubeA", "cubeA", None),
        ),
        reset_bounds={
            "D0": _bounds(_CUBES3, (-0.1, 0.1), (-0.1, 0.1)),
            "D1": _bounds(_CUBES3, (-0.2, 0.2), (-0.2, 0.2)),
        },
        horizon=400,
    ),
    shapes={"cubeA": _cube(RED), "cubeB": _cube(GREEN), "cubeC": _cube(BLUE)},
    min_distance=0.07,
)

SQUARE_PEG = PyBulletTask(
    spec=TaskSpec(
        name="square_peg",
        objects=("peg", "hole"),
        subtasks=(
            SubtaskSpec("grasp_peg", "peg", "grasp_peg", (15, 20)),
            SubtaskSpec("insert_peg", "hole", None),
        ),
        reset_bounds={
            "D0": {
                "peg": ObjectBounds((-0.05, 0.05), (-0.15, -0.1), FULL_YAW),
                "hole": ObjectBounds((-0.05, 0.05), (0.1, 0.15), FULL_YAW),
            },
            "D1": {
                "peg": ObjectBounds((-0.15, 0.15), (-0.2, -0.05), FULL_YAW),
                "hole": ObjectBounds((-0.15, 0.15), (0.05, 0.2), FULL_YAW),
            },
        },
        horizon=300,
    ),
    shapes={
        "peg": ObjectShape(
            (Box((PEG_HALF, PEG_HALF, PEG_HALF_HEIGHT)),), 0.05, PEG_HALF_HEIGHT, RED
        ),
        "hole": _fixture(),
    },
    min_distance=0.12,
)

TASKS = {t.spec.name: t for t in (STACK, STACK_THREE, SQUARE_PEG)}


def sample_object_poses(task: PyBulletTask, variant: str, rng: np.random.Generator) -> dict:
    """Initial world poses (4x4) of the task's objects in ``variant``, resting on the table.
    Objects are placed in spec order, each resampled (up to 1000 tries) while it is closer
    than ``task.min_distance`` to one placed before it."""
    bounds = task.spec.reset_bounds[variant]
    placed: dict[str, np.ndarray] = {}
    for name in task.spec.objects:
        b = bounds[name]
        for _ in range(1000):
            xy = np.array([rng.uniform(*b.x), rng.uniform(*b.y)])
            if all(np.linalg.norm(xy - p[:2, 3]) >= task.min_distance for p in placed.values()):
                break
        else:
            raise RuntimeError(f"{task.spec.name} {variant}: no room for {name}")
        yaw = rng.uniform(*b.yaw)
        pose = np.eye(4)
        pose[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
        pose[:2, 3], pose[2, 3] = xy, task.shapes[name].z
        placed[name] = pose
    return placed


def on_top(upper: np.ndarray, lower: np.ndarray) -> bool:
    """Cube ``upper`` rests on cube ``lower`` (world poses): centres within 2 cm
    horizontally and one cube height (+-1 cm) apart vertically."""
    d = upper[:3, 3] - lower[:3, 3]
    return bool(np.linalg.norm(d[:2]) < 0.02 and abs(d[2] - 2 * CUBE_HALF) < 0.01)


def peg_inserted(peg: np.ndarray, hole: np.ndarray) -> bool:
    """The peg's bottom is at least 2 cm down the hole (world poses), within 5 mm of its
    axis."""
    d = peg[:3, 3] - hole[:3, 3]
    bottom = d[2] - PEG_HALF_HEIGHT
    return bool(np.linalg.norm(d[:2]) < 0.005 and bottom < FIXTURE_HEIGHT - 0.02)
