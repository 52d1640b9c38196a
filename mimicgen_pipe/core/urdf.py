"""URDF composition shared by the back ends: arms from pybullet_data, the Franka hand
mounted on a flange, mesh paths made absolute, written where a simulator can load them."""

from __future__ import annotations

import copy
import hashlib
import os
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

from mimicgen_pipe.core.errors import InputError

PANDA_URDF = "franka_panda/panda.urdf"
HAND_LINKS = ("panda_hand", "panda_leftfinger", "panda_rightfinger")
FINGER_JOINTS = ("panda_finger_joint1", "panda_finger_joint2")
FINGER_OPEN = 0.04  # [m] per finger: the Franka hand opens 8 cm


def resolve(urdf: str) -> Path:
    """``urdf`` relative to pybullet_data (or absolute); InputError naming it if missing."""
    import pybullet_data

    path = Path(urdf)
    if not path.is_absolute():
        path = Path(pybullet_data.getDataPath()) / path
    if not path.is_file():
        raise InputError(f"robot URDF {path}: no such file")
    return path


def load_urdf(urdf: str) -> ET.Element:
    """The URDF's root element, its ROS control blocks dropped (no parser here reads them,
    and pytorch-kinematics cannot parse xArm's) and its mesh paths absolute."""
    path = resolve(urdf)
    root = ET.parse(path).getroot()
    for el in [el for el in root if el.tag in ("transmission", "gazebo")]:
        root.remove(el)
    for mesh in root.iter("mesh"):
        name = mesh.get("filename", "").removeprefix("package://")
        if not os.path.isabs(name):
            mesh.set("filename", str(path.parent / name))
    return root


def franka_hand(extra_links: tuple[str, ...] = (), extra_joints: tuple[str, ...] = ()) -> list:
    """Copies of the Franka hand's links and finger joints from pybullet_data's Panda, plus
    the named extra links and joints."""
    links, joints = HAND_LINKS + extra_links, FINGER_JOINTS + extra_joints
    return [
        copy.deepcopy(el)
        for el in load_urdf(PANDA_URDF)
        if (el.tag == "link" and el.get("name") in links)
        or (el.tag == "joint" and el.get("name") in joints)
    ]


def add_fixed_joint(
    robot: ET.Element, name: str, parent: str, child: str, xyz: str = "0 0 0", rpy: str = "0 0 0"
) -> None:
    if not any(link.get("name") == parent for link in robot.iter("link")):
        raise InputError(f"robot URDF {robot.get('name')}: no link {parent!r} to mount on")
    joint = ET.SubElement(robot, "joint", name=name, type="fixed")
    ET.SubElement(joint, "parent", link=parent)
    ET.SubElement(joint, "child", link=child)
    ET.SubElement(joint, "origin", xyz=xyz, rpy=rpy)


def urdf_file(text: str, name: str) -> Path:
    """``text`` written once to a content-addressed file under the system temp dir."""
    digest = hashlib.sha1(text.encode()).hexdigest()[:12]
    path = Path(tempfile.gettempdir()) / "mimicgen-pipe-robots" / f"{name}-{digest}.urdf"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_text(text)
        tmp.replace(path)
    return path
