"""Delta end-effector pose actions <-> absolute controller target poses (paper M.1).

An action is 7-D: [dpos (3), drot (3), gripper]. The controller adds the
translation ``pos_scale * clip(dpos, -1, 1)`` [m] to the current end-effector
position, and pre-multiplies the current end-effector rotation by the rotation
``rot_scale * normclip(drot, 1)`` [rad], both expressed in the robot root frame.
Each back end describes its own convention with a :class:`DeltaPoseController`
so that the generator never needs to know which simulator it drives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from mimicgen_pipe.core import poses


@dataclass(frozen=True, eq=False)
class DeltaPoseController:
    """A delta-pose controller's action convention.

    pos_scale: metres per unit translation action (clipped per dimension to [-1, 1]).
    rot_scale: radians per unit rotation action (rotation 3-vector norm-clipped to 1);
        negative where the simulator inverts the sign (ManiSkill: -0.1).
    rot_repr: how the scaled 3-vector encodes the rotation: intrinsic "euler_xyz"
        (Rx @ Ry @ Rz, ManiSkill) or "axis_angle".
    root_pose: 4x4 pose of the robot root in the world frame; deltas are in this frame.
    """

    pos_scale: float
    rot_scale: float
    rot_repr: Literal["euler_xyz", "axis_angle"] = "euler_xyz"
    root_pose: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self) -> None:
        # the inverse root pose is used on every step; computed once
        object.__setattr__(self, "root_pose_inv", poses.pose_inv(np.asarray(self.root_pose)))

    def _rot_from_vec(self, v: np.ndarray) -> np.ndarray:
        if self.rot_repr == "euler_xyz":
            return poses.euler_xyz_to_matrix(v)
        return poses.axis_angle_to_matrix(v)

    def _vec_from_rot(self, r: np.ndarray) -> np.ndarray:
        if self.rot_repr == "euler_xyz":
            return poses.matrix_to_euler_xyz(r)
        return poses.matrix_to_axis_angle(r)


def clip_actions(actions: np.ndarray) -> np.ndarray:
    """Clip as the controller does: translation per dimension to [-1, 1], rotation by norm to 1,
    gripper to [-1, 1]. Returns a new array."""
    a = np.array(actions, dtype=np.float64, copy=True)
    if a.shape == (7,):  # one action (every control step): plain floats, the same arithmetic
        x = a.tolist()
        a[:3] = [min(max(v, -1.0), 1.0) for v in x[:3]]
        # numpy's norm along an axis: sqrt of the squares summed in order
        norm = math.sqrt(x[3] * x[3] + x[4] * x[4] + x[5] * x[5])
        if norm > 1.0:
            a[3:6] /= max(norm, 1e-12)
        a[6] = min(max(x[6], -1.0), 1.0)
        return a
    a[..., :3] = np.clip(a[..., :3], -1.0, 1.0)
    norm = np.linalg.norm(a[..., 3:6], axis=-1, keepdims=True)
    a[..., 3:6] = np.where(norm > 1.0, a[..., 3:6] / np.maximum(norm, 1e-12), a[..., 3:6])
    a[..., 6] = np.clip(a[..., 6], -1.0, 1.0)
    return a


def actions_to_target_poses(
    eef_poses: np.ndarray, actions: np.ndarray, controller: DeltaPoseController
) -> np.ndarray:
    """Controller target poses (..., 4, 4, world frame) reached by applying ``actions`` (..., 7)
    from end-effector poses ``eef_poses`` (..., 4, 4, world frame)."""
    a = clip_actions(actions)
    eef_root = controller.root_pose_inv @ eef_poses
    target = np.array(eef_root, dtype=np.float64, copy=True)
    target[..., :3, 3] = eef_root[..., :3, 3] + controller.pos_scale * a[..., :3]
    delta_r = controller._rot_from_vec(controller.rot_scale * a[..., 3:6])
    target[..., :3, :3] = delta_r @ eef_root[..., :3, :3]
    return controller.root_pose @ target


def target_poses_to_actions(
    eef_poses: np.ndarray,
    target_poses: np.ndarray,
    gripper: np.ndarray,
    controller: DeltaPoseController,
) -> np.ndarray:
    """Delta-pose actions (..., 7) that move ``eef_poses`` towards ``target_poses`` (both
    (..., 4, 4), world frame), with gripper commands ``gripper`` (...,), clipped to the
    action space (a far target gives a saturated action, as the controller would)."""
    eef_root = controller.root_pose_inv @ eef_poses
    tgt_root = controller.root_pose_inv @ target_poses
    dpos = (tgt_root[..., :3, 3] - eef_root[..., :3, 3]) / controller.pos_scale
    delta_r = tgt_root[..., :3, :3] @ np.swapaxes(eef_root[..., :3, :3], -1, -2)
    drot = controller._vec_from_rot(delta_r) / controller.rot_scale
    grip = np.asarray(gripper, dtype=np.float64)[..., None]
    return clip_actions(np.concatenate([dpos, drot, grip], -1))
