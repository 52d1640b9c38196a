"""two_robot_lift_bar: on ManiSkill's TwoRobotStackCube-v1 scene; beyond the paper (two
arms, its limitation 9).

**Task Description:**
A bar 40 cm long lies between two Pandas that face each other across the table (bases at
y = -0.75 and +0.75 m). Each arm grasps its end of the bar; then both lift it together,
level, 10 cm and more.

The scene: TwoRobotStackCube-v1's table and robots, its two cubes set aside at the table's far
edge (x = 0.25, y = -/+0.4), its goal disc unused, and the bar (3 x 40 x 3 cm, 300 kg/m^3,
0.11 kg) added by ``load_scene``.

**Randomizations:**
World frame: the table centre is the origin; positions in metres, the bar's yaw about world
z in radians (yaw 0: along world y). ManiSkill's reset, the cubes set aside, then the bar
uniform in its box:
- D0: bar centre x in [-0.05, 0.05], y in [-0.03, 0.03], yaw in [-0.2, 0.2].
- D1: x in [-0.1, 0.1], y in [-0.06, 0.06], yaw in [-0.4, 0.4].
- D2: x in [-0.15, 0.15], y in [-0.1, 0.1], yaw in [-0.6, 0.6].

**Success Conditions:**
- both hands grasp the bar;
- its centre is at least 10 cm above the table;
- its long axis is within 0.1 rad of level.

**Subtasks:**
Arms: ``left`` (ManiSkill's agent 0, at y = -0.75) and ``right`` (agent 1). Constraint: the
two lifts are coordinated: they start together, follow one source demo and move by one
observed pose of the bar, step for step, as a bar held at both ends must.
- ``grasp_bar_left`` (arm ``left``), reference ``bar``: ends when ``bar_held_by_both``
  turns true: both hands grasp the bar.
- ``lift_bar_left`` (arm ``left``), reference ``bar``: ends with the demo.
- ``grasp_bar_right`` (arm ``right``), reference ``bar``: ends when ``bar_held_by_both``
  turns true.
- ``lift_bar_right`` (arm ``right``), reference ``bar``: ends with the demo.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mimicgen_pipe.backends.maniskill.tasks import ManiSkillTask
from mimicgen_pipe.backends.maniskill.two_arm import STEP, grasp_rotation, pose_at, step_toward
from mimicgen_pipe.core.taskspec import (
    ObjectBounds,
    ResetVariant,
    SubtaskConstraint,
    SubtaskSpec,
    TaskSpec,
)

OBJECTS = ("bar",)
BAR_HALF = (0.015, 0.2, 0.015)  # [m] half extents along the bar's own x, y (long), z
BAR_DENSITY = 300.0  # [kg/m^3]
GRIP = 0.15  # [m] from the bar's centre to where each hand holds it
LIFTED, LEVEL = 0.10, 0.1  # [m] centre height for success; [rad] largest tilt


def _variant(x: float, y: float, yaw: float) -> ResetVariant:
    return ResetVariant({"bar": ObjectBounds((-x, x), (-y, y), (-yaw, yaw))})


def load_scene(env) -> None:
    """Add the bar to TwoRobotStackCube-v1's scene."""
    import sapien

    builder = env.scene.create_actor_builder()
    builder.add_box_collision(half_size=BAR_HALF, density=BAR_DENSITY)
    builder.add_box_visual(
        half_size=BAR_HALF,
        material=sapien.render.RenderMaterial(base_color=[0.85, 0.55, 0.1, 1.0]),
    )
    builder.initial_pose = sapien.Pose(p=[0.0, 0.0, BAR_HALF[2]])
    env.bar = builder.build(name="bar")


def initialize(env, env_idx, variant: ResetVariant) -> None:
    """ManiSkill's reset of the robots and table, the cubes set aside, the bar drawn."""
    from mimicgen_pipe.backends.maniskill.env import draw_planar, set_planar_poses

    env.native_initialize(env_idx)
    b = len(env_idx)
    aside = [np.tile([[0.25, -0.4]], (b, 1)), np.tile([[0.25, 0.4]], (b, 1))]
    set_planar_poses([env.cubeA, env.cubeB], aside, [np.zeros(b), np.zeros(b)], [0.02, 0.02])
    xy, yaw = draw_planar(variant, OBJECTS, b, (0.0, 0.0))
    set_planar_poses([env.bar], xy, yaw, [BAR_HALF[2]])


def _tilt(env) -> Any:
    """The angle [rad] between the bar's long axis and the table, per scene."""
    import torch
    from mani_skill.utils.geometry.rotation_conversions import quaternion_to_matrix

    axis = quaternion_to_matrix(env.bar.pose.q)[:, :, 1]  # the bar's y axis in the world
    return torch.asin(axis[:, 2].abs().clamp(max=1.0))


def signals(env, info: dict) -> dict[str, Any]:
    left, right = env.agent.agents
    held = left.is_grasping(env.bar) & right.is_grasping(env.bar)
    return {"bar_held_by_both": held}


def evaluate(env) -> dict[str, bool]:
    held = signals(env, {})["bar_held_by_both"]
    lifted = env.bar.pose.p[:, 2] >= LIFTED
    success = held & lifted & (_tilt(env) <= LEVEL)
    return {"bar_held_by_both": bool(held), "success": bool(success)}


# -- the scripted demonstrator ----------------------------------------------------------------
ABOVE = 0.08  # [m] approach height above the grasp
LIFT = (0.10, 0.22)  # [m] the range a demo's lift height is drawn from
LIFT_STEP = (0.005, 0.012)  # [m] the range of a demo's lift speed per step


def demonstrate(env, seed: int) -> np.ndarray | None:
    """Both arms in step: above their ends of the bar, down, close (once both are there), a
    pause, then up together (the same move each step) by a height and at a speed drawn per
    demo from ``seed`` (LIFT, LIFT_STEP), and a pause. Each arm moves at most 1.2 cm and
    0.08 rad per step. Demos lift differently, so two arms lifting by two demos would tilt
    the bar: the lifts must follow one demo (the coordinated constraint)."""
    rng = np.random.default_rng(seed)
    lift, lift_step = rng.uniform(*LIFT), rng.uniform(*LIFT_STEP)
    arms = {a: env.arm(a) for a in ("left", "right")}
    bar = env.object_poses()["bar"]
    along = bar[:3, 1]  # the bar's long axis in the world
    ends = {"left": bar[:3, 3] - GRIP * along, "right": bar[:3, 3] + GRIP * along}
    if ends["left"][1] > ends["right"][1]:
        ends = {"left": ends["right"], "right": ends["left"]}
    # the fingers close across the bar: the TCP's x axis along the bar's long axis
    rot = {a: grasp_rotation(arms[a].eef_pose(), bar, math.pi, math.pi / 2) for a in arms}
    up = np.array([0.0, 0.0, ABOVE])
    phases = [  # per arm (target position, gripper); steps to hold once both are there; speed
        ({a: (ends[a] + up, 1.0) for a in arms}, 0, STEP),
        ({a: (ends[a], 1.0) for a in arms}, 3, STEP),
        ({a: (ends[a], -1.0) for a in arms}, 10, STEP),
        ({a: (ends[a] + (0, 0, lift), -1.0) for a in arms}, 8, lift_step),
    ]
    actions, phase, held = [], 0, 0
    for _ in range(400):
        if phase == len(phases):
            return np.asarray(actions, np.float32) if env.is_success() else None
        goals, hold, step = phases[phase]
        parts, there = [], True
        for a in ("left", "right"):
            eef = arms[a].eef_pose()
            goal = pose_at(rot[a], goals[a][0])
            target, arrived = step_toward(eef, goal, step)
            there &= arrived and np.linalg.norm(eef[:3, 3] - goal[:3, 3]) < 0.004
            parts.append(arms[a].target_pose_to_action(target, goals[a][1]))
        action = np.concatenate(parts).astype(np.float32)
        env.step(action)
        actions.append(action)
        if there:
            held += 1
            if held > hold:
                phase, held = phase + 1, 0
    return None


TASK = ManiSkillTask(
    spec=TaskSpec(
        name="two_robot_lift_bar",
        objects=OBJECTS,
        subtasks=(
            SubtaskSpec("grasp_bar_left", "bar", "bar_held_by_both", arm="left"),
            SubtaskSpec("lift_bar_left", "bar", None, arm="left"),
            SubtaskSpec("grasp_bar_right", "bar", "bar_held_by_both", arm="right"),
            SubtaskSpec("lift_bar_right", "bar", None, arm="right"),
        ),
        reset_variants={
            "D0": _variant(0.05, 0.03, 0.2),
            "D1": _variant(0.1, 0.06, 0.4),
            "D2": _variant(0.15, 0.1, 0.6),
        },
        horizon=300,
        paper_task="none: two arms, beyond the paper (its limitation 9)",
        constraints=(
            SubtaskConstraint(
                "coordinated", ("left", "lift_bar_left"), ("right", "lift_bar_right")
            ),
        ),
    ),
    base_env_id="TwoRobotStackCube-v1",
    objects={"bar": "bar"},
    signals=signals,
    evaluate=evaluate,
    initialize=initialize,
    load_scene=load_scene,
    arm_agents={"left": 0, "right": 1},
    demonstrator=demonstrate,
    video_view=((0.55, 0.0, 0.75), (-0.15, 0.0, 0.05)),
)
