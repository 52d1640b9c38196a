"""Rigid-body pose helpers over numpy arrays.

Poses are 4x4 homogeneous float64 matrices ``T_A^B`` (the pose of frame B in
frame A; translation in metres). Quaternions appear only at the edges, in
(w, x, y, z) order as ManiSkill/SAPIEN write them. Every function accepts a
batch of leading dimensions.
"""

from __future__ import annotations

import numpy as np


def quat_wxyz_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3, 3) rotation matrices."""
    q = np.asarray(q, dtype=np.float64)
    if q.ndim == 1:  # one quaternion: plain floats beat numpy's per-call overhead ~10x
        return np.array(_quat_rows_one(q))
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return _rotation(*np.moveaxis(q, -1, 0))


def _rotation(w: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices of unit quaternions given by their components (...)."""
    r = np.empty(np.shape(w) + (3, 3))
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - w * z)
    r[..., 0, 2] = 2 * (x * z + w * y)
    r[..., 1, 0] = 2 * (x * y + w * z)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - w * x)
    r[..., 2, 0] = 2 * (x * z - w * y)
    r[..., 2, 1] = 2 * (y * z + w * x)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def _quat_rows_one(q: np.ndarray) -> list[list[float]]:
    """The rows of one (4,) wxyz quaternion's rotation matrix, as plain floats."""
    w, x, y, z = q.tolist()
    n = (w * w + x * x + y * y + z * z) ** 0.5
    w, x, y, z = w / n, x / n, y / n, z / n
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]


def matrix_to_quat_wxyz(r: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) quaternions (w, x, y, z), w >= 0."""
    r = np.asarray(r, dtype=np.float64)
    if r.ndim == 2:  # one matrix: the batched path below costs ~15x more per call
        return _matrix_to_quat_one(r)
    q = _shepperd(r, np.sqrt)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def _shepperd(r: np.ndarray, root) -> np.ndarray:
    """(..., 4) unnormalised wxyz quaternions of rotations (..., 3, 3) by Shepperd's method:
    from the largest of the four squared components (the first, on a tie), for stability;
    ``root`` takes its square root (np.sqrt, or _root for the one-matrix path's floats)."""
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    cand = np.stack(
        [1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1
    )
    k = np.argmax(cand, axis=-1)
    s = root(np.maximum(np.take_along_axis(cand, k[..., None], -1)[..., 0], 1e-300)) * 2
    d10, d01 = r[..., 1, 0], r[..., 0, 1]
    d20, d02 = r[..., 2, 0], r[..., 0, 2]
    d21, d12 = r[..., 2, 1], r[..., 1, 2]
    rows = [
        (0.25 * s, (d21 - d12) / s, (d02 - d20) / s, (d10 - d01) / s),
        ((d21 - d12) / s, 0.25 * s, (d01 + d10) / s, (d02 + d20) / s),
        ((d02 - d20) / s, (d01 + d10) / s, 0.25 * s, (d12 + d21) / s),
        ((d10 - d01) / s, (d02 + d20) / s, (d12 + d21) / s, 0.25 * s),
    ]
    q = np.empty(r.shape[:-2] + (4,))
    for i, row in enumerate(rows):
        sel = k == i
        q[sel] = np.stack([np.asarray(c)[sel] for c in row], -1)
    return q


def _matrix_to_quat_one(r: np.ndarray) -> np.ndarray:
    """One 3x3 rotation -> wxyz quaternion with w >= 0 (Shepperd's method, plain floats)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = r.tolist()
    cand = (1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22)
    k = max(range(4), key=cand.__getitem__)
    s = max(cand[k], 1e-300) ** 0.5 * 2
    if k == 0:
        q = (0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s)
    elif k == 1:
        q = ((m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s)
    elif k == 2:
        q = ((m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s)
    else:
        q = ((m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s)
    n = sum(c * c for c in q) ** 0.5 * (1.0 if q[0] >= 0 else -1.0)
    return np.array([c / n for c in q])


def pose_from_pq(p: np.ndarray, q_wxyz: np.ndarray) -> np.ndarray:
    """Position (..., 3) [m] and quaternion (..., 4) wxyz -> (..., 4, 4) pose."""
    p = np.asarray(p, dtype=np.float64)
    q_wxyz = np.asarray(q_wxyz, dtype=np.float64)
    if p.ndim == 1 and q_wxyz.ndim == 1:  # one pose (every step): the same floats, built once
        rows = _quat_rows_one(q_wxyz)
        for row, v in zip(rows, p.tolist(), strict=True):
            row.append(v)
        return np.array([*rows, [0.0, 0.0, 0.0, 1.0]])
    t = np.zeros(p.shape[:-1] + (4, 4))
    t[..., :3, :3] = quat_wxyz_to_matrix(q_wxyz)
    t[..., :3, 3] = p
    t[..., 3, 3] = 1.0
    return t


def pose_from_pq_stepwise(p: np.ndarray, q_wxyz: np.ndarray) -> np.ndarray:
    """(T, 3) positions [m] and (T, 4) wxyz quaternions -> (T, 4, 4) poses, each row's the
    same floats, bit for bit, as pose_from_pq of that row alone: the one-pose arithmetic,
    vectorised. A recorder derives a whole episode's poses with it after the episode."""
    w, x, y, z = np.moveaxis(np.asarray(q_wxyz, np.float64), -1, 0)
    n = _root(w * w + x * x + y * y + z * z)
    t = np.zeros(w.shape + (4, 4))
    t[..., :3, :3] = _rotation(w / n, x / n, y / n, z / n)
    t[..., :3, 3] = np.asarray(p, np.float64)
    t[..., 3, 3] = 1.0
    return t


def matrix_to_quat_wxyz_stepwise(r: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations -> (..., 4) wxyz quaternions, w >= 0, each the same floats, bit
    for bit, as matrix_to_quat_wxyz of that matrix alone (the one-matrix path's arithmetic,
    vectorised; the batched path's own arithmetic differs in the last bit)."""
    r = np.asarray(r, dtype=np.float64)
    if r.ndim == 2:
        return _matrix_to_quat_one(r)
    q = _shepperd(r, _root)
    c0, c1, c2, c3 = np.moveaxis(q, -1, 0)
    n = _root(c0 * c0 + c1 * c1 + c2 * c2 + c3 * c3) * np.where(c0 >= 0, 1.0, -1.0)
    return q / n[..., None]


def _root(x: np.ndarray) -> np.ndarray:
    """x ** 0.5 element by element as Python floats take it (C's pow), as the one-pose paths
    do: np.sqrt may differ from pow in the last bit."""
    return np.array([v**0.5 for v in np.ravel(x).tolist()]).reshape(np.shape(x))


def pose_to_pq(t: np.ndarray) -> np.ndarray:
    """(..., 4, 4) pose -> (..., 7) [x, y, z, qw, qx, qy, qz]."""
    t = np.asarray(t, dtype=np.float64)
    return np.concatenate([t[..., :3, 3], matrix_to_quat_wxyz(t[..., :3, :3])], -1)


def pose_inv(t: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (..., 4, 4), exact (R^T, -R^T p)."""
    r = np.swapaxes(t[..., :3, :3], -1, -2)
    out = np.zeros_like(t, dtype=np.float64)
    out[..., :3, :3] = r
    out[..., :3, 3] = -(r @ t[..., :3, 3:4])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def axis_angle_to_matrix(v: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors (axis * angle [rad]) -> (..., 3, 3) (Rodrigues)."""
    v = np.asarray(v, dtype=np.float64)
    theta = np.linalg.norm(v, axis=-1)[..., None, None]
    k = np.zeros(v.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24, (1 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * k + b * (k @ k)


def matrix_to_axis_angle(r: np.ndarray) -> np.ndarray:
    """(..., 3, 3) -> (..., 3) rotation vectors with angle in [0, pi]."""
    q = matrix_to_quat_wxyz(r)
    w = np.clip(q[..., 0], -1.0, 1.0)
    s = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2 * np.arctan2(s, w)
    scale = np.where(s < 1e-12, 2.0, angle / np.where(s < 1e-12, 1.0, s))
    return q[..., 1:] * scale[..., None]


def rotation_angle(r_a: np.ndarray, r_b: np.ndarray) -> np.ndarray:
    """Angle [rad] of the relative rotation r_a^T r_b (the axis-angle magnitude)."""
    rel = np.swapaxes(r_a, -1, -2) @ r_b
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1) / 2
    return np.arccos(np.clip(cos, -1.0, 1.0))


def euler_xyz_to_matrix(e: np.ndarray) -> np.ndarray:
    """(..., 3) angles [rad] -> Rx(e0) @ Ry(e1) @ Rz(e2) (pytorch3d's "XYZ", used by ManiSkill)."""
    e = np.asarray(e, dtype=np.float64)
    cx, cy, cz = np.cos(e[..., 0]), np.cos(e[..., 1]), np.cos(e[..., 2])
    sx, sy, sz = np.sin(e[..., 0]), np.sin(e[..., 1]), np.sin(e[..., 2])
    r = np.empty(e.shape[:-1] + (3, 3))
    r[..., 0, 0] = cy * cz
    r[..., 0, 1] = -cy * sz
    r[..., 0, 2] = sy
    r[..., 1, 0] = cx * sz + sx * sy * cz
    r[..., 1, 1] = cx * cz - sx * sy * sz
    r[..., 1, 2] = -sx * cy
    r[..., 2, 0] = sx * sz - cx * sy * cz
    r[..., 2, 1] = sx * cz + cx * sy * sz
    r[..., 2, 2] = cx * cy
    return r


def matrix_to_euler_xyz(r: np.ndarray) -> np.ndarray:
    """Inverse of :func:`euler_xyz_to_matrix` (middle angle in [-pi/2, pi/2])."""
    r = np.asarray(r, dtype=np.float64)
    ex = np.arctan2(-r[..., 1, 2], r[..., 2, 2])
    ey = np.arcsin(np.clip(r[..., 0, 2], -1.0, 1.0))
    ez = np.arctan2(-r[..., 0, 1], r[..., 0, 0])
    return np.stack([ex, ey, ez], -1)


def slerp_matrix(r0: np.ndarray, r1: np.ndarray, alphas: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation from r0 (3, 3) to r1 (3, 3) at fractions alphas (K,)."""
    rel = matrix_to_axis_angle(r0.T @ r1)
    return r0 @ axis_angle_to_matrix(np.asarray(alphas, dtype=np.float64)[:, None] * rel)
