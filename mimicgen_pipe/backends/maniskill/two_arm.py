"""A ManiSkill task with two robots (ManiSkill's multi-agent envs, e.g. TwoRobotStackCube-v1)
as an env of the protocol's several-arm form (mimicgen_pipe.core.contracts.MultiArmEnv): one CPU
env, ManiSkill's own step and evaluation, each arm of the task's spec one of ManiSkill's
agents (``task.arm_agents``), a Panda under pd_ee_delta_pose."""

from __future__ import annotations

import math
import os

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from mimicgen_pipe.backends import load_task  # noqa: E402
from mimicgen_pipe.backends.maniskill.env import ManiSkillEnv, _pose_of, make_gym_env  # noqa: E402
from mimicgen_pipe.core import poses  # noqa: E402
from mimicgen_pipe.core.controller import (  # noqa: E402
    DeltaPoseController,
    actions_to_target_poses,
    target_poses_to_actions,
)
from mimicgen_pipe.core.errors import InputError  # noqa: E402


class ManiSkillArm:
    """One agent of a two-robot ManiSkill env as an arm (mimicgen_pipe.core.contracts.ArmEnv).
    Poses are 4x4 in the world frame [m]; its actions are ManiSkill's normalised
    pd_ee_delta_pose actions in the agent's root frame."""

    def __init__(self, agent) -> None:
        self.agent = agent
        arm = agent.controller.controllers["arm"].config
        self.controller = DeltaPoseController(
            pos_scale=float(arm.pos_upper),
            rot_scale=float(arm.rot_lower),
            rot_repr="euler_xyz",
            root_pose=_pose_of(agent.robot.pose.raw_pose),
        )
        robot = agent.robot
        self._fingers = [i for i, j in enumerate(robot.active_joints) if "finger" in j.name]

    def eef_pose(self) -> np.ndarray:
        return _pose_of(self.agent.tcp.pose.raw_pose)

    def gripper_state(self) -> np.ndarray:
        return self.agent.robot.get_qpos()[0].numpy().astype(np.float64)[self._fingers]

    def target_pose_to_action(self, target: np.ndarray, gripper: float) -> np.ndarray:
        return target_poses_to_actions(self.eef_pose(), target, gripper, self.controller)

    def action_to_target_pose(self, action: np.ndarray) -> np.ndarray:
        return actions_to_target_poses(self.eef_pose(), action, self.controller)

    def reachable(self, targets: np.ndarray) -> np.ndarray:
        """All True, as the one-arm env: ManiSkill's controller solves its own IK."""
        return np.ones(len(targets), bool)


class TwoArmManiSkillEnv:
    """A ManiSkill two-robot task (CPU, state only, pd_ee_delta_pose, ManiSkill's own step):
    the scene's reads here, each arm's through ``arm(name)``; ``step`` takes 7 action entries
    per arm in the spec's arm order."""

    backend = "maniskill"
    control_mode = "pd_ee_delta_pose"

    def __init__(self, task: str, robot: str = "panda", lean_step: bool = True) -> None:
        if robot != "panda":
            raise InputError(f"robot {robot!r}: task {task} has two Pandas")
        self.task = load_task("maniskill", task)
        self.spec = self.task.spec
        self.robot = robot
        self._env = make_gym_env(ManiSkillEnv.env_id_for(self.task), self.task)
        self._u = self._env.unwrapped
        self.control_freq = int(self._u.control_freq)
        self._keys = list(self._env.action_space.keys())  # one per agent, in agent order
        self._info: dict | None = None
        self.rebuild()

    def _bind(self) -> None:
        agents = self._u.agent.agents
        self._agent_keys = [self._keys[self.task.arm_agents[a]] for a in self.spec.arms]
        self._arms = {a: ManiSkillArm(agents[self.task.arm_agents[a]]) for a in self.spec.arms}

    def arm(self, name: str) -> ManiSkillArm:
        return self._arms[name]

    def reset(self, seed: int, variant: str) -> None:
        self._info = self._u.reset(seed=int(seed), options={"variant": variant})[1]

    def rebuild(self) -> None:
        self._u.reset(seed=self.task.rebuild_seed, options={"variant": "D0", "reconfigure": True})
        self._bind()
        self._info = None

    def eef_pose(self) -> np.ndarray:
        raise AttributeError(f"task {self.spec.name} has two arms: arm(name).eef_pose()")

    def gripper_state(self) -> np.ndarray:
        raise AttributeError(f"task {self.spec.name} has two arms: arm(name).gripper_state()")

    def object_poses(self) -> dict[str, np.ndarray]:
        u = self._u
        return {o: _pose_of(getattr(u, a).pose.raw_pose) for o, a in self.task.objects.items()}

    def step(self, action: np.ndarray) -> None:
        a = torch.as_tensor(np.asarray(action, np.float32))[None]
        parts = {key: a[:, 7 * n : 7 * n + 7] for n, key in enumerate(self._agent_keys)}
        self._info = self._u.step(parts)[4]

    def _evaluation(self) -> dict:
        if self._info is None:
            self._info = self._u.evaluate()
        return self._info

    def subtask_signals(self) -> dict[str, bool]:
        signals = self.task.signals(self._u, self._evaluation())
        return {name: bool(v) for name, v in signals.items()}

    def is_success(self) -> bool:
        return bool(self._evaluation()["success"])

    def get_state(self) -> np.ndarray:
        return self._u.get_state()[0].numpy().astype(np.float32)

    def state_layout(self) -> None:
        """None: the recorder reads both arms' fingers and the poses at every step."""
        return None

    def set_state(self, state: np.ndarray) -> None:
        self._u.set_state(torch.as_tensor(np.asarray(state, np.float32))[None])
        self._info = None

    def target_pose_to_action(self, target: np.ndarray, gripper: float) -> np.ndarray:
        raise AttributeError(f"task {self.spec.name} has two arms: arm(name)")

    def action_to_target_pose(self, action: np.ndarray) -> np.ndarray:
        raise AttributeError(f"task {self.spec.name} has two arms: arm(name)")

    def reachable(self, targets: np.ndarray) -> np.ndarray:
        raise AttributeError(f"task {self.spec.name} has two arms: arm(name)")

    def demonstrate(self, seed: int) -> np.ndarray | None:
        """The task's scripted demonstrator (``task.demonstrator``) from the scene reset
        with ``seed`` on D0, where the env is: its actions (T, 14), or None when its demo
        fails."""
        return self.task.demonstrator(self, seed)

    def close(self) -> None:
        self._env.close()


# -- for the task files' scripted two-arm demonstrators ----------------------------------------
STEP, TURN = 0.012, 0.08  # [m], [rad]: a scripted arm's largest move per control step


def yaw_of(rotation: np.ndarray) -> float:
    """The angle [rad] about world z of a rotation's x axis."""
    return math.atan2(rotation[1, 0], rotation[0, 0])


def rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose_at(rotation: np.ndarray, xyz) -> np.ndarray:
    """A 4x4 pose from a 3x3 rotation and a position [m]."""
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = rotation, xyz
    return t


def grasp_rotation(tcp: np.ndarray, obj: np.ndarray, period: float, offset: float = 0.0):
    """The TCP's rotation (4x4 ``tcp``, world) turned about world z the least way that puts its
    x axis at ``offset`` [rad] from the object's (4x4 ``obj``), an object that looks the same
    every ``period`` [rad] (a cube pi/2, a bar pi)."""
    d = yaw_of(obj[:3, :3]) + offset - yaw_of(tcp[:3, :3])
    return rot_z((d + period / 2) % period - period / 2) @ tcp[:3, :3]


def step_toward(eef: np.ndarray, goal: np.ndarray, step: float = STEP) -> tuple[np.ndarray, bool]:
    """A target at most ``step`` [m] and TURN from ``eef`` on the way to ``goal`` (4x4,
    world), and whether it is ``goal``."""
    d = goal[:3, 3] - eef[:3, 3]
    n = float(np.linalg.norm(d))
    rel = poses.matrix_to_axis_angle(goal[:3, :3] @ eef[:3, :3].T)
    angle = float(np.linalg.norm(rel))
    f = min(1.0, step / n if n > 0 else 1.0, TURN / angle if angle > 0 else 1.0)
    out = pose_at(poses.axis_angle_to_matrix(f * rel) @ eef[:3, :3], eef[:3, 3] + f * d)
    return out, f == 1.0
