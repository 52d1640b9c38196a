"""two_robot_pick_cube: ManiSkill's TwoRobotPickCube-v1; beyond the paper (two arms, its
limitation 9).

**Task Description:**
Two Pandas face each other across the table (bases at y = -1 and +1 m). The red cube starts
within the left arm's reach only, the goal (a point in the air) within the right arm's
only, so the cube changes hands: the left arm grasps it and sets it down on the handover
mark between the arms; once it has let go and risen, the right arm grasps it there and
carries it to the goal.

The handover mark is ours (``load_scene``: a flat disc without collision, 1 m from both
bases, where both arms reach the table top-down: the left TCP reaches y = +0.025 there, the
right y = -0.02).

**Randomizations:**
World frame: the table centre is the origin; positions in metres, yaw about world z in
radians. ManiSkill's reset, then the cube, the mark and the goal's x, y drawn uniform in
their boxes (no distance or reach cut); the cube's yaw uniform over a full turn, the mark's
and the goal's 0; the goal's height ManiSkill's, z in [0.02, 0.32] (0 to 30 cm above the
cube's centre at rest).
- D0: ManiSkill's x, y of the cube (x in [-0.05, 0.05], y in [-0.2, -0.1]) and of the goal
  (x in [-0.05, 0.05], y in [0.1, 0.2]); the mark at x in [-0.03, 0.03], y in [-0.01, 0.0].
- D1: the cube and the goal over twice ManiSkill's x spread (x in [-0.1, 0.1], y as D0);
  the mark as D0.
- D2: x in [-0.15, 0.15], the cube's y in [-0.25, -0.1], the goal's in [0.1, 0.25]; the
  mark as D0.

**Success Conditions:**
ManiSkill's, computed by the task file:
- the cube's centre is within 2.5 cm of the goal;
- the right arm is still (every arm joint below 0.2 rad/s).

**Subtasks:**
Arms: ``left`` (ManiSkill's agent 0) and ``right`` (agent 1). Constraint: right's grasp
starts once left's set-down has ended (sequential).
- ``grasp_cube_left`` (arm ``left``), reference ``cube``: ends when ``left_grasps_cube``
  turns true.
- ``set_on_mark`` (arm ``left``), reference ``handover``: ends when
  ``cube_released_on_mark`` turns true: the cube's centre within 1.5 cm of the mark's in
  the plane and at most 2.5 cm above the table, the left hand not grasping it.
- ``retreat_left`` (arm ``left``), reference ``handover``: ends with the demo.
- ``wait_for_handover`` (arm ``right``), reference ``handover``: ends when
  ``cube_released_on_mark`` turns true, as left's set-down does, so that right's grasp
  starts in every source demo with the cube on the mark.
- ``grasp_cube_right`` (arm ``right``), reference ``cube``: ends when ``right_grasps_cube``
  turns true.
- ``carry_to_goal`` (arm ``right``), reference ``goal``: ends with the demo.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mimicgen_pipe.backends.maniskill.tasks import FULL_YAW, ManiSkillTask
from mimicgen_pipe.backends.maniskill.two_arm import grasp_rotation, pose_at, step_toward
from mimicgen_pipe.core.taskspec import (
    ObjectBounds,
    ResetVariant,
    SubtaskConstraint,
    SubtaskSpec,
    TaskSpec,
)

OBJECTS = ("cube", "handover", "goal")
HALF = 0.02  # [m] the cube's half size
MARK = ObjectBounds((-0.03, 0.03), (-0.01, 0.0), (0.0, 0.0))
ON_MARK = 0.015  # [m] the cube's centre within this of the mark's, in the plane, to rest on it


def _variant(x: float, far: float) -> ResetVariant:
    """The cube and the goal in x in [-x, x], |y| in [0.1, far], on their arms' sides."""
    return ResetVariant(
        {
            "cube": ObjectBounds((-x, x), (-far, -0.1), FULL_YAW),
            "handover": MARK,
            "goal": ObjectBounds((-x, x), (0.1, far), (0.0, 0.0)),
        }
    )


def load_scene(env) -> None:
    """The handover mark: a flat disc, seen and not touched."""
    import sapien

    builder = env.scene.create_actor_builder()
    builder.add_cylinder_visual(
        radius=0.03,
        half_length=0.0005,
        material=sapien.render.RenderMaterial(base_color=[0.2, 0.4, 0.9, 1.0]),
        pose=sapien.Pose(q=[math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0]),  # its axis along z
    )
    builder.initial_pose = sapien.Pose(p=[0.0, 0.0, 0.0005])
    env.handover = builder.build_kinematic(name="handover")


def initialize(env, env_idx, variant: ResetVariant) -> None:
    """ManiSkill's reset (robots, cube, goal height), then the cube, the mark and the goal's
    x, y drawn from the variant."""
    import torch
    from mani_skill.utils.structs.pose import Pose

    from mimicgen_pipe.backends.maniskill.env import draw_planar, set_planar_poses

    env.native_initialize(env_idx)
    b = len(env_idx)
    xy, yaw = draw_planar(variant, OBJECTS, b, (0.0, 0.0))
    set_planar_poses([env.cube, env.handover], xy[:2], yaw[:2], [HALF, 0.0005])
    goal = env.goal_site.pose.p.clone()
    goal[:, :2] = torch.as_tensor(xy[2])
    env.goal_site.set_pose(Pose.create_from_pq(p=goal))


def _on_mark(env) -> Any:
    d = (env.cube.pose.p[:, :2] - env.handover.pose.p[:, :2]).norm(dim=1)
    return (d <= ON_MARK) & (env.cube.pose.p[:, 2] <= HALF + 0.005)


def signals(env, info: dict) -> dict[str, Any]:
    left, right = env.agent.agents
    return {
        "left_grasps_cube": left.is_grasping(env.cube),
        "cube_released_on_mark": _on_mark(env) & ~left.is_grasping(env.cube),
        "right_grasps_cube": right.is_grasping(env.cube),
    }


def evaluate(env) -> dict[str, bool]:
    """ManiSkill's success (TwoRobotPickCube-v1.evaluate): the cube within goal_thresh of the
    goal and the right arm static."""
    placed = (env.goal_site.pose.p - env.cube.pose.p).norm(dim=1) <= env.goal_thresh
    success = placed & env.agent.agents[1].is_static(0.2)
    return {k: bool(v) for k, v in signals(env, {}).items()} | {"success": bool(success)}


# -- the scripted demonstrator ----------------------------------------------------------------
ABOVE, LIFT = 0.08, 0.1  # [m]


def demonstrate(env, seed: int) -> np.ndarray | None:
    """The left arm above the cube, down, close, up, above the mark, down, open, up and back;
    then (once the cube rests released on the mark and the left arm has risen) the right arm
    above the cube as it lies, down, close, up and to the goal, and still there. Each arm
    moves at most 1.2 cm and 0.08 rad per step."""
    arms = {a: env.arm(a) for a in ("left", "right")}
    obj = env.object_poses()
    rl = grasp_rotation(arms["left"].eef_pose(), obj["cube"], math.pi / 2)
    c, m = obj["cube"][:3, 3], obj["handover"][:3, 3]
    down = (m[0], m[1], HALF + 0.002)
    left = [  # (target, gripper, steps to hold once there)
        (pose_at(rl, c + (0, 0, ABOVE)), 1.0, 0), (pose_at(rl, c), 1.0, 2),
        (pose_at(rl, c), -1.0, 8), (pose_at(rl, c + (0, 0, LIFT)), -1.0, 0),
        (pose_at(rl, (m[0], m[1], LIFT + HALF)), -1.0, 0), (pose_at(rl, down), -1.0, 2),
        (pose_at(rl, down), 1.0, 8), (pose_at(rl, (m[0], m[1], LIFT + HALF)), 1.0, 0),
        (pose_at(rl, (m[0], m[1] - 0.15, LIFT + HALF)), 1.0, 0),
    ]  # fmt: skip
    index = {"left": 0, "right": 0}
    held = {"left": 0, "right": 0}
    grip = {"left": 1.0, "right": 1.0}
    right: list[tuple[np.ndarray, float, int]] = []
    actions = []
    for _ in range(600):
        if right and index["right"] >= len(right) and env.is_success():
            return np.asarray(actions, np.float32)
        parts = []
        for arm in ("left", "right"):
            eef = arms[arm].eef_pose()
            if arm == "right" and not right:  # waits for the cube on the mark, left away
                if (
                    index["left"] >= len(left) - 1
                    and env.subtask_signals()["cube_released_on_mark"]
                ):
                    now = env.object_poses()
                    cube, goal = now["cube"][:3, 3], now["goal"][:3, 3]
                    rr = grasp_rotation(eef, now["cube"], math.pi / 2)
                    right = [
                        (pose_at(rr, cube + (0, 0, ABOVE)), 1.0, 0), (pose_at(rr, cube), 1.0, 2),
                        (pose_at(rr, cube), -1.0, 8), (pose_at(rr, cube + (0, 0, LIFT)), -1.0, 0),
                        (pose_at(rr, goal), -1.0, 10),
                    ]  # fmt: skip
                parts.append(arms[arm].target_pose_to_action(eef, grip[arm]))
                continue
            steps = left if arm == "left" else right
            if index[arm] >= len(steps):
                parts.append(arms[arm].target_pose_to_action(eef, grip[arm]))
                continue
            goal_pose, grip[arm], hold = steps[index[arm]]
            target, there = step_toward(eef, goal_pose)
            parts.append(arms[arm].target_pose_to_action(target, grip[arm]))
            if there and np.linalg.norm(eef[:3, 3] - goal_pose[:3, 3]) < 0.004:
                held[arm] += 1
                if held[arm] > hold:
                    index[arm], held[arm] = index[arm] + 1, 0
        action = np.concatenate(parts).astype(np.float32)
        env.step(action)
        actions.append(action)
    return None


TASK = ManiSkillTask(
    spec=TaskSpec(
        name="two_robot_pick_cube",
        objects=OBJECTS,
        subtasks=(
            SubtaskSpec("grasp_cube_left", "cube", "left_grasps_cube", arm="left"),
            SubtaskSpec("set_on_mark", "handover", "cube_released_on_mark", arm="left"),
            SubtaskSpec("retreat_left", "handover", None, arm="left"),
            SubtaskSpec("wait_for_handover", "handover", "cube_released_on_mark", arm="right"),
            SubtaskSpec("grasp_cube_right", "cube", "right_grasps_cube", arm="right"),
            SubtaskSpec("carry_to_goal", "goal", None, arm="right"),
        ),
        reset_variants={
            "D0": _variant(0.05, 0.2),
            "D1": _variant(0.1, 0.2),
            "D2": _variant(0.15, 0.25),
        },
        horizon=600,
        paper_task="none: two arms, beyond the paper (its limitation 9)",
        constraints=(
            SubtaskConstraint("sequential", ("left", "set_on_mark"), ("right", "grasp_cube_right")),
        ),
    ),
    base_env_id="TwoRobotPickCube-v1",
    objects={"cube": "cube", "handover": "handover", "goal": "goal_site"},
    signals=signals,
    evaluate=evaluate,
    initialize=initialize,
    load_scene=load_scene,
    arm_agents={"left": 0, "right": 1},
    demonstrator=demonstrate,
    video_view=((0.7, 0.0, 0.8), (-0.15, 0.0, 0.05)),
)
