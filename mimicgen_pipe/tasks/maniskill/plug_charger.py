"""plug_charger: ManiSkill's PlugCharger-v1; the paper's Coffee.

**Task Description:**
Grasp the charger and plug its two pins into the wall receptacle, 0.5 mm of clearance a
side.

Generation runs without action noise (max_action_noise 0): the clearance does not take it.
On D0 (40 attempts each, the same source demos) sigma 0.025 keeps 10 %, 0.01 17.5 %,
0.005 25 % and 0 65 %; every extra failure is a jammed plug-in, none a missed grasp.

**Randomizations:**
World frame: the table centre is the origin, the Panda base at x = -0.615 m; positions in
metres, yaw about world z in degrees. The goal pose follows the receptacle.
- D0: ManiSkill's own: the charger in x in [-0.1, -0.026], y in [-0.2, 0.2], yaw +-60 deg;
  the receptacle (10 cm above the table) in x in [0.01, 0.1], y in [-0.1, 0.1], yaw
  180 +- 22.5 deg.
- D1: the charger in x in [-0.2, -0.03], y in [-0.25, 0.25], yaw +-90 deg; the receptacle
  in x in [0.0, 0.12], y in [-0.15, 0.15], yaw as D0; centres at least 0.08 m apart.
- D2: D1 with the receptacle's yaw 180 +- 45 deg.

**Success Conditions:**
ManiSkill's: the charger within 5 mm and 0.2 rad of the goal pose (the receptacle's pose
turned half a turn about its z axis).

**Subtasks:**
- ``grasp_charger``, reference ``charger``: ends when ``grasp_charger`` (the agent's
  ``is_grasping(charger)``; ManiSkill's evaluate() has no grasp signal) turns true.
- ``plug_in``, reference ``receptacle``: ends with the demo.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mimicgen_pipe.backends.maniskill.tasks import ManiSkillTask
from mimicgen_pipe.core.taskspec import ObjectBounds, ResetVariant, SubtaskSpec, TaskSpec

DEG = math.pi / 180
BACK = 180 * DEG


def signals(env, info: dict) -> dict[str, Any]:
    return {"grasp_charger": env.agent.is_grasping(env.charger)}


def evaluate(env) -> dict[str, bool]:
    from mimicgen_pipe.backends.maniskill import lean

    # ManiSkill's success: the charger within 5 mm and 0.2 rad of the goal pose
    p, q = lean.pose(env.charger)
    goal = env.goal_pose.raw_pose[0].numpy()
    dist = np.linalg.norm(goal[:3] - p)
    rel = lean.quat_multiply(lean.quat_invert(goal[3:]), q)
    angle = 2 * math.atan2(float(np.linalg.norm(rel[1:])), float(rel[0]))
    angle = min(angle, 2 * math.pi - angle)
    return {
        "grasp_charger": lean.is_grasping(env, env.charger),
        "success": bool(dist <= 5e-3 and angle <= 0.2),
    }


def initialize(env, env_idx, variant: ResetVariant) -> None:
    from mimicgen_pipe.backends.maniskill.env import redraw_planar

    redraw_planar(env, env_idx, variant)
    restore(env)


def restore(env) -> None:
    """The goal follows the receptacle, as in ManiSkill's own reset; ManiSkill keeps it out
    of the simulator's state, so a restored state needs it again."""
    import sapien
    from transforms3d.euler import euler2quat

    env.goal_pose = env.receptacle.pose * sapien.Pose(q=euler2quat(0, 0, math.pi))


def _variant(receptacle_yaw: float) -> ResetVariant:
    return ResetVariant(
        {
            "charger": ObjectBounds((-0.2, -0.03), (-0.25, 0.25), (-90 * DEG, 90 * DEG)),
            "receptacle": ObjectBounds(
                (0.0, 0.12), (-0.15, 0.15), (BACK - receptacle_yaw, BACK + receptacle_yaw)
            ),
        },
        min_distance=0.08,
    )


TASK = ManiSkillTask(
    spec=TaskSpec(
        name="plug_charger",
        objects=("charger", "receptacle"),
        subtasks=(
            SubtaskSpec("grasp_charger", "charger", "grasp_charger", (10, 15)),
            SubtaskSpec("plug_in", "receptacle", None),
        ),
        reset_variants={
            "D0": ResetVariant(
                {
                    "charger": ObjectBounds((-0.1, -0.026), (-0.2, 0.2), (-60 * DEG, 60 * DEG)),
                    "receptacle": ObjectBounds(
                        (0.01, 0.1), (-0.1, 0.1), (BACK - 22.5 * DEG, BACK + 22.5 * DEG)
                    ),
                },
                native=True,
            ),
            "D1": _variant(22.5 * DEG),
            "D2": _variant(45 * DEG),
        },
        horizon=300,  # generated demos take 185 steps (median), up to 244
        paper_task="Coffee",
        max_action_noise=0.0,
    ),
    base_env_id="PlugCharger-v1",
    objects={"charger": "charger", "receptacle": "receptacle"},
    signals=signals,
    evaluate=evaluate,
    panda_uid="panda_wristcam",  # the only robot the task supports and resets
    initialize=initialize,
    restore=restore,
    batched=True,
)
