"""The method's pure functions: segment transform, interpolation, selection, noise, parsing."""

import numpy as np
import pytest

from mimicgen_pipe.core import poses
from mimicgen_pipe.core.taskspec import SubtaskSpec
from mimicgen_pipe.method.generation import (
    action_noise,
    add_action_noise,
    interpolation,
    pose_distance,
    select_source,
    transform_segment,
)
from mimicgen_pipe.method.segments import segment_bounds, split_into_segments, validate_segments
from mimicgen_pipe.method.selection import Candidates


def random_poses(rng, n):
    q = rng.standard_normal((n, 4))
    return poses.pose_from_pq(rng.uniform(-0.5, 0.5, (n, 3)), q)


def test_transformed_segment_keeps_pose_relative_to_object():
    rng = np.random.default_rng(0)
    seg = random_poses(rng, 30)
    src_obj, new_obj = random_poses(rng, 2)
    out = transform_segment(seg, src_obj, new_obj)
    rel_src = poses.pose_inv(src_obj) @ seg
    rel_new = poses.pose_inv(new_obj) @ out
    assert np.max(np.abs(rel_new - rel_src)) < 1e-9
    # and it moved: the new targets differ from the source ones
    assert np.max(np.abs(out - seg)) > 1e-3


def test_transform_with_same_object_pose_is_identity():
    rng = np.random.default_rng(1)
    seg = random_poses(rng, 5)
    obj = random_poses(rng, 1)[0]
    np.testing.assert_allclose(transform_segment(seg, obj, obj), seg, atol=1e-12)


@pytest.mark.parametrize("n_interp,n_fixed", [(5, 0), (25, 25), (2, 3), (1, 0), (0, 4)])
def test_interpolation_endpoints_and_length(n_interp, n_fixed):
    rng = np.random.default_rng(2)
    a, b = random_poses(rng, 2)
    out = interpolation(a, b, n_interp, n_fixed)
    assert out.shape == (n_interp + n_fixed, 4, 4)
    if n_interp >= 2:
        np.testing.assert_allclose(out[0], a, atol=1e-9)
    if len(out):
        np.testing.assert_allclose(out[-1], b, atol=1e-9)
        np.testing.assert_allclose(out[n_interp:], np.broadcast_to(b, (n_fixed, 4, 4)), atol=1e-9)


def test_interpolation_is_linear_and_slerp():
    a = np.eye(4)
    b = poses.pose_from_pq(np.array([0.4, 0, 0]), np.array([np.cos(0.5), 0, 0, np.sin(0.5)]))
    out = interpolation(a, b, 5, 0)
    np.testing.assert_allclose(out[:, 0, 3], [0, 0.1, 0.2, 0.3, 0.4], atol=1e-12)
    angles = poses.rotation_angle(np.broadcast_to(np.eye(3), (5, 3, 3)), out[:, :3, :3])
    np.testing.assert_allclose(angles, np.linspace(0, 1.0, 5), atol=1e-9)


def by_object(cands: np.ndarray, pose: np.ndarray) -> Candidates:
    """Candidates whose reference objects stand at ``cands``, the object now at ``pose``;
    the end effector far from every segment's start."""
    far = np.eye(4)
    far[:3, 3] = 5.0
    return Candidates(cands, pose, cands.copy(), far)


def test_nearest_neighbour_ranks_by_paper_distance_and_draws_from_first_k():
    base = np.eye(4)
    cands = np.stack([np.eye(4)] * 5)
    cands[0, :3, 3] = [0.30, 0, 0]  # 0.30
    cands[1, :3, 3] = [0.05, 0, 0]  # 0.05
    cands[2, :3, :3] = poses.axis_angle_to_matrix(np.array([0, 0, 0.1]))  # 0.10 (angle only)
    cands[3, :3, 3] = [0, 0.2, 0]  # 0.20
    cands[4, :3, 3] = [0.01, 0, 0]  # 0.01 + 0.5 rad
    cands[4, :3, :3] = poses.axis_angle_to_matrix(np.array([0.5, 0, 0]))
    np.testing.assert_allclose(
        pose_distance(cands, base), [0.30, 0.05, 0.10, 0.20, 0.51], atol=1e-9
    )
    rng = np.random.default_rng(0)
    c = by_object(cands, base)
    picks = {select_source("nearest_neighbor", c, rng, nn_k=2) for _ in range(200)}
    assert picks == {1, 2}
    picks = {select_source("nearest_neighbor", c, rng, nn_k=1) for _ in range(20)}
    assert picks == {1}
    picks = {select_source("random", c, rng) for _ in range(300)}
    assert picks == {0, 1, 2, 3, 4}


def test_robot_distance_ranks_segment_starts_by_distance_to_the_end_effector():
    """nearest_neighbor_robot_distance ranks by where each segment's first target lands in
    the new scene against the end effector now, not by the objects' poses."""
    rng = np.random.default_rng(1)
    eef = poses.pose_from_pq(np.array([0.1, -0.2, 0.3]), np.array([0.0, 1.0, 0.0, 0.0]))
    offsets = [0.30, 0.02, 0.15, 0.0, 0.08]  # [m] of each segment's first target from eef
    first = np.stack([eef.copy() for _ in offsets])
    for k, d in enumerate(offsets):
        first[k, :3, 3] += [d, 0, 0]
    first[3, :3, :3] = first[3, :3, :3] @ poses.axis_angle_to_matrix(np.array([0, 0, 0.4]))
    # object poses ranked the other way round: nearest_neighbor would pick otherwise
    objects = np.stack([np.eye(4)] * 5)
    for k, d in enumerate([0.0, 0.5, 0.1, 0.4, 0.3]):
        objects[k, :3, 3] = [d, 0, 0]
    c = Candidates(objects, np.eye(4), first, eef)
    np.testing.assert_allclose(pose_distance(first, eef), [0.30, 0.02, 0.15, 0.4, 0.08], atol=1e-9)
    picks = {select_source("nearest_neighbor_robot_distance", c, rng, nn_k=2) for _ in range(200)}
    assert picks == {1, 4}
    assert {select_source("nearest_neighbor", c, rng, nn_k=2) for _ in range(200)} == {0, 2}


def test_action_noise_spares_gripper():
    rng = np.random.default_rng(0)
    a = np.zeros((2000, 7))
    a[:, 6] = -1
    noise = action_noise(np.full(len(a), 0.05), rng)
    noisy = np.stack([add_action_noise(x, n) for x, n in zip(a, noise, strict=True)])
    assert np.all(noisy[:, 6] == -1)
    assert noisy[:, :6].std() == pytest.approx(0.05, rel=0.05)


def test_action_noise_drawn_at_once_is_drawn_row_by_row():
    sigma = np.array([0.05, 0.0, 0.1, 0.05])
    at_once = action_noise(sigma, np.random.default_rng(3))
    rng = np.random.default_rng(3)
    by_row = np.stack([action_noise(sigma[k : k + 1], rng)[0] for k in range(len(sigma))])
    assert np.array_equal(at_once, by_row)
    assert np.all(at_once[1] == 0) and np.all(at_once[[0, 2, 3]] != 0)


SUBTASKS = (
    SubtaskSpec("grasp", "a", "grasp_a", (2, 4)),
    SubtaskSpec("place", "b", "place_b", (0, 0)),
    SubtaskSpec("done", "b", None),
)


def test_split_on_first_rise_after_previous_boundary():
    t = 40
    grasp = np.zeros(t, bool)
    grasp[5:8] = True  # a first, brief grasp
    grasp[12:] = True
    place = np.zeros(t, bool)
    place[3] = True  # before the grasp: must be ignored
    place[25:] = True
    ends = split_into_segments({"grasp_a": grasp, "place_b": place}, SUBTASKS)
    assert ends.tolist() == [5, 25]
    assert validate_segments(ends, t, SUBTASKS) is None
    b = segment_bounds(ends, [3, 0], t)
    assert b.tolist() == [[0, 8], [8, 25], [25, 40]]


def test_split_errors_name_the_subtask():
    t = 20
    with pytest.raises(ValueError, match="place"):
        split_into_segments({"grasp_a": np.arange(t) > 3, "place_b": np.zeros(t, bool)}, SUBTASKS)
    with pytest.raises(ValueError, match="no signal"):
        split_into_segments({"grasp_a": np.arange(t) > 3}, SUBTASKS)


def test_validate_rejects_offsets_that_cross_the_next_boundary():
    assert validate_segments(np.array([5, 8]), 40, SUBTASKS) is not None  # 5 + 4 >= 8
    assert validate_segments(np.array([5, 10]), 40, SUBTASKS) is None
    assert validate_segments(np.array([5, 39]), 39, SUBTASKS) is not None  # last segment empty
