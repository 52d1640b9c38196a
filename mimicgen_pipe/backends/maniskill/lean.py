"""The lean control step (``maniskill.lean_step``): what ManiSkill's ``env.step`` does to the
simulation under ``pd_ee_delta_pose`` on the CPU, without its per-step bookkeeping.

ManiSkill runs every control step through batched torch code made for thousands of GPU
scenes: on one CPU scene its 1-element pose algebra, ``evaluate()``, reward and observations
cost ~25x the physics. ``LeanStep.step`` does only what moves the simulation: the arm
controller's target pose and IK, the gripper's drive targets, then the PhysX substeps. The
pose algebra repeats ManiSkill's own float32 arithmetic operation for operation (its
``Pose``, ``quaternion_multiply``, ``euler_angles_to_matrix``, ``matrix_to_quaternion``), and
the IK is ManiSkill's call of the same pinocchio solver, so the drive targets, and with them
the simulation, are the same bits as the stock step's (tests/test_lean_step.py).

The reads below (``is_grasping``, ``is_static``) are ManiSkill's checks on poses and contacts
read straight from SAPIEN, for the task files' ``evaluate`` (signals and success), computed
only when the generator asks for them.
"""

from __future__ import annotations

import math

import numpy as np
import sapien
import torch

F32 = np.float32
_ONE, _ZERO, _TWO, _FLOOR = F32(1.0), F32(0.0), F32(2.0), F32(0.1)


# -- ManiSkill's rotation_conversions in numpy float32, operation for operation -------------
def quat_raw_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of two (4,) float32 quaternions (w, x, y, z)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        F32,
    )


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a * b with a non-negative real part."""
    q = quat_raw_multiply(a, b)
    return -q if q[0] < 0 else q


def quat_invert(q: np.ndarray) -> np.ndarray:
    return np.array((q[0], -q[1], -q[2], -q[3]), F32)


def quat_apply(q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Point p (3,) rotated by quaternion q."""
    out = quat_raw_multiply(quat_raw_multiply(q, np.array((_ZERO, *p), F32)), quat_invert(q))
    return out[1:]


def pose_multiply(a: tuple, b: tuple) -> tuple[np.ndarray, np.ndarray]:
    """(p, q) of pose a * pose b."""
    return a[0] + quat_apply(a[1], b[0]), quat_multiply(a[1], b[1])


def pose_inverse(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    inv_q = quat_invert(q)
    return quat_apply(inv_q, -p), inv_q


def _matmul3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    # torch's 3x3 float32 product: each entry summed in order k = 0, 1, 2, no fused multiply-add
    return a[:, 0:1] * b[0] + a[:, 1:2] * b[1] + a[:, 2:3] * b[2]


def euler_xyz_quat(angles: np.ndarray) -> np.ndarray:
    """Quaternion of intrinsic "XYZ" Euler angles (3,) [rad], as ManiSkill's
    matrix_to_quaternion(euler_angles_to_matrix(angles, "XYZ"))."""
    t = torch.from_numpy(angles)
    # torch's float32 sin/cos (SLEEF) differ from numpy's in the last bit now and then
    s, c = torch.sin(t).numpy(), torch.cos(t).numpy()
    rx = np.array(((_ONE, _ZERO, _ZERO), (_ZERO, c[0], -s[0]), (_ZERO, s[0], c[0])), F32)
    ry = np.array(((c[1], _ZERO, s[1]), (_ZERO, _ONE, _ZERO), (-s[1], _ZERO, c[1])), F32)
    rz = np.array(((c[2], -s[2], _ZERO), (s[2], c[2], _ZERO), (_ZERO, _ZERO, _ONE)), F32)
    return matrix_to_quat(_matmul3(_matmul3(rx, ry), rz))


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Quaternion of a 3x3 float32 rotation matrix, as ManiSkill's matrix_to_quaternion."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = m
    q_abs = np.array(
        (
            _ONE + m00 + m11 + m22,
            _ONE + m00 - m11 - m22,
            _ONE - m00 + m11 - m22,
            _ONE - m00 - m11 + m22,
        ),
        F32,
    )
    positive = q_abs > 0
    # torch's float32 sqrt is not always the correctly rounded one numpy's is: take torch's,
    # on the same masked 1-D tensor ManiSkill takes it on
    q_abs[~positive] = _ZERO
    q_abs[positive] = torch.sqrt(torch.from_numpy(q_abs[positive])).numpy()
    k = int(np.argmax(q_abs))  # the best-conditioned of ManiSkill's four candidates
    if k == 0:
        row = (q_abs[0] * q_abs[0], m21 - m12, m02 - m20, m10 - m01)
    elif k == 1:
        row = (m21 - m12, q_abs[1] * q_abs[1], m10 + m01, m02 + m20)
    elif k == 2:
        row = (m02 - m20, m10 + m01, q_abs[2] * q_abs[2], m12 + m21)
    else:
        row = (m10 - m01, m20 + m02, m21 + m12, q_abs[3] * q_abs[3])
    q = np.array(row, F32) / (_TWO * max(q_abs[k], _FLOOR))
    return -q if q[0] < 0 else q


def _scaling(low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(mid, half) of ManiSkill's clip_and_scale_action: mid + half * clip(a, -1, 1)."""
    return F32(0.5) * (high + low), F32(0.5) * (high - low)


def _clip_and_scale(a: np.ndarray, mid: np.ndarray, half: np.ndarray) -> np.ndarray:
    return mid + half * np.minimum(np.maximum(a, F32(-1)), F32(1))


class LeanStep:
    """One control step of a ManiSkill CPU env under pd_ee_delta_pose, arm controller
    ``PDEEPoseController`` (translation in the root frame, rotation root-aligned about the
    end effector, no virtual target, no interpolation) and a ``PDJointPos(Mimic)Controller``
    gripper. Holds the env's own controller objects; ``bind()`` again after the scene is
    rebuilt."""

    def __init__(self, env) -> None:
        self.env = env
        self.bind()

    def bind(self) -> None:
        env = self.env
        arm = env.agent.controller.controllers["arm"]
        grip = env.agent.controller.controllers["gripper"]
        cfg = arm.config
        if type(arm).__name__ != "PDEEPoseController" or (
            cfg.use_target
            or cfg.interpolate
            or not cfg.use_delta
            or not cfg.normalize_action
            or cfg.frame != "root_translation:root_aligned_body_rotation"
        ):
            raise ValueError(f"lean_step: no lean step for the arm controller {arm!r}")
        if grip.config.use_delta or grip.config.interpolate or not grip.config.normalize_action:
            raise ValueError(f"lean_step: no lean step for the gripper controller {grip!r}")
        kin = arm.kinematics
        self._robot = env.agent.robot._objs[0]
        self._ee = arm.ee_link._objs[0]
        self._root = arm.root_link._objs[0]
        self._pmodel, self._end_link = kin.pmodel, kin.end_link_idx
        self._ik_q = kin.pmodel_active_joint_indices.numpy()
        self._ik_out = kin.pmodel_controlled_joint_indices.numpy()
        self._qmask = kin.qmask
        self._arm_q = np.asarray(arm.active_joint_indices)
        self._arm_joints = [j._objs[0] for j in arm.joints]
        low, high = arm.action_space_low.numpy(), arm.action_space_high.numpy()
        self._arm_scaling = _scaling(low[:3], high[:3])
        self._rot_scale = F32(cfg.rot_lower)
        self._grip_scaling = _scaling(grip.action_space_low.numpy(), grip.action_space_high.numpy())
        self._to_base: tuple = (None, None)  # (root pose bytes, its inverse)
        self._grip_joints = [j._objs[0] for j in grip.joints]
        # joint -> the entry of the gripper action it takes (a mimic joint: its control joint's
        # times multiplier plus offset; ManiSkill's PDJointPosMimicController)
        n = len(grip.joints)
        self._grip_source = np.arange(n)
        self._grip_mul = np.ones(n, F32)
        self._grip_off = np.zeros(n, F32)
        if hasattr(grip, "mimic_joint_indices"):
            control = grip.control_joint_indices.numpy().tolist()
            self._grip_source = np.array(
                [control.index(i) if i in control else -1 for i in range(n)]
            )
            for m, c, mul, off in zip(
                grip.mimic_joint_indices.numpy().ravel(),
                grip.mimic_control_joint_indices.numpy().ravel(),
                grip._multiplier.numpy(),
                grip._offset.numpy(),
                strict=True,
            ):
                self._grip_source[m] = control.index(int(c))
                self._grip_mul[m], self._grip_off[m] = mul, off
        self._sim_steps = int(env._sim_steps_per_control)
        self._px = env.scene.px

    def arm_targets(self, arm_action: np.ndarray) -> np.ndarray:
        """The arm's joint drive targets [rad] (float32) for a normalised delta-pose action (6,):
        the target pose = the delta applied to the current end-effector pose in the robot
        root frame, solved by IK from the current joints; the current joints if IK fails."""
        delta = _clip_and_scale(arm_action[:3], *self._arm_scaling)
        rot = arm_action[3:6]
        if float(np.dot(rot, rot)) > 0.999:  # maybe past the unit norm: clip it as torch does
            t = torch.from_numpy(rot[None])
            norm = torch.linalg.norm(t, axis=1)
            if norm > 1:
                rot = torch.mul(t, 1 / norm[:, None]).numpy()[0]
        rot = rot * self._rot_scale
        ee, root = self._ee.entity_pose, self._root.entity_pose
        key = root.p.tobytes() + root.q.tobytes()
        if key != self._to_base[0]:  # a fixed base: inverted once
            self._to_base = (key, pose_inverse(root.p, root.q))
        ee_p, ee_q = pose_multiply(self._to_base[1], (ee.p, ee.q))
        target_q = quat_multiply(euler_xyz_quat(rot), ee_q)
        target_p = ee_p + delta
        qpos = self._robot.qpos
        result, ok, _ = self._pmodel.compute_inverse_kinematics(
            self._end_link,
            sapien.Pose(target_p, target_q),
            initial_qpos=qpos[self._ik_q],
            active_qmask=self._qmask,
            max_iterations=100,
        )
        if ok:
            return result[self._ik_out].astype(F32)
        return qpos[self._arm_q]

    def step(self, action: np.ndarray) -> None:
        """One control step: set the arm's and gripper's drive targets for ``action`` (7,),
        then run the simulation substeps."""
        action = np.asarray(action, F32)
        if np.isnan(action).any():
            raise ValueError("Action cannot be NaN. Environment received:", action)
        env = self.env
        for joint, target in zip(self._arm_joints, self.arm_targets(action[:6]), strict=True):
            joint.set_drive_target(float(target))
        grip = _clip_and_scale(action[6:], *self._grip_scaling)
        for joint, i, mul, off in zip(
            self._grip_joints, self._grip_source, self._grip_mul, self._grip_off, strict=True
        ):
            joint.set_drive_target(float(grip[i] * mul + off))
        env._before_control_step()
        for _ in range(self._sim_steps):
            env._before_simulation_step()
            self._px.step()
            env._after_simulation_step()
        env._after_control_step()
        env._elapsed_steps += 1


# -- ManiSkill's checks on poses and contacts, read straight from SAPIEN --------------------
def is_grasping(env, actor, min_force: float = 0.5, max_angle: float = 85) -> bool:
    """ManiSkill's Panda ``agent.is_grasping(actor)``: both fingers push on ``actor`` with at
    least ``min_force`` [N], each within ``max_angle`` [deg] of its opening direction."""
    agent = env.agent
    fingers = (agent.finger1_link._objs[0], agent.finger2_link._objs[0])
    target = actor._bodies[0]
    impulse = [np.zeros(3), np.zeros(3)]
    for contact in env.scene.px.get_contacts():
        # SAPIEN hands back the same Python object for a body, so `is` compares bodies
        b0, b1 = contact.bodies
        if b1 is target:
            other, sign = b0, 1  # the impulse acts on bodies[0]
        elif b0 is target:
            other, sign = b1, -1
        else:
            continue
        for i, finger in enumerate(fingers):
            if other is finger and (points := contact.points):
                # the points' float32 impulses summed in order, as numpy sums them along an
                # axis of arrays stacked, without the stacking
                total = points[0].impulse
                for point in points[1:]:
                    total = total + point.impulse
                impulse[i] += sign * total
    dt = F32(env.scene.px.timestep)
    for finger, side, total in zip(fingers, (1, -1), impulse, strict=True):
        force = total.astype(F32) / dt
        norm = math.sqrt(float(force @ force))
        if norm < min_force:
            return False
        # the finger's opening direction: its y axis (the right finger's, reversed)
        w, x, y, z = (float(v) for v in finger.entity_pose.q)
        axis = side * np.array((2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)))
        cos = float(axis @ force) / (math.sqrt(float(axis @ axis)) * norm)
        if math.degrees(math.acos(min(1.0, max(-1.0, cos)))) > max_angle:
            return False
    return True


def is_static(actor, lin_thresh: float = 1e-2, ang_thresh: float = 1e-1) -> bool:
    """ManiSkill's ``actor.is_static``: linear [m/s] and angular [rad/s] speed under the
    thresholds."""
    body = actor._bodies[0]
    v, w = body.linear_velocity, body.angular_velocity
    return math.sqrt(float(v @ v)) <= lin_thresh and math.sqrt(float(w @ w)) <= ang_thresh


def pose(actor) -> tuple[np.ndarray, np.ndarray]:
    """(p (3,), q (4,) w first) float32 world pose [m] of a ManiSkill actor."""
    p = actor._objs[0].pose
    return p.p, p.q


def offset_pose(actor, offset) -> tuple[np.ndarray, np.ndarray]:
    """(p, q) world pose of ``actor``'s pose times ``offset`` (ManiSkill Pose of one scene,
    in the actor's frame), as ManiSkill's ``actor.pose * offset``."""
    raw = offset.raw_pose[0].numpy()
    return pose_multiply(pose(actor), (raw[:3], raw[3:]))
