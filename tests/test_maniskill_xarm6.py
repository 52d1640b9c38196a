"""The xArm6 (with the Franka hand) on the ManiSkill back end (needs SAPIEN; marked ``sim``)."""

from __future__ import annotations

import numpy as np
import pytest

from mimicgen_pipe.core import poses

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def env():
    from mimicgen_pipe.backends import make_env

    e = make_env("maniskill", "stack_cube", "xarm6")
    yield e
    e.close()


def test_make_env_gives_the_xarm6(env):
    from mimicgen_pipe.backends.maniskill.xarm6 import BASE_XYZ, XArm6ManiSkillEnv

    assert isinstance(env, XArm6ManiSkillEnv)
    assert env.robot == "xarm6" and env.spec.name == "stack_cube"
    np.testing.assert_allclose(env.controller.root_pose[:3, 3], BASE_XYZ, atol=1e-6)
    env.reset(seed=0, variant="D0")
    np.testing.assert_allclose(env.gripper_state(), [0.04, 0.04], atol=1e-6)
    assert env.eef_pose()[2, 2] < -0.99  # the TCP points down at the rest keyframe


def test_reset_is_deterministic_per_seed(env):
    env.reset(seed=11, variant="D0")
    first = env.get_state()
    env.reset(seed=12, variant="D0")
    other = env.get_state()
    env.reset(seed=11, variant="D0")
    np.testing.assert_array_equal(env.get_state(), first)
    assert not np.allclose(other, first)


def test_controller_round_trip_converges(env):
    env.reset(seed=4, variant="D0")
    target = env.eef_pose().copy()
    target[:3, 3] += np.array([0.03, -0.03, -0.025])  # ~5 cm
    target[:3, :3] = poses.axis_angle_to_matrix(np.array([0, 0, np.radians(20)])) @ target[:3, :3]
    assert np.linalg.norm(target[:3, 3] - env.eef_pose()[:3, 3]) == pytest.approx(0.05, abs=2e-3)
    for _ in range(40):
        env.step(env.target_pose_to_action(target, 1.0))
        e = env.eef_pose()
        pos_err = np.linalg.norm(e[:3, 3] - target[:3, 3])
        rot_err = poses.rotation_angle(e[:3, :3], target[:3, :3])
        if pos_err < 3e-3 and rot_err < np.radians(2.0):
            break
    assert pos_err < 3e-3, pos_err
    assert rot_err < np.radians(2.0), np.degrees(rot_err)


def _grasp_pose(eef: np.ndarray, cube: np.ndarray, z: float) -> np.ndarray:
    """The TCP pointing down over the cube at height z, its yaw the nearest of the cube's
    four symmetric yaws to the current one."""
    yaw_cube = np.arctan2(cube[1, 0], cube[0, 0])
    yaw_eef = np.arctan2(eef[1, 0], eef[0, 0])
    dyaw = (yaw_cube - yaw_eef + np.pi / 4) % (np.pi / 2) - np.pi / 4
    out = eef.copy()
    out[:3, :3] = poses.axis_angle_to_matrix(np.array([0, 0, dyaw])) @ eef[:3, :3]
    out[:3, 3] = [cube[0, 3], cube[1, 3], z]
    return out


def test_scripted_grasp_lifts_cube_a(env):
    env.reset(seed=2, variant="D0")
    cube0 = env.object_poses()["cubeA"].copy()
    above = _grasp_pose(env.eef_pose(), cube0, cube0[2, 3] + 0.08)
    down = above.copy()
    down[2, 3] = cube0[2, 3]
    lift = above.copy()
    lift[2, 3] = cube0[2, 3] + 0.12
    for target, gripper, n in (
        (above, 1.0, 25),
        (down, 1.0, 20),
        (down, -1.0, 10),
        (lift, -1.0, 25),
    ):
        for _ in range(n):
            env.step(env.target_pose_to_action(target, gripper))
    assert env.subtask_signals()["grasp_cubeA"]
    assert env.object_poses()["cubeA"][2, 3] - cube0[2, 3] > 0.05
    assert np.all(env.gripper_state() < 0.03)  # closed on the 4 cm cube
