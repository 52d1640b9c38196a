"""square_peg: PyBullet; the paper's Square.

**Task Description:**
Grasp a standing square peg (30 x 30 x 60 mm, 50 g) and insert it into the square hole
(34 x 34 mm, 40 mm deep) of a fixture fixed to the table: 4 mm clearance, 2 mm a side, so
the peg's yaw must match the hole's within a few degrees.

**Randomizations:**
World frame: the table centre is the origin, the robot base at x = -0.5 m; positions in
metres. Each object uniform in its box, its yaw about world z uniform over a full turn,
the centres at least 0.12 m apart.
- D0: the peg in x in [-0.05, 0.05], y in [-0.15, -0.1]; the fixture in x in [-0.05, 0.05],
  y in [0.1, 0.15] (the demonstrator's distribution).
- D1: 3x wider in x (+-0.15), y in [-0.2, -0.05] (peg) and [0.05, 0.2] (fixture).

**Success Conditions:**
- the peg is inserted: its centre within 5 mm of the hole's axis horizontally and its bottom
  less than 2 cm above the table, at least 2 cm down the hole. Nothing is asked of the
  grasp.

**Subtasks:**
- ``grasp_peg``, reference ``peg``: ends when ``grasp_peg`` (both fingers touch the peg)
  turns true.
- ``insert_peg``, reference ``hole``: ends with the demo.
"""

from __future__ import annotations

import numpy as np

from mimicgen_pipe.backends.pybullet.demos import pick, place
from mimicgen_pipe.backends.pybullet.tasks import FULL_YAW, RED, Box, ObjectShape, PyBulletTask
from mimicgen_pipe.core.taskspec import ObjectBounds, ResetVariant, SubtaskSpec, TaskSpec

PEG_HALF = 0.015
PEG_HALF_HEIGHT = 0.03
HOLE_HALF = 0.017
FIXTURE_HALF = 0.05
FIXTURE_HEIGHT = 0.04


def fixture() -> ObjectShape:
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


def peg_inserted(peg: np.ndarray, hole: np.ndarray) -> bool:
    """The peg's bottom is at least 2 cm down the hole (world poses), within 5 mm of its
    axis."""
    d = peg[:3, 3] - hole[:3, 3]
    bottom = d[2] - PEG_HALF_HEIGHT
    return bool(np.linalg.norm(d[:2]) < 0.005 and bottom < FIXTURE_HEIGHT - 0.02)


def signals(env) -> dict[str, bool]:
    obj = env.object_poses()
    return {"grasp_peg": env.grasped("peg"), "peg_inserted": peg_inserted(obj["peg"], obj["hole"])}


def success(s: dict[str, bool]) -> bool:
    return s["peg_inserted"]


def demonstrate(op, env) -> None:
    # held 5 mm above its centre of mass, the peg does not pivot between the fingers
    pick(op, env.object_poses()["peg"], 0.005)
    goal = env.object_poses()["hole"].copy()
    # released with its bottom 20 mm down the hole, the fingertips above the fixture; it
    # drops to the bottom
    goal[2, 3] += PEG_HALF_HEIGHT + FIXTURE_HEIGHT - 0.02
    place(op, "peg", goal, 0.17, FIXTURE_HEIGHT + 0.03, 0.004)


TASK = PyBulletTask(
    spec=TaskSpec(
        name="square_peg",
        objects=("peg", "hole"),
        subtasks=(
            SubtaskSpec("grasp_peg", "peg", "grasp_peg", (15, 20)),
            SubtaskSpec("insert_peg", "hole", None),
        ),
        reset_variants={
            "D0": ResetVariant(
                {
                    "peg": ObjectBounds((-0.05, 0.05), (-0.15, -0.1), FULL_YAW),
                    "hole": ObjectBounds((-0.05, 0.05), (0.1, 0.15), FULL_YAW),
                },
                min_distance=0.12,
            ),
            "D1": ResetVariant(
                {
                    "peg": ObjectBounds((-0.15, 0.15), (-0.2, -0.05), FULL_YAW),
                    "hole": ObjectBounds((-0.15, 0.15), (0.05, 0.2), FULL_YAW),
                },
                min_distance=0.12,
            ),
        },
        horizon=300,
        paper_task="Square",
    ),
    shapes={
        "peg": ObjectShape(
            (Box((PEG_HALF, PEG_HALF, PEG_HALF_HEIGHT)),), 0.05, PEG_HALF_HEIGHT, RED
        ),
        "hole": fixture(),
    },
    signals=signals,
    success=success,
    demonstrate=demonstrate,
)
