"""peg_insertion: ManiSkill's PegInsertionSide-v1; the paper's Square (and Threading).

**Task Description:**
Grasp a peg lying on the table and insert it sideways into the hole of a box, 3 mm of
clearance. The peg is ManiSkill's draw for seed 2022 (its range: half-length 8.5-12.5 cm,
radius 1.5-2.5 cm): 17.1 cm long, radius 2.0 cm, into a hole of radius 2.3 cm, the same in
every episode.

**Randomizations:**
World frame: the table centre is the origin, the Panda base at x = -0.615 m; positions in
metres; yaw of the peg's long axis and of the box about world z, in degrees.
- D0: ManiSkill's own: the peg in x in [-0.1, 0.1], y in [-0.3, 0.0], yaw 90 +- 60 deg;
  the box in x in [-0.05, 0.05], y in [0.2, 0.4], yaw 90 +- 22.5 deg.
- D1: the peg in x in [-0.15, 0.15], y in [-0.35, 0.0], yaw 90 +- 90 deg; the box in x
  in [-0.1, 0.1], y in [0.15, 0.4], yaw as D0; centres at least 0.2 m apart.
- D2: D1 with the box's yaw 90 +- 45 deg.
- O1 (object transfer, paper F): D0's distribution with another peg, ManiSkill's draw for
  seed 7: half-length 8.8 cm (source 8.5), radius 2.3 cm (source 2.0), hole 2.6 cm (2.3).
  ManiSkill places the hole in the box by a draw of the same seed: (0, -0.40, +1.46) cm
  from the box's centre against the source scene's (0, -2.53, -2.94) cm. The box is
  therefore reported in its hole's frame (``frames``), so the insertion, carried in the
  box's frame, follows the hole.

**Success Conditions:**
ManiSkill's: the peg's head, in the hole's frame (x along the hole's axis), has
x >= -0.015 m and y, z within the hole's radius (2.3 cm) of the axis. Nothing is asked of
the grasp.

**Subtasks:**
- ``grasp_peg``, reference ``peg``: ends when ``grasp_peg`` (the agent's
  ``is_grasping(peg)``; ManiSkill's evaluate() has no grasp signal) turns true.
- ``insert_peg``, reference ``box`` (reported in its hole's frame): ends with the demo.
"""

from __future__ import annotations

import math

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


def _variant(box_yaw: float) -> ResetVariant:
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

# O1 draws the scene as D0 does; its box is reported in its hole's frame (``frames``), up to
# 2.2 cm from the box's actor along the box's y axis (about world -x at these yaws)
O1 = ResetVariant(
    {
        "peg": D0.bounds["peg"],
        "box": ObjectBounds((-0.075, 0.05), (0.19, 0.41), D0.bounds["box"].yaw),
    },
    native=True,
)

TASK = ManiSkillTask(
    spec=TaskSpec(
        name="peg_insertion",
        objects=("peg", "box"),
        subtasks=(
            SubtaskSpec("grasp_peg", "peg", "grasp_peg", (10, 15)),
            SubtaskSpec("insert_peg", "box", None),
        ),
        reset_variants={
            "D0": D0,
            "D1": _variant(22.5 * DEG),
            "D2": _variant(45 * DEG),
            "O1": O1,
        },
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
    # rebuilds it at every reset; built once (at creation, seed 2022) the peg is the same in
    # the planner's env, ManiSkill's converter and ours, and a stored state replays exactly
    env_kwargs={"reconfiguration_freq": 0},
    rebuild_seed=2022,
    variant_scene_seeds={"O1": 7},
    # the insertion is carried in the hole's frame, so that it follows the hole in O1's box
    frames={"box": hole_frame},
)
