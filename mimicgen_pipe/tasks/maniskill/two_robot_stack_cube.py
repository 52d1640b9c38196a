"""two_robot_stack_cube: ManiSkill's TwoRobotStackCube-v1; beyond the paper (two arms, its
limitation 9).

**Task Description:**
Two Pandas face each other across the table (bases at y = -0.75 and +0.75 m). The right arm
grasps the green cube B and sets it on the goal disc; once it has let go, the left arm,
which has meanwhile grasped the blue cube A and lifted it, stacks A on B.

**Randomizations:**
World frame: the table centre is the origin; positions in metres, yaw about world z.
ManiSkill's reset, then the cubes redrawn uniform in their boxes (no distance or reach
cut), their yaw uniform over a full turn, and the goal disc drawn uniform in its box (its
height and tilt ManiSkill's).
- D0: ManiSkill's cubes (A: x in [-0.05, 0.05], y in [-0.2, -0.1]; B: x in [-0.05, 0.05],
  y in [0.1, 0.2]) with the goal disc at x in [-0.05, 0.05], y in [-0.02, 0.02].
  ManiSkill puts the goal at y = -0.1, which the right Panda cannot reach top-down (driven
  there with pd_ee_delta_pose its TCP stops 7.6 cm short, at y = -0.033); near y = 0 both
  arms reach it.
- D1: the cubes over twice ManiSkill's spread (A: x in [-0.1, 0.1], y in [-0.25, -0.05];
  B: x in [-0.1, 0.1], y in [0.05, 0.25]), the goal as in D0.
- D2: the cubes over three times ManiSkill's x spread and y out to 30 cm from the centre (A:
  x in [-0.15, 0.15], y in [-0.3, -0.08]; B: mirrored, y in [0.08, 0.3]), the goal as in D0:
  B at least 4 cm from the goal disc's edge.

**Success Conditions:**
ManiSkill's:
- A is on B: centres within the cubes' half diagonal + 5 mm (3.3 cm) in xy and
  4 cm +- 5 mm apart in z;
- B's centre is within 6 cm of the goal's in xy;
- the left arm does not grasp A, nor the right arm B.

**Subtasks:**
Arms: ``left`` (ManiSkill's agent 0, near cube A) and ``right`` (agent 1, near cube B).
Constraint: left's stack starts once right's place has ended (sequential).
- ``grasp_cubeA`` (arm ``left``), reference ``cubeA``: ends when ``grasp_cubeA``
  (ManiSkill's ``is_cubeA_grasped``) turns true.
- ``carry_cubeA`` (arm ``left``), reference ``goal``: ends when ``cubeB_released_on_goal``
  turns true, as right's place does.
- ``stack_cubeA`` (arm ``left``), reference ``cubeB``: ends with the demo.
- ``grasp_cubeB`` (arm ``right``), reference ``cubeB``: ends when ``grasp_cubeB``
  (ManiSkill's ``is_cubeB_grasped``) turns true.
- ``place_cubeB`` (arm ``right``), reference ``goal``: ends when ``cubeB_released_on_goal``
  turns true: B within 6 cm of the goal (ManiSkill's ``cubeB_placed``) and released.
- ``retreat`` (arm ``right``), reference ``goal``: ends with the demo.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mimicgen_pipe.backends.maniskill.tasks import FULL_YAW, ManiSkillTask
from mimicgen_pipe.backends.maniskill.two_arm import grasp_rotation, step_toward
from mimicgen_pipe.backends.maniskill.two_arm import pose_at as _pose
from mimicgen_pipe.core.taskspec import (
    ObjectBounds,
    ResetVariant,
    SubtaskConstraint,
    SubtaskSpec,
    TaskSpec,
)

OBJECTS = ("cubeA", "cubeB", "goal")
GOAL = ObjectBounds((-0.05, 0.05), (-0.02, 0.02), (0.0, 0.0))


def _variant(x: float, y: tuple[float, float]) -> ResetVariant:
    """Cube A in x in [-x, x] and y in ``y``, cube B mirrored across y = 0 (on the right
    arm's side), the goal disc in GOAL."""
    return ResetVariant(
        {
            "cubeA": ObjectBounds((-x, x), y, FULL_YAW),
            "cubeB": ObjectBounds((-x, x), (-y[1], -y[0]), FULL_YAW),
            "goal": GOAL,
        }
    )


def initialize(env, env_idx, variant: ResetVariant) -> None:
    """ManiSkill's reset, then the cubes redrawn from the variant and the goal disc drawn
    uniformly in its bounds (its height and tilt ManiSkill's)."""
    import torch

    from mimicgen_pipe.backends.maniskill.env import draw_planar, set_planar_poses

    env.native_initialize(env_idx)
    b = len(env_idx)
    xy, yaw = draw_planar(variant, ("cubeA", "cubeB"), b, (0.0, 0.0))
    set_planar_poses([env.cubeA, env.cubeB], xy, yaw, [0.02, 0.02])
    from mani_skill.utils.structs.pose import Pose

    goal = env.goal_region.pose.raw_pose.clone()
    bounds = variant.bounds["goal"]
    for axis, (lo, hi) in enumerate((bounds.x, bounds.y)):
        goal[:, axis] = torch.rand(b) * (hi - lo) + lo

    env.goal_region.set_pose(Pose.create_from_pq(p=goal[:, :3], q=goal[:, 3:]))


def signals(env, info: dict) -> dict[str, Any]:
    return {
        "grasp_cubeA": info["is_cubeA_grasped"],
        "grasp_cubeB": info["is_cubeB_grasped"],
        "cubeB_released_on_goal": info["cubeB_placed"] & ~info["is_cubeB_grasped"],
    }


def evaluate(env) -> dict[str, bool]:
    info = env.evaluate()
    return {k: bool(v) for k, v in signals(env, info).items()} | {"success": bool(info["success"])}


# -- the scripted demonstrator ----------------------------------------------------------------
ABOVE, LIFT, CUBE = 0.08, 0.16, 0.04  # [m]


def _grasp_rotation(tcp: np.ndarray, obj: np.ndarray) -> np.ndarray:
    """The TCP's rotation turned about world z to the object's faces (a cube looks the same
    every 90 degrees)."""
    return grasp_rotation(tcp, obj, math.pi / 2)


def demonstrate(env, seed: int) -> np.ndarray | None:
    """Both arms follow their moves, each at most 1.2 cm and 0.08 rad per step: the right
    arm above B, down, close, up, above the goal, down, open, up and back; the left arm
    above A, down, close, up to 16 cm, then (once B is released on the goal and the right
    arm has risen) above B, down onto it, open, up."""
    arms = {a: env.arm(a) for a in ("left", "right")}
    obj = env.object_poses()
    start = {a: arms[a].eef_pose() for a in arms}
    ra = _grasp_rotation(start["left"], obj["cubeA"])
    rb = _grasp_rotation(start["right"], obj["cubeB"])
    a, b, g = obj["cubeA"][:3, 3], obj["cubeB"][:3, 3], obj["goal"][:3, 3]
    # (target, gripper, steps to hold once there); a target None: above cube B as it is then
    on_goal = (g[0], g[1], b[2] + 0.003)
    moves = {
        "right": [
            (_pose(rb, b + (0, 0, ABOVE)), 1.0, 0), (_pose(rb, b), 1.0, 2), (_pose(rb, b), -1.0, 8),
            (_pose(rb, b + (0, 0, LIFT)), -1.0, 0), (_pose(rb, (g[0], g[1], b[2] + LIFT)), -1.0, 0),
            (_pose(rb, on_goal), -1.0, 2), (_pose(rb, on_goal), 1.0, 8),
            (_pose(rb, (g[0], g[1], b[2] + LIFT + 0.08)), 1.0, 0),
            (_pose(rb, (g[0], g[1] + 0.2, b[2] + LIFT + 0.08)), 1.0, 4),
        ],
        "left": [
            (_pose(ra, a + (0, 0, ABOVE)), 1.0, 0), (_pose(ra, a), 1.0, 2), (_pose(ra, a), -1.0, 8),
            (_pose(ra, (a[0], a[1] - 0.05, a[2] + LIFT)), -1.0, 0),
            None,  # wait for B on the goal, released, and the right arm away
            "above", "onto", "open", "up",
        ],
    }  # fmt: skip
    index = {"left": 0, "right": 0}
    held = {"left": 0, "right": 0}
    grip = {"left": 1.0, "right": 1.0}
    plan: dict[str, tuple[np.ndarray, float, int]] = {}
    actions = []
    for _ in range(600):
        if env.is_success() and index["left"] >= len(moves["left"]):
            return np.asarray(actions, np.float32)
        sig = env.subtask_signals()
        now = env.object_poses()
        parts = []
        for arm in ("right", "left"):
            eef = arms[arm].eef_pose()
            steps = moves[arm]
            if index[arm] >= len(steps):
                parts.append(arms[arm].target_pose_to_action(eef, grip[arm]))
                continue
            move = steps[index[arm]]
            if move is None:  # the left arm waits
                away = index["right"] >= len(moves["right"]) - 1
                if sig["cubeB_released_on_goal"] and away:
                    index[arm] += 1
                parts.append(arms[arm].target_pose_to_action(eef, grip[arm]))
                continue
            if isinstance(move, str):
                bb = now["cubeB"][:3, 3]
                rot = _grasp_rotation(eef, now["cubeB"])
                top = bb[2] + CUBE
                if arm not in plan or plan[arm][2] != index[arm]:
                    target = {
                        "above": (_pose(rot, (bb[0], bb[1], top + ABOVE)), -1.0),
                        "onto": (_pose(rot, (bb[0], bb[1], top + 0.003)), -1.0),
                        "open": (_pose(eef[:3, :3], eef[:3, 3]), 1.0),
                        "up": (_pose(eef[:3, :3], eef[:3, 3] + (0, 0, ABOVE)), 1.0),
                    }[move]
                    plan[arm] = (target[0], target[1], index[arm])
                goal_pose, grip[arm], hold = plan[arm][0], plan[arm][1], 8 if move == "open" else 0
            else:
                goal_pose, grip[arm], hold = move
            target, there = step_toward(eef, goal_pose)
            parts.append(arms[arm].target_pose_to_action(target, grip[arm]))
            if there and np.linalg.norm(eef[:3, 3] - goal_pose[:3, 3]) < 0.004:
                held[arm] += 1
                if held[arm] > hold:
                    index[arm], held[arm] = index[arm] + 1, 0
        action = np.concatenate([parts[1], parts[0]]).astype(np.float32)  # left, right
        env.step(action)
        actions.append(action)
    return None


TASK = ManiSkillTask(
    spec=TaskSpec(
        name="two_robot_stack_cube",
        objects=OBJECTS,
        subtasks=(
            SubtaskSpec("grasp_cubeA", "cubeA", "grasp_cubeA", arm="left"),
            SubtaskSpec("carry_cubeA", "goal", "cubeB_released_on_goal", arm="left"),
            SubtaskSpec("stack_cubeA", "cubeB", None, arm="left"),
            SubtaskSpec("grasp_cubeB", "cubeB", "grasp_cubeB", arm="right"),
            SubtaskSpec("place_cubeB", "goal", "cubeB_released_on_goal", arm="right"),
            SubtaskSpec("retreat", "goal", None, arm="right"),
        ),
        reset_variants={
            "D0": _variant(0.05, (-0.2, -0.1)),
            "D1": _variant(0.1, (-0.25, -0.05)),
            "D2": _variant(0.15, (-0.3, -0.08)),
        },
        horizon=600,
        paper_task="none: two arms, beyond the paper (its limitation 9)",
        constraints=(
            SubtaskConstraint("sequential", ("right", "place_cubeB"), ("left", "stack_cubeA")),
        ),
    ),
    base_env_id="TwoRobotStackCube-v1",
    objects={"cubeA": "cubeA", "cubeB": "cubeB", "goal": "goal_region"},
    signals=signals,
    evaluate=evaluate,
    initialize=initialize,
    arm_agents={"left": 0, "right": 1},
    demonstrator=demonstrate,
    video_view=((0.55, 0.0, 0.75), (-0.15, 0.0, 0.05)),  # from the side, both arms in view
)
