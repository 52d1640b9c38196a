"""The xArm6 on the ManiSkill back end: pybullet_data's xArm6 arm carrying the Franka hand.

The robot is a ManiSkill agent (uid ``xarm6_pandahand``) that subclasses ManiSkill's Panda
agent, so it keeps the Panda's controller configs (pd_ee_delta_pose and the others), its
finger friction materials and its ``is_grasping``; only the kinematic chain differs. The
URDF is composed at import time from pybullet_data (the xArm6 arm, the Franka hand and
fingers mounted on link6) and written to a content-addressed file under the system temp
dir. The TCP link ``panda_hand_tcp`` lies 0.1034 m ahead of the hand, as on ManiSkill's Panda,
so a TCP pose recorded with the Panda means the same grasp on the xArm6.

StackCube with this arm: ``MimicGenStackCubeXArm6-v1`` (stack_cube's env with its reset
variants) with the robot base at x = -0.4: from the Panda's -0.615 the xArm6 with the
0.16 m hand cannot reach StackCube's far cube positions.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import numpy as np  # noqa: E402
import sapien  # noqa: E402
from mani_skill.agents.base_agent import Keyframe  # noqa: E402
from mani_skill.agents.registration import register_agent  # noqa: E402
from mani_skill.agents.robots.panda.panda import Panda  # noqa: E402
from mani_skill.envs.tasks import StackCubeEnv  # noqa: E402
from mani_skill.utils import sapien_utils  # noqa: E402
from mani_skill.utils.registration import register_env  # noqa: E402

from mimicgen_pipe.backends import load_task  # noqa: E402
from mimicgen_pipe.backends.maniskill.env import ManiSkillEnv, variant_env_class  # noqa: E402
from mimicgen_pipe.backends.maniskill.tasks import ManiSkillTask  # noqa: E402
from mimicgen_pipe.core.errors import InputError  # noqa: E402
from mimicgen_pipe.core.urdf import (  # noqa: E402
    FINGER_JOINTS,
    FINGER_OPEN,
    add_fixed_joint,
    franka_hand,
    load_urdf,
    urdf_file,
)

ROBOT = "xarm6"
AGENT_UID = "xarm6_pandahand"
ENV_IDS = {"stack_cube": "MimicGenStackCubeXArm6-v1"}
ARM_URDF = "xarm/xarm6_robot.urdf"
FLANGE = "link6"  # link6's frame is the xArm6 flange face
TCP_LINK = "panda_hand_tcp"
TCP_OFFSET = 0.1034  # [m] ahead of panda_hand along its z axis, as ManiSkill's Panda
BASE_XYZ = (-0.4, 0.0, 0.0)  # [m] world position of the robot base
# arm joints [rad] then fingers [m]: the TCP pointing down at world (0, 0, 0.18), fingers open
REST_QPOS = np.array([0.0, -0.11784, -0.7075, 0.0, 0.82534, 0.0, 0.04, 0.04])
# pybullet_data's hand/finger inertias (0.1 kg m^2) are unphysical for PhysX; values like
# ManiSkill's panda_v2: (com xyz, mass [kg], principal inertia diag [kg m^2])
HAND_INERTIA = {
    "panda_hand": ("-0.01 0 0.03", 0.73, (0.001, 0.0025, 0.0017)),
    "panda_leftfinger": ("0 0 0.02", 0.015, (2.375e-6, 2.375e-6, 7.5e-7)),
    "panda_rightfinger": ("0 0 0.02", 0.015, (2.375e-6, 2.375e-6, 7.5e-7)),
}


def _set_inertial(link: ET.Element, xyz: str, mass: float, diag: tuple[float, ...]) -> None:
    for el in link.findall("inertial"):
        link.remove(el)
    inertial = ET.SubElement(link, "inertial")
    ET.SubElement(inertial, "origin", rpy="0 0 0", xyz=xyz)
    ET.SubElement(inertial, "mass", value=str(mass))
    ixx, iyy, izz = (str(v) for v in diag)
    ET.SubElement(inertial, "inertia", ixx=ixx, ixy="0", ixz="0", iyy=iyy, iyz="0", izz=izz)


def urdf_text() -> str:
    """The xArm6 + Franka hand URDF for SAPIEN, mesh paths absolute."""
    arm = load_urdf(ARM_URDF)
    for el in list(arm):
        if (el.tag, el.get("name")) in (("link", "world"), ("joint", "world_joint")):
            arm.remove(el)  # the dummy world link: ManiSkill places the root itself
    for el in franka_hand():
        if el.tag == "link":
            for contact in el.findall("contact"):
                el.remove(contact)  # pybullet-only
            for geom in el.findall("visual") + el.findall("collision"):
                for material in geom.findall("material"):
                    geom.remove(material)
            _set_inertial(el, *HAND_INERTIA[el.get("name")])
        else:
            el.find("limit").set("effort", "100")
        arm.append(el)
    add_fixed_joint(arm, "xarm_hand_mount", FLANGE, "panda_hand")
    ET.SubElement(arm, "link", name=TCP_LINK)
    add_fixed_joint(arm, "panda_hand_tcp_joint", "panda_hand", TCP_LINK, f"0 0 {TCP_OFFSET}")
    arm.set("name", AGENT_UID)
    return ET.tostring(arm, encoding="unicode")


@register_agent()
class XArm6PandaHand(Panda):
    """ManiSkill's Panda agent (controllers, grasp check, gripper materials) on the xArm6."""

    uid = AGENT_UID
    urdf_path = str(urdf_file(urdf_text(), AGENT_UID))
    keyframes = dict(rest=Keyframe(qpos=REST_QPOS, pose=sapien.Pose()))
    arm_joint_names = [f"joint{i}" for i in range(1, 7)]
    gripper_joint_names = list(FINGER_JOINTS)
    ee_link_name = TCP_LINK

    def _after_init(self):
        links = self.robot.get_links()
        self.finger1_link = sapien_utils.get_obj_by_name(links, "panda_leftfinger")
        self.finger2_link = sapien_utils.get_obj_by_name(links, "panda_rightfinger")
        self.tcp = sapien_utils.get_obj_by_name(links, self.ee_link_name)


@register_env(ENV_IDS["stack_cube"], max_episode_steps=200)
class MimicGenStackCubeXArm6Env(variant_env_class(load_task("maniskill", "stack_cube"))):
    """stack_cube's env (same D0/D1 cube resets) with the xArm6 based at BASE_XYZ."""

    SUPPORTED_ROBOTS = [AGENT_UID]

    def __init__(self, *args, robot_uids=AGENT_UID, **kwargs):
        super().__init__(*args, robot_uids=robot_uids, **kwargs)

    def _load_agent(self, options: dict):
        # skip StackCubeEnv's _load_agent, which places the base at the Panda's -0.615
        super(StackCubeEnv, self)._load_agent(options, sapien.Pose(p=list(BASE_XYZ)))

    def _initialize_episode(self, env_idx, options: dict):
        super()._initialize_episode(env_idx, options)  # table + cubes; no robot branch for us
        qpos = self.agent.keyframes["rest"].qpos
        # the table scene's noise for the Panda, from the episode's seeded RNG
        if self._enhanced_determinism:
            noise = self._batched_episode_rng[env_idx].normal(
                0, self.robot_init_qpos_noise, len(qpos)
            )
        else:
            noise = self._episode_rng.normal(
                0, self.robot_init_qpos_noise, (len(env_idx), len(qpos))
            )
        qpos = qpos + noise
        qpos[:, -2:] = FINGER_OPEN
        self.agent.reset(qpos)
        self.agent.robot.set_pose(sapien.Pose(p=list(BASE_XYZ)))


class XArm6ManiSkillEnv(ManiSkillEnv):
    """ManiSkillEnv on the xArm6 (see the module docstring); the protocol is the parent's."""

    agent_uids = {ROBOT: AGENT_UID}

    @staticmethod
    def env_id_for(task: ManiSkillTask) -> str:
        if task.spec.name not in ENV_IDS:
            raise InputError(
                f"task {task.spec.name!r}: the xarm6 on maniskill has {', '.join(ENV_IDS)} only"
            )
        return ENV_IDS[task.spec.name]
