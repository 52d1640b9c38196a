"""Scripted source demonstrators for the PyBullet tasks: the moves a task file's
``demonstrate`` is written in (``Teleop``, ``pick``, ``place``), and ``demonstrate`` itself.

Waypoints are placed in object frames (grasp at the object's centre, place relative to the
object below, insert over the hole), and a demo moves between them through the same
delta-pose actions a generated episode uses. Like a person teleoperating, each demo varies:
speed per motion, approach and lift heights, a few millimetres of grasp offset, and the
pauses while the gripper opens or closes; all of it drawn from the demo's seed. The grasp
takes the object's yaw (mod 90 degrees, the objects' symmetry) nearest the gripper's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mimicgen_pipe.core import poses

OPEN, CLOSED = 1.0, -1.0
ROT_SPEED = 0.08  # [rad] per step at most


@dataclass(frozen=True)
class Demo:
    """seed: the reset seed (D0). initial_state: the env state before the first action.
    actions: (T, 7). success: the task's success after the last action."""

    seed: int
    initial_state: np.ndarray
    actions: np.ndarray
    success: bool


def _yaw(pose: np.ndarray) -> float:
    return math.atan2(pose[1, 0], pose[0, 0])


def _nearest_symmetric_yaw(yaw: float, reference: float) -> float:
    """yaw + k pi/2 closest to ``reference`` (square objects look the same every 90 deg)."""
    k = round((reference - yaw) / (math.pi / 2))
    return yaw + k * math.pi / 2


def _down(pos: np.ndarray, yaw: float) -> np.ndarray:
    """A TCP pose at ``pos`` pointing down (z to -z world), its x axis at ``yaw``."""
    c, s = math.cos(yaw), math.sin(yaw)
    out = np.eye(4)
    out[:3, :3] = np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])
    out[:3, 3] = pos
    return out


class Teleop:
    """Moves the env's TCP along straight lines at a chosen speed, recording actions."""

    def __init__(self, env, rng: np.random.Generator) -> None:
        self.env, self.rng = env, rng
        self.actions: list[np.ndarray] = []
        self.target = env.eef_pose().copy()
        self.gripper = OPEN

    def _act(self, target: np.ndarray) -> None:
        action = self.env.target_pose_to_action(target, self.gripper).astype(np.float32)
        self.actions.append(action)
        self.env.step(action)

    def move(self, goal: np.ndarray, speed: float, settle: int = 3) -> None:
        """Straight line to ``goal`` at ``speed`` [m/step], then ``settle`` steps on it."""
        dist = np.linalg.norm(goal[:3, 3] - self.target[:3, 3])
        angle = float(poses.rotation_angle(goal[None, :3, :3], self.target[None, :3, :3])[0])
        n = max(1, math.ceil(max(dist / speed, angle / ROT_SPEED)))
        alphas = np.linspace(0.0, 1.0, n + 1)[1:]
        rots = poses.slerp_matrix(self.target[:3, :3], goal[:3, :3], alphas)
        for a, r in zip(alphas, rots, strict=True):
            t = np.eye(4)
            t[:3, :3], t[:3, 3] = r, (1 - a) * self.target[:3, 3] + a * goal[:3, 3]
            self._act(t)
        self.target = goal.copy()
        for _ in range(settle):
            self._act(goal)

    def grip(self, command: float, steps: int) -> None:
        self.gripper = command
        for _ in range(steps):
            self._act(self.target)

    def speed(self, lo: float, hi: float) -> float:
        return float(self.rng.uniform(lo, hi))


def pick(op: Teleop, obj: np.ndarray, grasp_z: float) -> None:
    """Approach above ``obj``, descend, close; ``grasp_z``: TCP height above the object's
    frame origin [m]."""
    rng = op.rng
    yaw = _nearest_symmetric_yaw(_yaw(obj), _yaw(op.target))
    offset = np.append(rng.uniform(-0.004, 0.004, 2), grasp_z + rng.uniform(-0.004, 0.004))
    above = obj[:3, 3] + offset + [0.0, 0.0, rng.uniform(0.06, 0.1)]
    op.move(_down(above, yaw), op.speed(0.012, 0.02))
    op.move(_down(obj[:3, 3] + offset, yaw), op.speed(0.006, 0.01))
    op.grip(CLOSED, int(rng.integers(6, 11)))


def place(
    op: Teleop, held: str, goal: np.ndarray, lift: float, clearance: float, descent: float
) -> None:
    """Carry object ``held`` so that its frame reaches ``goal`` (world pose; its yaw taken mod
    90 degrees): lift the TCP to ``lift`` [m], move over the goal with the object
    ``clearance`` [m] above it, lower at ``descent`` [m/step], open and back off."""
    rng, env = op.rng, op.env
    up = op.target.copy()
    up[2, 3] = lift + rng.uniform(0.0, 0.03)
    op.move(up, op.speed(0.01, 0.02))
    obj_now = env.object_poses()[held]
    in_hand = poses.pose_inv(env.eef_pose()) @ obj_now  # as held once lifted
    yaw = _nearest_symmetric_yaw(_yaw(goal), _yaw(obj_now))
    upright = np.eye(4)
    upright[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    upright[:3, 3] = goal[:3, 3]
    tcp_goal = upright @ poses.pose_inv(in_hand)
    tcp_goal[:3, :3] = _down(np.zeros(3), _yaw(tcp_goal))[:3, :3]  # keep the TCP vertical
    over = tcp_goal.copy()
    over[2, 3] += clearance
    op.move(over, op.speed(0.012, 0.02))
    op.move(tcp_goal, descent, settle=int(rng.integers(2, 5)))
    op.grip(OPEN, int(rng.integers(5, 9)))
    back = op.target.copy()
    back[2, 3] += rng.uniform(0.04, 0.07)
    op.move(back, op.speed(0.01, 0.02))


def demonstrate(env, seed: int, variant: str = "D0") -> Demo:
    """One scripted demo of ``env``'s task (its file's ``demonstrate``) from reset ``seed``."""
    env.reset(seed=seed, variant=variant)
    initial_state = env.get_state()
    rng = np.random.default_rng([seed, 1])  # the demonstrator's own stream, apart from the reset
    op = Teleop(env, rng)
    env.task.demonstrate(op, env)
    return Demo(seed, initial_state, np.asarray(op.actions, np.float32), env.is_success())
