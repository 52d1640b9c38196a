"""stack_tower: ManiSkill's StackPyramid-v1 scene; the paper's Stack Three (robosuite's
tower).

**Task Description:**
Grasp cube A, place it on cube B, grasp cube C, place it on A. It is set in ManiSkill's
StackPyramid-v1 scene, with three 4 cm cubes. Robosuite's B is 5 cm; here it is 4 cm like
the others.

The demonstrator plans with stack_pyramid's grasp and place motions
(mimicgen_pipe/tasks/maniskill/stack_pyramid.py). A goes on B's centre, turned to B's yaw;
C goes on A's.

**Randomizations:**
World frame: the table centre is the origin, the Panda base at x = -0.615 m; positions in
metres. ManiSkill's reset, then every cube redrawn: uniform in its box, its yaw about world
z uniform over a full turn, its centre at least 0.06 m from the others (more than the
5.7 cm at which two 4 cm cubes could touch) and at most 0.76 m horizontally from the Panda's
base (its top-down reach; D0's box lies within it).
- D0 (the paper's): each cube's centre in x, y in [-0.1, 0.1].
- D1 (the paper's): each cube's centre in x, y in [-0.2, 0.2].
- D2 (ours; the paper has none): stack_pyramid's D2, x in [-0.3, 0.2] and y in
  [-0.35, 0.35].

**Success Conditions:**
The task's own (its env reports it in place of StackPyramid-v1's): ManiSkill's StackCube
test applied twice.
- A is on B and C is on A: centres within the cubes' half diagonal + 5 mm (3.3 cm) in xy,
  and 4 cm +- 5 mm apart in z;
- A and C are released and static, static meaning below 3 cm/s and 0.5 rad/s here
  (StackCube's 1 cm/s is below what PhysX reports for cubes resting in a tower).

Robosuite's test asks instead that A and C be lifted, released and touching the cube below.
stack_pyramid, the same scene with ManiSkill's pyramid goal, stays the harder variant.

**Subtasks:**
- ``grasp_cubeA``, reference ``cubeA``: ends when ``grasp_cubeA`` (the agent's
  ``is_grasping``) turns true.
- ``place_on_cubeB``, reference ``cubeB``: ends when ``cubeA_on_cubeB`` turns true: A on B
  as the success test has it, and released.
- ``grasp_cubeC``, reference ``cubeC``: ends when ``grasp_cubeC`` turns true.
- ``place_on_cubeA``, reference ``cubeA``: ends with the demo.
"""

from __future__ import annotations

import numpy as np

from mimicgen_pipe.backends.maniskill.cube_motions import HALF, grasp, panda_planner, place
from mimicgen_pipe.backends.maniskill.tasks import FULL_YAW, PANDA_REACH, ManiSkillTask
from mimicgen_pipe.core.taskspec import ObjectBounds, ResetVariant, SubtaskSpec, TaskSpec

OBJECTS = ("cubeA", "cubeB", "cubeC")

F32 = np.float32
# StackCube-v1's "on" test: centres within the half diagonal + 5 mm in xy, 2 * HALF apart in z
NEAR_XY = np.linalg.norm(np.full(2, HALF, F32)) + F32(0.005)
NEAR_Z = F32(0.005)
# [m/s] "static": PhysX reports 1.2-1.7 cm/s of downward speed, step after step, for cubes
# resting in a three-cube tower (positions unchanged to 1 mm), more than StackCube's
# 1 cm/s; a cube sliding or toppling off moves faster
STATIC_SPEED = 0.03


def on(upper: np.ndarray, lower: np.ndarray) -> bool:
    """Whether the cube centred at ``upper`` sits on the one at ``lower`` (world, [m])."""
    d = upper - lower
    return bool(np.linalg.norm(d[:2]) <= NEAR_XY and abs(d[2] - F32(2 * HALF)) <= NEAR_Z)


def _signals(p: dict[str, np.ndarray], grasped: dict[str, bool]) -> dict[str, bool]:
    return {
        "grasp_cubeA": grasped["cubeA"],
        "cubeA_on_cubeB": on(p["cubeA"], p["cubeB"]) and not grasped["cubeA"],
        "grasp_cubeC": grasped["cubeC"],
    }


def signals(env, info: dict) -> dict[str, bool]:
    p = {o: getattr(env, o).pose.p.numpy()[0] for o in OBJECTS}
    grasped = {o: bool(env.agent.is_grasping(getattr(env, o))) for o in ("cubeA", "cubeC")}
    return _signals(p, grasped)


def evaluate(env) -> dict[str, bool]:
    from mimicgen_pipe.backends.maniskill import lean

    p = {o: lean.pose(getattr(env, o))[0] for o in OBJECTS}
    grasped = {o: lean.is_grasping(env, getattr(env, o)) for o in ("cubeA", "cubeC")}
    out = _signals(p, grasped)
    free = all(
        lean.is_static(getattr(env, o), lin_thresh=STATIC_SPEED, ang_thresh=0.5) and not grasped[o]
        for o in ("cubeA", "cubeC")
    )
    out["success"] = on(p["cubeA"], p["cubeB"]) and on(p["cubeC"], p["cubeA"]) and free
    return out


def solve(env, seed: int | None = None):
    """The source demonstrator: one planned demo on ManiSkill's ``pd_joint_pos`` env from
    reset ``seed``; ManiSkill's solution convention (the last step's result, or -1 where a
    motion cannot be planned)."""
    planner = panda_planner(env, seed)
    u = env.unwrapped
    for held, below in ((u.cubeA, u.cubeB), (u.cubeC, u.cubeA)):
        if not grasp(u, planner, held):
            return -1
        b = below.pose.sp
        res = place(u, planner, held, b.p + [0, 0, 2 * HALF], b.q)
        if res == -1:
            return -1
    planner.close()
    return res


def _variant(x: tuple[float, float], y: tuple[float, float]) -> ResetVariant:
    return ResetVariant(
        {o: ObjectBounds(x, y, FULL_YAW) for o in OBJECTS},
        min_distance=0.06,
        max_reach=PANDA_REACH,
    )


TASK = ManiSkillTask(
    spec=TaskSpec(
        name="stack_tower",
        objects=OBJECTS,
        subtasks=(
            SubtaskSpec("grasp_cubeA", "cubeA", "grasp_cubeA", (20, 25)),
            SubtaskSpec("place_on_cubeB", "cubeB", "cubeA_on_cubeB", (20, 25)),
            SubtaskSpec("grasp_cubeC", "cubeC", "grasp_cubeC", (20, 25)),
            SubtaskSpec("place_on_cubeA", "cubeA", None),
        ),
        reset_variants={
            "D0": _variant((-0.1, 0.1), (-0.1, 0.1)),
            "D1": _variant((-0.2, 0.2), (-0.2, 0.2)),
            "D2": _variant((-0.3, 0.2), (-0.35, 0.35)),
        },
        horizon=500,
        paper_task="Stack Three",
    ),
    base_env_id="StackPyramid-v1",
    objects={o: o for o in OBJECTS},
    signals=signals,
    evaluate=evaluate,
    planner=solve,
    own_success=True,  # the tower's test, not StackPyramid-v1's
)
