"""stack: PyBullet; the paper's Stack.

**Task Description:**
Grasp cube A and place it on cube B. Cubes are 4 cm, 50 g.

**Randomizations:**
World frame: the table centre is the origin, the robot base at x = -0.5 m; positions in
metres. Each cube uniform in its box, its yaw about world z uniform over a full turn, cube
centres at least 0.07 m apart.
- D0: both cubes in x, y in [-0.08, 0.08], the demonstrator's distribution.
- D1: x, y in [-0.2, 0.2], 2.5x wider.

**Success Conditions:**
- cube A is on cube B: centres within 2 cm horizontally and 4 cm +- 1 cm apart vertically;
- cube A is not grasped (not touched by both fingers).

**Subtasks:**
- ``grasp_cubeA``, reference ``cubeA``: ends when ``grasp_cubeA`` (both fingers touch
  cube A) turns true.
- ``place_on_cubeB``, reference ``cubeB``: ends with the demo.
"""

from __future__ import annotations

from mimicgen_pipe.backends.pybullet.demos import pick, place
from mimicgen_pipe.backends.pybullet.tasks import GREEN, RED, PyBulletTask, bounds, cube, on, on_top
from mimicgen_pipe.core.taskspec import ResetVariant, SubtaskSpec, TaskSpec

OBJECTS = ("cubeA", "cubeB")


def signals(env) -> dict[str, bool]:
    obj = env.object_poses()
    return {
        "grasp_cubeA": env.grasped("cubeA"),
        "cubeA_on_cubeB": on_top(obj["cubeA"], obj["cubeB"]),
    }


def success(s: dict[str, bool]) -> bool:
    return s["cubeA_on_cubeB"] and not s["grasp_cubeA"]


def demonstrate(op, env) -> None:
    pick(op, env.object_poses()["cubeA"], 0.0)
    place(op, "cubeA", on(env.object_poses()["cubeB"], 0.004), 0.12, 0.03, 0.006)


TASK = PyBulletTask(
    spec=TaskSpec(
        name="stack",
        objects=OBJECTS,
        subtasks=(
            SubtaskSpec("grasp_cubeA", "cubeA", "grasp_cubeA", (15, 20)),
            SubtaskSpec("place_on_cubeB", "cubeB", None),
        ),
        reset_variants={
            "D0": ResetVariant(bounds(OBJECTS, (-0.08, 0.08), (-0.08, 0.08)), min_distance=0.07),
            "D1": ResetVariant(bounds(OBJECTS, (-0.2, 0.2), (-0.2, 0.2)), min_distance=0.07),
        },
        horizon=200,
        paper_task="Stack",
    ),
    shapes={"cubeA": cube(RED), "cubeB": cube(GREEN)},
    signals=signals,
    success=success,
    demonstrate=demonstrate,
)
