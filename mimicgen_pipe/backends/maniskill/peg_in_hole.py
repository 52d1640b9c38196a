"""What ManiSkill's PegInsertionSide-v1 tasks share (mimicgen_pipe/tasks/maniskill/
peg_insertion.py, peg_insertion_square.py): their subtask signals, success test, reset
variants D0-D2 and the task they build, which differ only in the hole's clearance and the
variants they list. ManiSkill is imported inside the functions only.

World frame: the table centre is the origin, the Panda base at x = -0.615 m; positions in
metres; yaw of the peg's long axis and of the box about world z, in radians.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mimicgen_pipe.backends.maniskill.tasks import ManiSkillTask
from mimicgen_pipe.core.taskspec import ObjectBounds, ResetVariant, SubtaskSpec, TaskSpec

F32 = np.float32

DEG = math.pi / 180
UP = 90 * DEG


def signals(env, info: dict) -> dict[str, bool]:
    return {"grasp_peg": bool(env.agent.is_grasping(env.peg))}


def evaluate(env) -> dict[str, bool]:
    from mimicgen_pipe.backends.maniskill import lean

    # ManiSkill's has_peg_inserted
    x, y, z = head_in_hole(env)
    r = env.box_hole_radii.numpy()[0]
    inserted = bool(F32(-0.015) <= x and -r <= y <= r and -r <= z <= r)
    return {"grasp_peg": lean.is_grasping(env, env.peg), "success": inserted}


def head_in_hole(env) -> np.ndarray:
    """The peg's head in the hole's frame (3,) [m], float32: x along the hole's axis (the
    box's face at minus the peg's half-length), y and z across it. ``env``: ManiSkill's."""
    from mimicgen_pipe.backends.maniskill import lean

    hole = lean.offset_pose(env.box, env.box_hole_offsets)
    head = lean.offset_pose(env.peg, env.peg_head_offsets)
    return lean.pose_multiply(lean.pose_inverse(*hole), head)[0]


def hole_frame(env) -> np.ndarray:
    """The hole in the box's frame (4x4, [m]): ManiSkill draws its place in the box with
    the peg, so it moves when the scene is built with another seed (O1)."""
    from mimicgen_pipe.core.poses import pose_from_pq

    offset = env.box_hole_offsets
    return pose_from_pq(
        offset.p.numpy()[0].astype(np.float64), offset.q.numpy()[0].astype(np.float64)
    )


def variant(box_yaw: float) -> ResetVariant:
    return ResetVariant(
        {
            "peg": ObjectBounds((-0.15, 0.15), (-0.35, 0.0), (UP - 90 * DEG, UP + 90 * DEG)),
            "box": ObjectBounds((-0.1, 0.1), (0.15, 0.4), (UP - box_yaw, UP + box_yaw)),
        },
        min_distance=0.2,
    )


D0 = ResetVariant(
    {
        "peg": ObjectBounds((-0.1, 0.1), (-0.3, 0.0), (UP - 60 * DEG, UP + 60 * DEG)),
        "box": ObjectBounds((-0.05, 0.05), (0.2, 0.4), (UP - 22.5 * DEG, UP + 22.5 * DEG)),
    },
    native=True,
)


def peg_task(name: str, reset_variants: dict[str, ResetVariant], **fields: Any) -> ManiSkillTask:
    """The peg-in-hole task ``name`` with ``reset_variants``; ``fields``: the ManiSkillTask
    fields it sets beyond the shared ones (its planner, scene seeds, env attributes)."""
    return ManiSkillTask(
        spec=TaskSpec(
            name=name,
            objects=("peg", "box"),
            subtasks=(
                SubtaskSpec("grasp_peg", "peg", "grasp_peg", (10, 15)),
                SubtaskSpec("insert_peg", "box", None),
            ),
            reset_variants=reset_variants,
            # generated demos take 165 steps (median), up to 214; the paper rolls Square out
            # for 400 (MimicGen's training configs)
            horizon=400,
            paper_task="Square",
        ),
        base_env_id="PegInsertionSide-v1",
        objects={"peg": "peg", "box": "box"},
        signals=signals,
        evaluate=evaluate,
        panda_uid="panda_wristcam",  # the only robot the task supports and resets
        # ManiSkill draws the peg's length and radius when it builds the scene, and by default
        # rebuilds it at every reset; built once (at creation, seed 2022) the peg is the same
        # in the planner's env, ManiSkill's converter and ours, and a stored state replays
        # exactly
        env_kwargs={"reconfiguration_freq": 0},
        rebuild_seed=2022,
        # the insertion is carried in the hole's frame, so that it follows the hole in O1's box
        frames={"box": hole_frame},
        **fields,
    )
