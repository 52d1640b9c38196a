"""Low-dimensional policy observations (paper N: end-effector pose, gripper finger positions
and ground-truth object poses), computed one way for recording and for policy rollouts.

Every key is a flat float32 vector in the world frame (positions in metres, quaternions
wxyz). Quaternions carry a sign convention, because simulators return q or -q at will and a
sign flip between two steps is a jump the policy would have to learn:

- the end effector's quaternion lies in the hemisphere of ``EEF_QUAT_REFERENCE`` (gripper
  pointing straight down): continuous for every top-down grasp yaw within ±180°;
- an object's quaternion has w >= 0.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence

import numpy as np

from mimicgen_pipe.core import poses

QUAT_ORDER = "wxyz"  # the order of every quaternion key's four components (scalar first)
EEF_QUAT_REFERENCE = np.array([0.0, 1.0, 0.0, 0.0])  # wxyz: 180° about world x, pointing down


def observation_keys(objects: Sequence[str], arms: Sequence[str] = ()) -> tuple[str, ...]:
    """Every key ``low_dim_observation`` returns for a task with these objects, in order;
    with ``arms`` (a task of several), :func:`arms_observation_values`'."""
    keys = ["eef_pos", "eef_quat", "gripper_qpos"]
    for o in objects:
        keys += [f"{o}_pos", f"{o}_quat", f"eef_to_{o}_pos"]
    for i, a in enumerate(objects):
        keys += [f"{a}_to_{b}_pos" for b in objects[i + 1 :]]
    if arms:
        return _arm_keys(tuple(keys), arms)
    return tuple(keys)


def _arm_keys(keys: tuple[str, ...], arms: Sequence[str]) -> tuple[str, ...]:
    """One arm's keys for several arms: the arm's own (end effector, gripper) once per arm,
    prefixed with its name, then the objects' once."""
    own = tuple(k for k in keys if _is_arms(k))
    return tuple(f"{a}_{k}" for a in arms for k in own) + tuple(k for k in keys if k not in own)


def is_robot_key(key: str) -> bool:
    """An observation key of the robot (observation.state), not of an object: eef_pos,
    eef_quat, gripper_qpos, or one of them after an arm's name (left_eef_pos);
    eef_to_<obj>_pos is the object's, seen from the gripper."""
    own = re.sub(r"^[A-Za-z0-9]+_(?=eef_|gripper_)", "", key)
    return own.startswith(("eef_", "gripper_")) and not own.startswith("eef_to_")


def is_quat_key(key: str) -> bool:
    """A quaternion's key (eef_quat, cubeA_quat, left_eef_quat): four values in QUAT_ORDER."""
    return key.endswith("_quat")


def _is_arms(key: str) -> bool:
    return key.startswith("eef") or key == "gripper_qpos"


def _quat(rotation: np.ndarray, reference: np.ndarray | None) -> np.ndarray:
    q = poses.matrix_to_quat_wxyz_stepwise(rotation)  # w >= 0, the same floats one or many
    if reference is None:
        return q
    return np.where((q @ reference)[..., None] < 0, -q, q)


def low_dim_observation(
    eef_pose: np.ndarray,
    gripper_qpos: np.ndarray,
    object_poses: Mapping[str, np.ndarray],
    objects: Sequence[str],
) -> dict[str, np.ndarray]:
    """Observation of one step: :func:`observation_values` as float32."""
    values = observation_values(eef_pose, gripper_qpos, object_poses, objects)
    return {k: np.asarray(v, np.float32) for k, v in values.items()}


def observation_values(
    eef_pose: np.ndarray,
    gripper_qpos: np.ndarray,
    object_poses: Mapping[str, np.ndarray],
    objects: Sequence[str],
) -> dict[str, np.ndarray]:
    """Observation of one step, or of many at once (leading dimensions), in float64 (a
    recorder casts a whole episode's at once); the same floats either way.

    eef_pose: (..., 4, 4) end-effector (TCP) pose, world frame. gripper_qpos: (..., n)
    finger joint positions [m]. object_poses: object name -> (..., 4, 4) pose, world frame.
    Relative positions
    (``eef_to_<obj>_pos`` = object minus end-effector position, ``<a>_to_<b>_pos`` = b minus
    a) are in the world frame.
    """
    out = {
        "eef_pos": eef_pose[..., :3, 3],
        "eef_quat": _quat(eef_pose[..., :3, :3], EEF_QUAT_REFERENCE),
        "gripper_qpos": np.asarray(gripper_qpos, np.float64),
    }
    for o in objects:
        t = object_poses[o]
        out[f"{o}_pos"] = t[..., :3, 3]
        out[f"{o}_quat"] = _quat(t[..., :3, :3], None)
        out[f"eef_to_{o}_pos"] = t[..., :3, 3] - eef_pose[..., :3, 3]
    for i, a in enumerate(objects):
        for b in objects[i + 1 :]:
            out[f"{a}_to_{b}_pos"] = object_poses[b][..., :3, 3] - object_poses[a][..., :3, 3]
    return out


def arms_observation_values(
    eef_poses: Mapping[str, np.ndarray],
    gripper_qpos: Mapping[str, np.ndarray],
    object_poses: Mapping[str, np.ndarray],
    objects: Sequence[str],
) -> dict[str, np.ndarray]:
    """Observation of one step of a task with several arms, in float64: each arm's
    end-effector pose, gripper and end-effector-to-object positions as one arm's, prefixed
    with the arm's name (``left_eef_pos``), and the objects' poses and relative positions
    once. eef_poses, gripper_qpos: arm -> as :func:`observation_values` takes them."""
    out: dict[str, np.ndarray] = {}
    for arm, eef in eef_poses.items():
        one = observation_values(eef, gripper_qpos[arm], object_poses, objects)
        out |= {f"{arm}_{k}": v for k, v in one.items() if _is_arms(k)}
    return out | {k: v for k, v in one.items() if not _is_arms(k)}


def observation_dims(objects: Sequence[str], arms: Sequence[str] = ()) -> dict[str, int]:
    """Width of every observation key of a task with these objects (and with ``arms``, a
    task of several, :func:`arms_observation_values`' keys)."""
    eye = np.eye(4)
    poses_ = {o: eye for o in objects}
    if arms:
        values = arms_observation_values(
            {a: eye for a in arms}, {a: np.zeros(2) for a in arms}, poses_, objects
        )
    else:
        values = observation_values(eye, np.zeros(2), poses_, objects)
    return {k: int(np.size(v)) for k, v in values.items()}
