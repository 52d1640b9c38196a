"""Pose helpers and the delta-pose action <-> target-pose conversion (no simulator)."""

import numpy as np
import pytest

from mimicgen_pipe.core import poses
from mimicgen_pipe.core.controller import (
    DeltaPoseController,
    actions_to_target_poses,
    target_poses_to_actions,
)


def random_poses(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.standard_normal((n, 4))
    return poses.pose_from_pq(
        rng.uniform(-0.5, 0.5, (n, 3)), q / np.linalg.norm(q, axis=1)[:, None]
    )


def test_quaternion_round_trip_and_known_rotation():
    rng = np.random.default_rng(0)
    t = random_poses(rng, 50)
    back = poses.pose_from_pq(*np.split(poses.pose_to_pq(t), [3], axis=-1))
    np.testing.assert_allclose(back, t, atol=1e-12)
    # 90 degrees about z maps x to y
    r = poses.quat_wxyz_to_matrix(np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]))
    np.testing.assert_allclose(r @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_inverse_is_exact():
    t = random_poses(np.random.default_rng(1), 20)
    np.testing.assert_allclose(
        t @ poses.pose_inv(t), np.broadcast_to(np.eye(4), t.shape), atol=1e-12
    )


def test_euler_xyz_round_trip_and_order():
    rng = np.random.default_rng(2)
    e = rng.uniform(-1.2, 1.2, (100, 3))
    np.testing.assert_allclose(
        poses.matrix_to_euler_xyz(poses.euler_xyz_to_matrix(e)), e, atol=1e-10
    )
    # Rx(a) @ Ry(b) @ Rz(c), as pytorch3d's "XYZ"
    a, b, c = 0.3, -0.4, 0.5
    rx = poses.axis_angle_to_matrix(np.array([a, 0, 0]))
    ry = poses.axis_angle_to_matrix(np.array([0, b, 0]))
    rz = poses.axis_angle_to_matrix(np.array([0, 0, c]))
    np.testing.assert_allclose(
        poses.euler_xyz_to_matrix(np.array([a, b, c])), rx @ ry @ rz, atol=1e-12
    )


def test_axis_angle_round_trip():
    rng = np.random.default_rng(3)
    v = rng.standard_normal((100, 3))
    v *= (rng.uniform(0, np.pi - 1e-3, 100) / np.linalg.norm(v, axis=1))[:, None]
    np.testing.assert_allclose(
        poses.matrix_to_axis_angle(poses.axis_angle_to_matrix(v)), v, atol=1e-9
    )


@pytest.mark.parametrize("rot_repr,rot_scale", [("euler_xyz", -0.1), ("axis_angle", 0.5)])
def test_action_target_round_trip(rot_repr, rot_scale):
    rng = np.random.default_rng(4)
    root = poses.pose_from_pq(
        np.array([-0.615, 0.1, 0.0]), np.array([np.cos(0.2), 0, 0, np.sin(0.2)])
    )
    ctrl = DeltaPoseController(
        pos_scale=0.1, rot_scale=rot_scale, rot_repr=rot_repr, root_pose=root
    )
    eef = random_poses(rng, 200)
    actions = rng.uniform(-1, 1, (200, 7))
    actions[:, 3:6] *= 0.5 / np.linalg.norm(actions[:, 3:6], axis=1, keepdims=True).clip(1, None)
    targets = actions_to_target_poses(eef, actions, ctrl)
    back = target_poses_to_actions(eef, targets, actions[:, 6], ctrl)
    np.testing.assert_allclose(back, actions, atol=1e-9)
    # translation is in the root frame: the world displacement is R_root @ (0.1 * dpos)
    np.testing.assert_allclose(
        targets[:, :3, 3] - eef[:, :3, 3], (root[:3, :3] @ (0.1 * actions[:, :3]).T).T, atol=1e-12
    )


def test_far_target_saturates():
    ctrl = DeltaPoseController(pos_scale=0.1, rot_scale=-0.1)
    eef = np.eye(4)
    target = np.eye(4)
    target[:3, 3] = [1.0, -2.0, 0.05]
    target[:3, :3] = poses.axis_angle_to_matrix(np.array([0, 0, 1.0]))
    a = target_poses_to_actions(eef, target, 1.0, ctrl)
    np.testing.assert_allclose(a[:3], [1.0, -1.0, 0.5])
    assert np.linalg.norm(a[3:6]) == pytest.approx(1.0)
    assert a[5] < 0  # rot_scale < 0: a positive yaw needs a negative action


def test_stepwise_paths_give_the_one_pose_floats_bit_for_bit():
    """A recorder derives an episode's poses and quaternions after it, all steps at once:
    each row must be the floats the one-pose path gives that row alone, with float32
    simulator quaternions (not quite unit) and the four branches of the matrix conversion."""
    rng = np.random.default_rng(3)
    q = rng.standard_normal((4000, 4))
    q[:1000] *= [4, 1, 1, 1]  # w largest ...
    q[1000:2000] *= [1, 4, 1, 1]  # ... x, y, z largest: every branch of Shepperd's method
    q[2000:3000] *= [1, 1, 4, 1]
    q[3000:] *= [1, 1, 1, 4]
    q = (q / np.linalg.norm(q, axis=-1, keepdims=True)).astype(np.float32).astype(np.float64)
    p = rng.uniform(-1, 1, (len(q), 3)).astype(np.float32).astype(np.float64)
    many = poses.pose_from_pq_stepwise(p, q)
    one = np.stack([poses.pose_from_pq(a, b) for a, b in zip(p, q, strict=True)])
    assert many.tobytes() == one.tobytes()
    quats = poses.matrix_to_quat_wxyz_stepwise(many[:, :3, :3])
    assert (
        quats.tobytes()
        == np.stack([poses.matrix_to_quat_wxyz(r) for r in one[:, :3, :3]]).tobytes()
    )
    # the batched path's own arithmetic is another: it is not the reference here
    assert (quats[:, 0] >= 0).all()
