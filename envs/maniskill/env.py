"""The ManiSkill adapter: one CPU env implementing the generator's env protocol."""

from __future__ import annotations

import dataclasses
import os

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from mani_skill.envs.tasks import StackCubeEnv  # noqa: E402
from mani_skill.utils.registration import register_env  # noqa: E402
from mani_skill.utils.structs.pose import Pose  # noqa: E402

from envs.maniskill.tasks import (  # noqa: E402
    D1_MAX_REACH,
    D1_MIN_DIST,
    D1_X,
    D1_Y,
    ROBOT_BASE_XY,
    ROBOTS,
    TASKS,
)
from mimicgen_pipe import poses  # noqa: E402
from mimicgen_pipe.controller import (  # noqa: E402
    DeltaPoseController,
    actions_to_target_poses,
    target_poses_to_actions,
)
from mimicgen_pipe.errors import InputError  # noqa: E402


def _yaw_quats(n: int) -> torch.Tensor:
    yaw = torch.rand(n) * 2 * torch.pi
    q = torch.zeros(n, 4)
    q[:, 0], q[:, 3] = torch.cos(yaw / 2), torch.sin(yaw / 2)
    return q


@register_env(TASKS["stack_cube"].env_id, max_episode_steps=200)
class MimicGenStackCubeEnv(StackCubeEnv):
    """StackCube with reset variants: ``reset(options={"variant": "D1"})``; D0 is the
    parent's own reset distribution (see envs/maniskill/tasks.py for the bounds)."""

    variant = "D0"

    def reset(self, seed=None, options=None):
        options = dict(options or {})
        self.variant = options.pop("variant", self.variant)
        return super().reset(seed=seed, options=options)

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        if self.variant == "D0":
            return super()._initialize_episode(env_idx, options)
        if self.variant != "D1":
            raise ValueError(f"unknown variant {self.variant}")
        with torch.device(self.device):
            b = len(env_idx)
            self.table_scene.initialize(env_idx)
            lo = torch.tensor([D1_X[0], D1_Y[0]])
            span = torch.tensor([D1_X[1] - D1_X[0], D1_Y[1] - D1_Y[0]])
            base = torch.tensor(ROBOT_BASE_XY)

            def sample(reject) -> torch.Tensor:
                xy = lo + torch.rand(b, 2) * span
                for _ in range(1000):  # rejection sampling; the accepted area is most of the box
                    bad = reject(xy)
                    if not bad.any():
                        return xy
                    xy[bad] = lo + torch.rand(int(bad.sum()), 2) * span
                raise RuntimeError("D1 reset: rejection sampling did not converge")

            def too_far(xy: torch.Tensor) -> torch.Tensor:
                return torch.linalg.norm(xy - base, dim=1) > D1_MAX_REACH

            a_xy = sample(too_far)
            b_xy = sample(
                lambda xy: too_far(xy) | (torch.linalg.norm(xy - a_xy, dim=1) < D1_MIN_DIST)
            )
            for actor, xy in ((self.cubeA, a_xy), (self.cubeB, b_xy)):
                xyz = torch.zeros(b, 3)
                xyz[:, :2], xyz[:, 2] = xy, 0.02
                actor.set_pose(Pose.create_from_pq(p=xyz, q=_yaw_quats(b)))


def _pose_of(raw_pose: torch.Tensor) -> np.ndarray:
    pq = raw_pose[0].numpy().astype(np.float64)
    return poses.pose_from_pq(pq[:3], pq[3:])


def _matrix(pose) -> np.ndarray:
    """A sapien.Pose as a 4x4 matrix."""
    return poses.pose_from_pq(np.asarray(pose.p, np.float64), np.asarray(pose.q, np.float64))


_ZERO3 = np.zeros(3, np.float32)


class ManiSkillEnv:
    """One CPU ManiSkill env (physx_cpu, no rendering, state only, pd_ee_delta_pose).

    Poses are 4x4 in the world frame. Actions are ManiSkill's normalised pd_ee_delta_pose
    actions: translation 0.1 m per unit in the robot root frame, rotation as Euler "XYZ"
    angles of -0.1 rad per unit (ManiSkill inverts the sign), gripper +1 open / -1 closed.
    """

    backend = "maniskill"
    control_mode = "pd_ee_delta_pose"
    control_freq = 20
    # robot name -> ManiSkill agent uid, and task -> registered env id; another arm's env
    # (envs/maniskill/xarm6.py) swaps in its own
    agent_uids = {r: r for r in ROBOTS}
    env_ids = {name: t.env_id for name, t in TASKS.items()}

    def __init__(self, task: str = "stack_cube", robot: str = "panda") -> None:
        if robot not in self.agent_uids:
            known = ", ".join(self.agent_uids)
            raise InputError(f"robot {robot!r}: unknown for maniskill (known: {known})")
        if task not in self.env_ids:
            raise InputError(f"task {task!r}: unknown for maniskill with robot {robot!r}")
        self.task = dataclasses.replace(TASKS[task], env_id=self.env_ids[task])
        self.spec = self.task.spec
        self.robot = robot
        self._env = gym.make(
            self.task.env_id,
            obs_mode="none",
            reward_mode="none",
            control_mode=self.control_mode,
            sim_backend="physx_cpu",
            render_backend="none",
            robot_uids=self.agent_uids[robot],
        )
        self.unwrapped = self._env.unwrapped
        self._u = self.unwrapped
        arm = self._u.agent.controller.controllers["arm"].config
        self.control_freq = int(self._u.control_freq)
        self.controller = DeltaPoseController(
            pos_scale=float(arm.pos_upper),
            rot_scale=float(arm.rot_lower),
            rot_repr="euler_xyz",
            root_pose=_pose_of(self._u.agent.robot.pose.raw_pose),
        )
        self._info: dict = {}
        self._eef: np.ndarray | None = None  # cached until the next step/reset/set_state
        self._objects: dict[str, np.ndarray] | None = None
        self._bind()
        self.reset(seed=0, variant="D0")

    # -- protocol -------------------------------------------------------------------------
    def reset(self, seed: int, variant: str) -> None:
        self._u.reset(seed=int(seed), options={"variant": variant})
        self._changed(self._u.evaluate())

    def rebuild(self) -> None:
        # PhysX keeps contact caches across plain resets; a reconfigure builds a new scene.
        self._u.reset(seed=0, options={"variant": "D0", "reconfigure": True})
        self._bind()
        self._changed(self._u.evaluate())

    def _changed(self, info: dict) -> None:
        self._info, self._eef, self._objects = info, None, None

    def _bind(self) -> None:
        """Hold the simulator objects read on every step (a reconfigure replaces them).
        ManiSkill's get_state() goes through batched torch structures (~0.1 ms per call); the
        same values read straight from SAPIEN, in get_state_dict()'s order, cost a tenth."""
        u = self._u
        self._tcp = u.agent.tcp._objs[0]
        self._actors = {n: getattr(u, a)._objs[0] for n, a in self.task.objects.items()}
        self._state_actors = []
        for name in u.get_state_dict()["actors"]:
            actor = u.scene.actors[name]
            body = actor._bodies[0] if actor.px_body_type == "dynamic" else None
            self._state_actors.append((actor._objs[0], body))
        self._state_arts = [
            u.scene.articulations[n]._objs[0] for n in u.get_state_dict()["articulations"]
        ]
        robot = u.agent.robot
        self._robot = robot._objs[0]
        self._finger_index = [
            robot.active_joints.index(j) for j in robot.active_joints if "finger" in j.name
        ]

    def step(self, action: np.ndarray) -> None:
        self._info = self._u.step(np.asarray(action, dtype=np.float32))[4]
        self._eef = self._objects = None

    def eef_pose(self) -> np.ndarray:
        if self._eef is None:
            self._eef = _matrix(self._tcp.entity_pose)
        return self._eef

    def object_poses(self) -> dict[str, np.ndarray]:
        if self._objects is None:
            self._objects = {name: _matrix(a.pose) for name, a in self._actors.items()}
        return self._objects

    def gripper_state(self) -> np.ndarray:
        return np.asarray(self._robot.qpos, np.float64)[self._finger_index]

    def subtask_signals(self) -> dict[str, bool]:
        return {name: bool(self._info[key]) for name, key in self.task.signals.items()}

    def is_success(self) -> bool:
        return bool(self._info["success"])

    def get_state(self) -> np.ndarray:
        parts = []
        for entity, body in self._state_actors:
            pose = entity.pose
            vel = (body.linear_velocity, body.angular_velocity) if body else (_ZERO3, _ZERO3)
            parts += [pose.p, pose.q, *vel]
        for art in self._state_arts:
            root = art.root_pose
            parts += [
                root.p,
                root.q,
                art.root_linear_velocity,
                art.root_angular_velocity,
                art.qpos,
                art.qvel,
            ]
        return np.concatenate(parts).astype(np.float32)

    def set_state(self, state: np.ndarray) -> None:
        self._u.set_state(torch.as_tensor(np.asarray(state, dtype=np.float32))[None])
        self._changed(self._u.evaluate())

    def set_state_dict(self, state: dict) -> None:
        """Restore a ManiSkill state dict ({"actors": {...}, "articulations": {...}})."""
        self._u.set_state_dict(state)
        self._changed(self._u.evaluate())

    def target_pose_to_action(self, target: np.ndarray, gripper: float) -> np.ndarray:
        return target_poses_to_actions(self.eef_pose(), target, gripper, self.controller)

    def action_to_target_pose(self, action: np.ndarray) -> np.ndarray:
        return actions_to_target_poses(self.eef_pose(), action, self.controller)

    def reachable(self, targets: np.ndarray) -> np.ndarray:
        """All True: ManiSkill's controller solves its own IK each step, and a target it
        cannot reach leaves the arm where it is, which shows up as a task failure."""
        return np.ones(len(targets), bool)

    def close(self) -> None:
        self._env.close()
