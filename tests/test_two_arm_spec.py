"""Task specs with two arms (mimicgen_pipe.core.taskspec): each arm's own ordered subtasks, the
constraints between two arms' subtasks (sequential, coordinated), and every inconsistency
refused when the task file builds its spec; one-arm tasks are the one-arm case."""

from __future__ import annotations

import pytest

from mimicgen_pipe import backends
from mimicgen_pipe.core.taskspec import (
    ARM,
    ObjectBounds,
    ResetVariant,
    SubtaskConstraint,
    SubtaskSpec,
    TaskSpec,
)

BOX = ObjectBounds((-0.1, 0.1), (-0.1, 0.1), (0.0, 0.0))
VARIANTS = {"D0": ResetVariant({"tray": BOX, "cube": BOX})}
LEFT = (
    SubtaskSpec("grasp_tray_left", "tray", "left_grasped", arm="left"),
    SubtaskSpec("lift_left", "tray", None, arm="left"),
)
RIGHT = (
    SubtaskSpec("grasp_cube", "cube", "cube_grasped", arm="right"),
    SubtaskSpec("place_cube", "tray", "cube_placed", arm="right"),
    SubtaskSpec("grasp_tray_right", "tray", "right_grasped", arm="right"),
    SubtaskSpec("lift_right", "tray", None, arm="right"),
)


def two_arm(*constraints: SubtaskConstraint, subtasks=LEFT + RIGHT) -> TaskSpec:
    return TaskSpec("tray_lift", ("tray", "cube"), subtasks, VARIANTS, 400, constraints=constraints)


def sequential(a, b) -> SubtaskConstraint:
    return SubtaskConstraint("sequential", a, b)


def coordinated(a, b) -> SubtaskConstraint:
    return SubtaskConstraint("coordinated", a, b)


def test_each_arm_has_its_own_ordered_subtasks():
    spec = two_arm(
        sequential(("right", "place_cube"), ("left", "grasp_tray_left")),
        coordinated(("left", "lift_left"), ("right", "lift_right")),
    )
    assert spec.arms == ("left", "right")
    assert [s.name for s in spec.arm_subtasks("right")] == [s.name for s in RIGHT]
    assert spec.arm_subtasks("left") == LEFT
    # interleaved in the flat tuple, each arm's order is its own
    mixed = two_arm(subtasks=(RIGHT[0], LEFT[0], RIGHT[1], RIGHT[2], LEFT[1], RIGHT[3]))
    assert mixed.arm_subtasks("left") == LEFT and mixed.arm_subtasks("right") == RIGHT


@pytest.mark.parametrize(
    "backend, several",
    [
        ("maniskill", {"two_robot_stack_cube", "two_robot_lift_bar", "two_robot_pick_cube"}),
        ("pybullet", set()),
    ],
)
def test_every_other_task_of_the_package_is_the_one_arm_case(backend, several):
    for name in backends.task_names(backend):
        spec = backends.task_spec(backend, name)
        if name in several:
            assert len(spec.arms) == 2 and spec.constraints
            continue
        assert spec.arms == (ARM,) and spec.constraints == ()
        assert spec.arm_subtasks(ARM) == spec.subtasks


@pytest.mark.parametrize(
    "constraints, message",
    [
        (
            [sequential(("middle", "lift_left"), ("right", "lift_right"))],
            "no arm 'middle' (arms: left, right)",
        ),
        (
            [sequential(("left", "lift"), ("right", "lift_right"))],
            "arm left has no subtask 'lift' (its subtasks: grasp_tray_left, lift_left)",
        ),
        (
            [sequential(("right", "grasp_cube"), ("right", "lift_right"))],
            "a constraint is between two arms",
        ),
        (
            [coordinated(("left", "grasp_tray_left"), ("right", "grasp_cube"))],
            "move relative to one object; they name tray and cube",
        ),
        (  # each arm waits for the other
            [
                sequential(("left", "grasp_tray_left"), ("right", "grasp_cube")),
                sequential(("right", "grasp_cube"), ("left", "grasp_tray_left")),
            ],
            "the constraints make a cycle",
        ),
        (  # through the arms' own orders: right grasps the cube once left has lifted,
            # and left grasps the tray (before its lift) once right has placed the cube
            [
                sequential(("left", "lift_left"), ("right", "grasp_cube")),
                sequential(("right", "place_cube"), ("left", "grasp_tray_left")),
            ],
            "the constraints make a cycle",
        ),
        (  # started together, yet one after the other
            [
                coordinated(("left", "lift_left"), ("right", "lift_right")),
                sequential(("left", "lift_left"), ("right", "lift_right")),
            ],
            "the constraints make a cycle",
        ),
    ],
)
def test_inconsistent_constraints_are_refused(constraints, message):
    with pytest.raises(ValueError, match="task tray_lift: ") as err:
        two_arm(*constraints)
    assert message in str(err.value)


def test_each_arms_last_subtask_ends_with_the_demo():
    left = (LEFT[0], SubtaskSpec("lift_left", "tray", "lifted", arm="left"))
    with pytest.raises(ValueError, match="the final subtask of arm left ends with the demo"):
        two_arm(subtasks=left + RIGHT)
    twice = (LEFT[0], LEFT[0], LEFT[1])
    with pytest.raises(ValueError, match="arm left has two subtasks of one name"):
        two_arm(subtasks=twice + RIGHT)


def test_planned_transit_for_two_arms_is_refused():
    with pytest.raises(Exception, match="the task has 2 arms and the motion planner plans for one"):
        backends.check_transit("maniskill", "panda", "planned", 2)
    backends.check_transit("maniskill", "panda", "linear", 2)  # linear transit: any number of arms
