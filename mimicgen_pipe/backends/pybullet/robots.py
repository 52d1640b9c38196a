"""Arms of the PyBullet back end, built from the URDFs shipped in pybullet_data.

Every arm carries the same parallel gripper, the Franka hand (links panda_hand, the two
prismatic fingers, and the TCP frame panda_grasptarget 0.105 m ahead of the hand along its
z axis, between the fingertips). On the Panda it is the URDF's own hand; on the KUKA iiwa and
the xArm6 it is mounted on the flange by a fixed joint. The TCP is therefore calibrated
across arms by construction: the same gripper geometry around the same TCP frame, so a
TCP target pose recorded with the Panda means the same grasp on any arm. Each arm starts at
the same home TCP pose (pointing down, fingers along world y).

The kinematic chain (base link -> TCP) is parsed from the same URDF text with
pytorch-kinematics and handed to mimicgen_pipe.core.kinematics as arrays.
"""

from __future__ import annotations

import functools
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.kinematics import Chain
from mimicgen_pipe.core.urdf import (
    PANDA_URDF,
    add_fixed_joint,
    franka_hand,
    load_urdf,
    urdf_file,
)

CONTROL = ("ee_delta_pose", 20)  # every arm's controller here, and its rate [Hz]
TCP_LINK = "panda_grasptarget"
# home TCP pose in the robot base frame: 0.45 m ahead, 0.25 m up, z axis pointing down
HOME_TCP = np.array(
    [[1.0, 0.0, 0.0, 0.45], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.25], [0.0, 0.0, 0.0, 1.0]]
)


@dataclass(frozen=True)
class RobotSpec:
    """urdf: the arm's URDF, relative to pybullet_data or absolute. flange: link the Franka
    hand is mounted on (None: the URDF has the hand). mount_xyz [m] / mount_rpy [rad]: the
    mounting joint's origin in the flange frame. seed_q: joint positions [rad] the home IK
    starts from (elbow up, hand over the table)."""

    name: str
    urdf: str
    flange: str | None
    seed_q: tuple[float, ...]
    mount_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mount_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)


ROBOTS = {
    "panda": RobotSpec("panda", PANDA_URDF, None, (0.0, -0.3, 0.0, -2.2, 0.0, 1.9, 0.785)),
    # the iiwa's flange face is 0.045 m beyond the link_7 frame; the hand is turned half a
    # turn so that the home pose needs no wrist rotation near joint 7's +-3.05 rad limits
    "iiwa": RobotSpec(
        "iiwa",
        "kuka_iiwa/model.urdf",
        "lbr_iiwa_link_7",
        (0.0, 0.35, 0.0, -1.75, 0.0, 1.05, 0.0),
        mount_xyz=(0.0, 0.0, 0.045),
        mount_rpy=(0.0, 0.0, float(np.pi)),
    ),
    # link6's frame is the xArm6 flange face
    "xarm6": RobotSpec("xarm6", "xarm/xarm6_robot.urdf", "link6", (0.0, 0.2, -1.2, 0.0, 1.0, 0.0)),
}


def robot_spec(name: str) -> RobotSpec:
    if name not in ROBOTS:
        raise InputError(f"robot {name!r}: unknown for pybullet (known: {', '.join(ROBOTS)})")
    return ROBOTS[name]


@functools.lru_cache
def robot_urdf_text(spec: RobotSpec) -> str:
    """The URDF of ``spec``'s arm with the Franka hand, mesh paths made absolute."""
    arm = load_urdf(spec.urdf)
    if spec.flange is not None:
        arm.extend(franka_hand(("panda_grasptarget",), ("panda_grasptarget_hand",)))
        add_fixed_joint(
            arm,
            "hand_mount",
            spec.flange,
            "panda_hand",
            " ".join(map(str, spec.mount_xyz)),
            " ".join(map(str, spec.mount_rpy)),
        )
    return ET.tostring(arm, encoding="unicode")


def robot_urdf_file(spec: RobotSpec) -> Path:
    """``robot_urdf_text`` in a file PyBullet can load."""
    return urdf_file(robot_urdf_text(spec), spec.name)


def robot_chain(spec: RobotSpec) -> Chain:
    """The base link -> TCP chain of ``spec``'s arm, parsed with pytorch-kinematics."""
    import pytorch_kinematics as pk
    from pytorch_kinematics.urdf_parser_py.xml_reflection import core

    previous, core.on_error = core.on_error, lambda message: None  # quiet about <material> tags
    try:
        serial = pk.build_serial_chain_from_urdf(robot_urdf_text(spec), TCP_LINK)
    finally:
        core.on_error = previous
    offsets, axes, prismatic, names = [], [], [], []
    acc = np.eye(4)
    for frame in serial._serial_frames:
        joint = frame.joint
        off = np.eye(4) if joint.offset is None else joint.offset.get_matrix()[0].double().numpy()
        if joint.joint_type == "fixed":
            acc = acc @ off
            continue
        offsets.append(acc @ off)
        acc = np.eye(4)
        axes.append(joint.axis.double().numpy())
        prismatic.append(joint.joint_type == "prismatic")
        names.append(joint.name)
    lower, upper = (np.asarray(x, np.float64) for x in serial.get_joint_limits())
    return Chain(
        offsets=np.stack(offsets),
        axes=np.stack(axes),
        prismatic=np.asarray(prismatic, bool),
        tip=acc,
        lower=lower,
        upper=upper,
        names=tuple(names),
    )
