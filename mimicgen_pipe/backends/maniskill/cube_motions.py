"""Scripted cube motions with ManiSkill's Panda motion planner, shared by the source
demonstrators of the cube-stacking tasks (mimicgen_pipe/tasks/maniskill/stack_pyramid.py,
stack_tower.py). ManiSkill is imported inside the functions only.

World frame: ManiSkill's, the table top is z = 0 with its centre at the origin; positions in
metres, quaternions wxyz.
"""

from __future__ import annotations

import numpy as np

HALF = 0.02  # [m] the half size of StackPyramid-v1's cubes
LIFT = 0.1  # [m] the hand rises after each grasp and each release


def panda_planner(env, seed: int | None):
    """``env`` reset to ``seed`` and ManiSkill's Panda motion planner on it."""
    from mani_skill.examples.motionplanning.panda.motionplanner import (
        PandaArmMotionPlanningSolver,
    )

    env.reset(seed=seed)
    u = env.unwrapped
    return PandaArmMotionPlanningSolver(
        env,
        vis=False,
        base_pose=u.agent.robot.pose,
        visualize_target_grasp_pose=False,
        print_env_info=False,
    )


def grasp(u, planner, actor) -> bool:
    """Grasp the cube ``actor`` from above and lift it by LIFT; False where a motion cannot
    be planned or the fingers end up without it."""
    import sapien
    from mani_skill.examples.motionplanning.base_motionplanner.utils import (
        compute_grasp_info_by_obb,
        get_actor_obb,
    )

    down = np.array([0.0, 0.0, -1.0])
    closing = u.agent.tcp.pose.to_transformation_matrix()[0, :3, 1].cpu().numpy()
    info = compute_grasp_info_by_obb(
        get_actor_obb(actor), approaching=down, target_closing=closing, depth=0.025
    )
    pose = u.agent.build_grasp_pose(down, info["closing"], info["center"])
    for target in (pose * sapien.Pose([0, 0, -0.05]), pose):
        if planner.move_to_pose_with_screw(target) == -1:
            return False
    planner.close_gripper()
    # a cube pressed against another may slip the fingers: no grasp, no demo
    if not u.agent.is_grasping(actor).item():
        return False
    # lifted well clear before the next subtask, whose motion is carried in another frame
    return planner.move_to_pose_with_screw(sapien.Pose([0, 0, LIFT]) * pose) != -1


def place(u, planner, actor, p: np.ndarray, q: np.ndarray):
    """The held ``actor`` put down with its centre at ``p`` [m] and the yaw of ``q`` (wxyz),
    both world frame, turned by the multiple of 90 deg nearest to the hand's present
    orientation, then let go and the hand raised by LIFT; -1 where a motion cannot be
    planned."""
    import sapien
    from transforms3d.euler import euler2quat

    tcp = u.agent.tcp.pose.sp
    to_tcp = actor.pose.sp.inv() * tcp
    goals = [
        sapien.Pose(p, q) * sapien.Pose(q=euler2quat(0, 0, k * np.pi / 2)) * to_tcp
        for k in range(4)
    ]
    goal = max(goals, key=lambda g: abs(float(np.dot(g.q, tcp.q))))
    for target in (
        sapien.Pose(goal.p + [0, 0, 0.05], goal.q),
        sapien.Pose(goal.p + [0, 0, 0.003], goal.q),
    ):
        if planner.move_to_pose_with_screw(target) == -1:
            return -1
    planner.open_gripper()
    return planner.move_to_pose_with_screw(sapien.Pose([0, 0, LIFT]) * u.agent.tcp.pose.sp)
