"""peg_insertion_square (paper: Square, at Square's tolerance): peg_insertion's task with the
clearance of robosuite's Square, 6.75 mm between peg and hole on each side, where ManiSkill's
PegInsertionSide leaves 3 mm. Square's square peg is 3.2 cm across and its nut's hole 4.55 cm
(robosuite's square-nut.xml); here the same 17.1 cm peg of radius 2.0 cm goes into a hole of
radius 2.675 cm. Everything else is peg_insertion's (envs/maniskill/tasks/peg_insertion.py):
the peg, the box, the subtasks, the success test (ManiSkill's, against the wider hole),
reset variants D0-D2 and the horizon. peg_insertion stays ManiSkill's harder benchmark; this
one compares with the paper's Square row.

Its env class is PegInsertionSide's with ``_clearance`` set (``env_attributes``), registered
under an id of its own, and ManiSkill's motion planner records its source demos in it.
"""

from __future__ import annotations

import dataclasses

from envs.maniskill.tasks import ManiSkillTask
from envs.maniskill.tasks.peg_insertion import TASK as PEG_INSERTION

SQUARE_CLEARANCE = 0.00675  # [m] on each side: (4.55 - 3.2) cm / 2, robosuite's Square

_spec = PEG_INSERTION.spec
TASK: ManiSkillTask = dataclasses.replace(
    PEG_INSERTION,
    spec=dataclasses.replace(
        _spec,
        name="peg_insertion_square",
        # O1's other peg is peg_insertion's object-transfer study; not repeated here
        reset_variants={v: _spec.reset_variants[v] for v in ("D0", "D1", "D2")},
    ),
    planner="PegInsertionSide-v1",  # ManiSkill's motion-planning solution for the task
    variant_scene_seeds={},
    env_attributes={"_clearance": SQUARE_CLEARANCE},
)
