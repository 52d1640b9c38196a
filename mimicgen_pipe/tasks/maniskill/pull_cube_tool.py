"""pull_cube_tool: ManiSkill's PullCubeTool-v1; the paper's Hammer Cleanup (tool use).

**Task Description:**
Grasp the L-shaped tool (20 cm handle, 5 cm hook), reach behind the 4 cm cube with the hook
and pull the cube towards the robot.

**Randomizations:**
World frame: the table centre is the origin, the Panda base at x = -0.615 m; positions in
metres, yaw about world z in degrees.
- D0: ManiSkill's own: the tool in x, y in [-0.3, -0.1], yaw 0; the cube in x in
  [0.05, 0.25], y in [-0.25, 0.05], yaw in +-30 deg.
- D1: the tool in x in [-0.35, -0.05], y in [-0.35, 0.0], yaw in +-30 deg; the cube in
  x in [0.05, 0.3], y in [-0.3, 0.1], yaw in +-45 deg; centres at least 0.1 m apart.
- D2: D1 with the tool's yaw in +-60 deg and the cube's in +-60 deg.

**Success Conditions:**
ManiSkill's: the cube's centre less than 0.6 m from the robot base in xy.

**Subtasks:**
- ``grasp_tool``, reference ``tool``: ends when ``grasp_tool`` (the agent's
  ``is_grasping(tool)``; ManiSkill's evaluate() has no grasp signal) turns true.
- ``pull_cube``, reference ``cube``: ends with the demo.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mimicgen_pipe.backends.maniskill.tasks import ManiSkillTask
from mimicgen_pipe.core.taskspec import ObjectBounds, ResetVariant, SubtaskSpec, TaskSpec

F32 = np.float32

DEG = math.pi / 180


def signals(env, info: dict) -> dict[str, Any]:
    return {"grasp_tool": env.agent.is_grasping(env.l_shape_tool)}


def evaluate(env) -> dict[str, bool]:
    from mimicgen_pipe.backends.maniskill import lean

    cube = lean.pose(env.cube)[0]
    base = env.agent.robot.get_links()[0]._objs[0].entity_pose.p
    pulled = bool(np.linalg.norm(cube[:2] - base[:2]) < F32(0.6))
    return {"grasp_tool": lean.is_grasping(env, env.l_shape_tool), "success": pulled}


def _variant(tool_yaw: float, cube_yaw: float) -> ResetVariant:
    return ResetVariant(
        {
            "tool": ObjectBounds((-0.35, -0.05), (-0.35, 0.0), (-tool_yaw, tool_yaw)),
            "cube": ObjectBounds((0.05, 0.3), (-0.3, 0.1), (-cube_yaw, cube_yaw)),
        },
        min_distance=0.1,
    )


TASK = ManiSkillTask(
    spec=TaskSpec(
        name="pull_cube_tool",
        objects=("tool", "cube"),
        subtasks=(
            SubtaskSpec("grasp_tool", "tool", "grasp_tool", (10, 15)),
            SubtaskSpec("pull_cube", "cube", None),
        ),
        reset_variants={
            "D0": ResetVariant(
                {
                    "tool": ObjectBounds((-0.3, -0.1), (-0.3, -0.1), (0.0, 0.0)),
                    "cube": ObjectBounds((0.05, 0.25), (-0.25, 0.05), (-30 * DEG, 30 * DEG)),
                },
                native=True,
            ),
            "D1": _variant(30 * DEG, 45 * DEG),
            "D2": _variant(60 * DEG, 60 * DEG),
        },
        horizon=350,  # source demos take 215-282 steps
        paper_task="Hammer Cleanup",
    ),
    base_env_id="PullCubeTool-v1",
    objects={"tool": "l_shape_tool", "cube": "cube"},
    signals=signals,
    evaluate=evaluate,
    batched=True,
)
