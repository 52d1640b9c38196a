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

from mimicgen_pipe.backends.maniskill.peg_in_hole import D0, DEG, peg_task, variant
from mimicgen_pipe.core.taskspec import ObjectBounds, ResetVariant

# O1 draws the scene as D0 does; its box is reported in its hole's frame (``frames``), up to
# 2.2 cm from the box's actor along the box's y axis (about world -x at these yaws)
O1 = ResetVariant(
    {
        "peg": D0.bounds["peg"],
        "box": ObjectBounds((-0.075, 0.05), (0.19, 0.41), D0.bounds["box"].yaw),
    },
    native=True,
)

TASK = peg_task(
    "peg_insertion",
    {"D0": D0, "D1": variant(22.5 * DEG), "D2": variant(45 * DEG), "O1": O1},
    variant_scene_seeds={"O1": 7},
)
