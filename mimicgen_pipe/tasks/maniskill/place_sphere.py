"""place_sphere: ManiSkill's PlaceSphere-v1; the paper's Pick Place.

**Task Description:**
Grasp a 2 cm-radius sphere and place it in a small square bin (4 cm inside).

Source demos come from our own planner (``solve``), not ManiSkill's solution for the task:
that one takes the grasp from the sphere's oriented bounding box, whose axes are arbitrary
for a sphere (its three extents agree to 1e-5 m). trimesh computed them with last-bit
differences from one process to the next, which flipped the closing direction and gave
seed 18 a 105-, 125- or 134-step plan. A sphere can be grasped at any yaw, so ``solve``
closes along the hand's own horizontal axis.

**Randomizations:**
World frame: the table centre is the origin, the Panda base at x = -0.615 m; positions in
metres; the sphere's yaw means nothing and stays 0.
- D0: ManiSkill's own: the sphere in x in [-0.1, -0.05], y in [-0.1, 0.1]; the bin in
  x in [0.0, 0.1], y in [-0.1, 0.1], yaw 0.
- D1: the sphere in x in [-0.2, -0.05], y in [-0.2, 0.2]; the bin in x in [0.0, 0.15],
  y in [-0.2, 0.2], yaw 0; centres at least 0.08 m apart.
- D2: D1 with the bin's yaw in +-45 deg (+-pi/4 rad).

**Success Conditions:**
ManiSkill's:
- the sphere rests in the bin: centres within 5 mm in xy, and the sphere's centre its
  radius + half the bin floor's thickness (2.25 cm) above the bin's, +- 5 mm;
- the sphere is static (below 1 cm/s and 0.5 rad/s) and not grasped.

**Subtasks:**
- ``grasp_sphere``, reference ``sphere``: ends when ``grasp_sphere`` (ManiSkill's
  ``is_obj_grasped``) turns true.
- ``place_in_bin``, reference ``bin``: ends with the demo.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mimicgen_pipe.backends.maniskill.tasks import ManiSkillTask
from mimicgen_pipe.core.taskspec import ObjectBounds, ResetVariant, SubtaskSpec, TaskSpec

F32 = np.float32


def signals(env, info: dict) -> dict[str, Any]:
    return {"grasp_sphere": info["is_obj_grasped"]}


def evaluate(env) -> dict[str, bool]:
    from mimicgen_pipe.backends.maniskill import lean

    offset = lean.pose(env.obj)[0] - lean.pose(env.bin)[0]
    on_bin = bool(
        np.linalg.norm(offset[:2]) <= F32(0.005)
        and abs(offset[2] - F32(env.radius) - F32(env.block_half_size[0])) <= F32(0.005)
    )
    grasped = lean.is_grasping(env, env.obj)
    static = lean.is_static(env.obj, lin_thresh=1e-2, ang_thresh=0.5)
    return {"grasp_sphere": grasped, "success": on_bin and static and not grasped}


LIFT = 0.1  # [m] the sphere is carried this high above its start
RELEASE = 0.003  # [m] let go this far above the sphere's resting height in the bin


def solve(env, seed: int | None = None):
    """The source demonstrator: one planned demo on ManiSkill's ``pd_joint_pos`` env from
    reset ``seed``; ManiSkill's solution convention (the last step's result, or -1 where a
    motion cannot be planned). Top-down grasp at the sphere's centre, lift, carry over the
    bin, lower to just above the resting height, open."""
    import sapien
    from mani_skill.examples.motionplanning.panda.motionplanner import (
        PandaArmMotionPlanningSolver,
    )
    from transforms3d.euler import euler2quat

    env.reset(seed=seed)
    u = env.unwrapped
    planner = PandaArmMotionPlanningSolver(
        env,
        vis=False,
        base_pose=u.agent.robot.pose,
        visualize_target_grasp_pose=False,
        print_env_info=False,
    )

    def run() -> Any:
        down = np.array([0.0, 0.0, -1.0])
        closing = u.agent.tcp.pose.to_transformation_matrix()[0, :3, 1].cpu().numpy()
        closing[2] = 0.0
        sphere = u.obj.pose.sp.p
        upright = u.agent.build_grasp_pose(down, closing / np.linalg.norm(closing), sphere)
        # the first yaw about the vertical that a screw motion reaches
        for yaw in (0.0, np.pi / 4, -np.pi / 4, np.pi / 2, -np.pi / 2):
            grasp = upright * sapien.Pose(q=euler2quat(0, 0, yaw))
            if planner.move_to_pose_with_screw(grasp, dry_run=True) != -1:
                break
        else:
            return -1
        for target in (grasp * sapien.Pose([0, 0, -0.05]), grasp):
            if planner.move_to_pose_with_screw(target) == -1:
                return -1
        planner.close_gripper()
        if not u.agent.is_grasping(u.obj).item():
            return -1
        lifted = sapien.Pose([0, 0, LIFT]) * grasp
        if planner.move_to_pose_with_screw(lifted) == -1:
            return -1
        rest = u.bin.pose.sp.p + [0.0, 0.0, float(u.radius) + float(u.block_half_size[0])]
        to_rest = rest + [0.0, 0.0, RELEASE] - u.obj.pose.sp.p
        for target in (
            sapien.Pose(lifted.p + to_rest + [0.0, 0.0, LIFT], lifted.q),
            sapien.Pose(lifted.p + to_rest, lifted.q),
        ):
            if planner.move_to_pose_with_screw(target) == -1:
                return -1
        return planner.open_gripper()

    res = run()
    planner.close()
    return res


def _variant(bin_yaw: float) -> ResetVariant:
    return ResetVariant(
        {
            "sphere": ObjectBounds((-0.2, -0.05), (-0.2, 0.2), (0.0, 0.0)),
            "bin": ObjectBounds((0.0, 0.15), (-0.2, 0.2), (-bin_yaw, bin_yaw)),
        },
        min_distance=0.08,
    )


TASK = ManiSkillTask(
    spec=TaskSpec(
        name="place_sphere",
        objects=("sphere", "bin"),
        subtasks=(
            SubtaskSpec("grasp_sphere", "sphere", "grasp_sphere", (10, 15)),
            SubtaskSpec("place_in_bin", "bin", None),
        ),
        reset_variants={
            "D0": ResetVariant(
                {
                    "sphere": ObjectBounds((-0.1, -0.05), (-0.1, 0.1), (0.0, 0.0)),
                    "bin": ObjectBounds((0.0, 0.1), (-0.1, 0.1), (0.0, 0.0)),
                },
                native=True,
            ),
            "D1": _variant(0.0),
            "D2": _variant(math.pi / 4),
        },
        horizon=200,  # source demos take 121-141 steps
        paper_task="Pick Place",
    ),
    base_env_id="PlaceSphere-v1",
    planner=solve,
    objects={"sphere": "obj", "bin": "bin"},
    signals=signals,
    evaluate=evaluate,
    batched=True,
)
