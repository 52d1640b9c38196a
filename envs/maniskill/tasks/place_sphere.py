"""place_sphere (ManiSkill PlaceSphere-v1; paper: Pick Place): grasp a 2 cm-radius sphere
and place it in a small square bin (4 cm inside). The grasp signal is ManiSkill's own
``is_obj_grasped``.

Reset variants (world frame; the table centre is the origin, the Panda base at x = -0.615;
the sphere's yaw means nothing and stays 0):
- D0: ManiSkill's own: the sphere in x in [-0.1, -0.05], y in [-0.1, 0.1]; the bin in
  x in [0.0, 0.1], y in [-0.1, 0.1], yaw 0.
- D1: the sphere in x in [-0.2, -0.05], y in [-0.2, 0.2]; the bin in x in [0.0, 0.15],
  y in [-0.2, 0.2], yaw 0.
- D2: D1 with the bin's yaw in +-45 deg.
"""

from __future__ import annotations

import math

import numpy as np

from envs.maniskill.tasks import ManiSkillTask
from mimicgen_pipe.taskspec import ObjectBounds, ResetVariant, SubtaskSpec, TaskSpec

F32 = np.float32


def signals(env, info: dict) -> dict[str, bool]:
    return {"grasp_sphere": bool(info["is_obj_grasped"])}


def evaluate(env) -> dict[str, bool]:
    from envs.maniskill import lean

    offset = lean.pose(env.obj)[0] - lean.pose(env.bin)[0]
    on_bin = bool(
        np.linalg.norm(offset[:2]) <= F32(0.005)
        and abs(offset[2] - F32(env.radius) - F32(env.block_half_size[0])) <= F32(0.005)
    )
    grasped = lean.is_grasping(env, env.obj)
    static = lean.is_static(env.obj, lin_thresh=1e-2, ang_thresh=0.5)
    return {"grasp_sphere": grasped, "success": on_bin and static and not grasped}


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
        horizon=200,  # source demos take 105-137 steps
        paper_task="Pick Place",
    ),
    base_env_id="PlaceSphere-v1",
    objects={"sphere": "obj", "bin": "bin"},
    signals=signals,
    evaluate=evaluate,
)
