"""peg_insertion_square: ManiSkill's PegInsertionSide-v1 at the tolerance of the paper's
Square.

**Task Description:**
peg_insertion's task with the clearance of robosuite's Square, 6.75 mm between peg and hole
on each side, where ManiSkill's PegInsertionSide leaves 3 mm. Square's square peg is 3.2 cm
across and its nut's hole 4.55 cm (robosuite's square-nut.xml); here the same 17.1 cm peg of
radius 2.0 cm goes into a hole of radius 2.675 cm. Everything else is peg_insertion's
(mimicgen_pipe/backends/maniskill/peg_in_hole.py): the peg, the box, the subtasks, the
success test, reset variants D0-D2 and the horizon. peg_insertion stays ManiSkill's harder
benchmark; this one compares with the paper's Square row.

Its env class is PegInsertionSide's with ``_clearance`` set (``env_attributes``), registered
under an id of its own, and ManiSkill's motion planner records its source demos in it.

**Randomizations:**
peg_insertion's D0-D2 (its O1 is not repeated here). World frame: the table centre is the
origin, the Panda base at x = -0.615 m; positions in metres; yaw of the peg's long axis and
of the box about world z, in degrees.
- D0: ManiSkill's own: the peg in x in [-0.1, 0.1], y in [-0.3, 0.0], yaw 90 +- 60 deg;
  the box in x in [-0.05, 0.05], y in [0.2, 0.4], yaw 90 +- 22.5 deg.
- D1: the peg in x in [-0.15, 0.15], y in [-0.35, 0.0], yaw 90 +- 90 deg; the box in x
  in [-0.1, 0.1], y in [0.15, 0.4], yaw as D0; centres at least 0.2 m apart.
- D2: D1 with the box's yaw 90 +- 45 deg.

**Success Conditions:**
ManiSkill's, against the wider hole: the peg's head, in the hole's frame (x along the
hole's axis), has x >= -0.015 m and y, z within the hole's radius (2.675 cm) of the axis.

**Subtasks:**
peg_insertion's:
- ``grasp_peg``, reference ``peg``: ends when ``grasp_peg`` (the agent's
  ``is_grasping(peg)``) turns true.
- ``insert_peg``, reference ``box`` (reported in its hole's frame): ends with the demo.
"""

from __future__ import annotations

from mimicgen_pipe.backends.maniskill.peg_in_hole import D0, DEG, peg_task, variant

SQUARE_CLEARANCE = 0.00675  # [m] on each side: (4.55 - 3.2) cm / 2, robosuite's Square

TASK = peg_task(
    "peg_insertion_square",
    # O1's other peg is peg_insertion's object-transfer study; not repeated here
    {"D0": D0, "D1": variant(22.5 * DEG), "D2": variant(45 * DEG)},
    planner="PegInsertionSide-v1",  # ManiSkill's motion-planning solution for the task
    env_attributes={"_clearance": SQUARE_CLEARANCE},
)
