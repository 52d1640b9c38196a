"""stack_pyramid: ManiSkill's StackPyramid-v1; the paper's Stack Three.

**Task Description:**
Grasp cube A, place it beside cube B, grasp cube C, place it on A and B. Cubes are 4 cm.

ManiSkill's own planner for this task pushes A towards B with a closed gripper (and skips
the push where A starts within 7 cm of B), so its demos have no "grasp A" and their subtask
structure varies. This file's demonstrator (``solve``) grasps and places instead, from the
same planner primitives: A goes beside the face of B nearest to A's start, 3 mm from it
and turned to B's yaw; C goes on the middle of the two.

**Randomizations:**
World frame: the table centre is the origin, the Panda base at x = -0.615 m; positions in
metres; each cube's yaw about world z uniform over a full turn.
- D0: ManiSkill's own: each cube's centre in x in [-0.1, 0.1], y in [-0.2, 0.2], apart by
  at least 5.7 cm.
- D1: each cube in x in [-0.2, 0.15], y in [-0.3, 0.3], centres at least 0.08 m apart, cut
  by the Panda's top-down reach (at most 0.76 m horizontally from the base).
- D2: each cube in x in [-0.3, 0.2], y in [-0.35, 0.35], at least 0.08 m apart and cut by
  the reach as D1.

**Success Conditions:**
ManiSkill's:
- A is next to B: centres within the cubes' diagonal + 5 mm (6.2 cm) in xy;
- C is on top of A and of B: centres within 6.2 cm in xy, more than 2 cm apart in z;
- A and C are static (below 1 cm/s and 0.5 rad/s) and not grasped.

**Subtasks:**
- ``grasp_cubeA``, reference ``cubeA``: ends when ``grasp_cubeA`` (the agent's
  ``is_grasping``) turns true.
- ``place_beside_cubeB``, reference ``cubeB``: ends when ``cubeA_beside_cubeB`` turns true:
  A released, its centre within 6.2 cm of B's in xy and within 5 mm of B's height.
- ``grasp_cubeC``, reference ``cubeC``: ends when ``grasp_cubeC`` turns true.
- ``place_on_pyramid``, reference ``cubeB``: ends with the demo.
"""

from __future__ import annotations

import numpy as np

from mimicgen_pipe.backends.maniskill.cube_motions import HALF, grasp, panda_planner, place
from mimicgen_pipe.backends.maniskill.tasks import FULL_YAW, PANDA_REACH, ManiSkillTask
from mimicgen_pipe.core.taskspec import ObjectBounds, ResetVariant, SubtaskSpec, TaskSpec

OBJECTS = ("cubeA", "cubeB", "cubeC")
GAP = 0.003  # [m] between the facing sides of A and B in the demos
SLACK = 0.004  # [m] how far a demo's A may land from its spot beside B
F32 = np.float32
# ManiSkill's "next to" and "on top" tests: centres within this in xy [m]
NEAR = np.linalg.norm(np.full(2, 2 * HALF, F32)) + F32(0.005)


def _beside(a: np.ndarray, b: np.ndarray) -> bool:
    """A's centre ``a`` next to B's ``b`` (world, [m]) and on the table as B is."""
    return bool(np.linalg.norm(a[:2] - b[:2]) <= NEAR and abs(a[2] - b[2]) <= F32(0.005))


def _on_top(upper: np.ndarray, lower: np.ndarray) -> bool:
    d = lower - upper  # ManiSkill's offset, lower minus upper
    return bool(np.linalg.norm(d[:2]) <= NEAR and abs(d[2]) > F32(0.02))


def _signals(p: dict[str, np.ndarray], grasped: dict[str, bool]) -> dict[str, bool]:
    return {
        "grasp_cubeA": grasped["cubeA"],
        "cubeA_beside_cubeB": _beside(p["cubeA"], p["cubeB"]) and not grasped["cubeA"],
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
    # ManiSkill's success: A next to B (xy only), C on top of both; A and C static, let go
    a_ok = np.linalg.norm(p["cubeA"][:2] - p["cubeB"][:2]) <= NEAR
    c_ok = _on_top(p["cubeC"], p["cubeB"]) and _on_top(p["cubeC"], p["cubeA"])
    a_free = lean.is_static(env.cubeA, lin_thresh=1e-2, ang_thresh=0.5) and not grasped["cubeA"]
    c_free = lean.is_static(env.cubeC, lin_thresh=1e-2, ang_thresh=0.5) and not grasped["cubeC"]
    out["success"] = bool(a_ok and c_ok and a_free and c_free)
    return out


def solve(env, seed: int | None = None):
    """The source demonstrator: one planned demo on ManiSkill's ``pd_joint_pos`` env from
    reset ``seed``; ManiSkill's solution convention (the last step's result, or -1 where a
    motion cannot be planned)."""
    import sapien

    planner = panda_planner(env, seed)
    u = env.unwrapped
    a, b, c = u.cubeA.pose.sp, u.cubeB.pose.sp, u.cubeC.pose.sp
    axes = sapien.Pose(q=b.q).to_transformation_matrix()[:3, :2].T
    sides = sorted(
        (s * n for n in axes for s in (1.0, -1.0)), key=lambda n: -float(n[:2] @ (a.p - b.p)[:2])
    )
    spots = [b.p + (2 * HALF + GAP) * n for n in sides]
    spots = [s for s in spots if np.linalg.norm(s[:2] - c.p[:2]) > 0.07]  # clear of C
    if not spots or not grasp(u, planner, u.cubeA):
        return -1
    if place(u, planner, u.cubeA, spots[0], b.q) == -1:
        return -1
    # A slid or turned on the way down: a demo C would have to fix, so none
    if np.linalg.norm(u.cubeA.pose.sp.p[:2] - spots[0][:2]) > SLACK:
        return -1
    if not grasp(u, planner, u.cubeC):
        return -1
    a, b = u.cubeA.pose.sp, u.cubeB.pose.sp
    res = place(u, planner, u.cubeC, (a.p + b.p) / 2 + [0, 0, 2 * HALF], b.q)
    planner.close()
    return res


def _variant(x: tuple[float, float], y: tuple[float, float]) -> ResetVariant:
    return ResetVariant(
        {o: ObjectBounds(x, y, FULL_YAW) for o in OBJECTS},
        min_distance=0.08,
        max_reach=PANDA_REACH,
    )


TASK = ManiSkillTask(
    spec=TaskSpec(
        name="stack_pyramid",
        objects=OBJECTS,
        subtasks=(
            SubtaskSpec("grasp_cubeA", "cubeA", "grasp_cubeA", (20, 25)),
            SubtaskSpec("place_beside_cubeB", "cubeB", "cubeA_beside_cubeB", (20, 25)),
            SubtaskSpec("grasp_cubeC", "cubeC", "grasp_cubeC", (20, 25)),
            SubtaskSpec("place_on_pyramid", "cubeB", None),
        ),
        reset_variants={
            "D0": ResetVariant(
                {o: ObjectBounds((-0.1, 0.1), (-0.2, 0.2), FULL_YAW) for o in OBJECTS},
                native=True,
            ),
            "D1": _variant((-0.2, 0.15), (-0.3, 0.3)),
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
)
