"""Serial-chain kinematics and damped-least-squares inverse kinematics, batched over poses.

A :class:`Chain` is plain arrays (mimicgen_pipe/backends/pybullet/robots.py builds it from a URDF
with pytorch-kinematics); every function here takes a batch of joint vectors (B, n) and poses
(B, 4, 4), so one call solves one pose or a whole segment. All poses are in the chain's root
frame (the robot base link) [m].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mimicgen_pipe.core import poses


@dataclass(frozen=True, eq=False)
class Chain:
    """A serial chain of n revolute/prismatic joints ending at a tool centre point (TCP).

    offsets: (n, 4, 4) fixed transform from the previous joint's frame (the root for the first)
        to joint i's frame at zero position, fixed links folded in.
    axes: (n, 3) unit joint axes in each joint's frame. prismatic: (n,) bool.
    tip: (4, 4) fixed transform from the last joint's frame to the TCP.
    lower / upper: (n,) joint limits [rad or m]. names: joint names, in order.
    """

    offsets: np.ndarray
    axes: np.ndarray
    prismatic: np.ndarray
    tip: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    names: tuple[str, ...]

    @property
    def dof(self) -> int:
        return len(self.names)


def _joint_motion(axes: np.ndarray, prismatic: bool, q: np.ndarray) -> np.ndarray:
    """(B, 4, 4) motion of one joint at positions q (B,)."""
    out = np.zeros((len(q), 4, 4))
    out[:, 3, 3] = 1.0
    if prismatic:
        out[:, :3, :3] = np.eye(3)
        out[:, :3, 3] = q[:, None] * axes
    else:
        out[:, :3, :3] = poses.axis_angle_to_matrix(q[:, None] * axes)
    return out


def forward_kinematics(chain: Chain, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """TCP poses (B, 4, 4) and joint frames (B, n, 4, 4) at joint positions q (B, n)."""
    q = np.atleast_2d(np.asarray(q, np.float64))
    frames = np.zeros((len(q), chain.dof, 4, 4))
    t = np.broadcast_to(np.eye(4), (len(q), 4, 4))
    for i in range(chain.dof):
        t = t @ chain.offsets[i]
        frames[:, i] = t
        t = t @ _joint_motion(chain.axes[i], bool(chain.prismatic[i]), q[:, i])
    return t @ chain.tip, frames


def jacobian(chain: Chain, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Geometric Jacobians (B, 6, n) of the TCP (linear rows first, root frame) and the TCP
    poses (B, 4, 4) at q (B, n)."""
    tcp, frames = forward_kinematics(chain, q)
    z = np.einsum("bnij,nj->bni", frames[..., :3, :3], chain.axes)  # axes in the root frame
    jac = np.zeros((len(tcp), 6, chain.dof))
    lever = tcp[:, None, :3, 3] - frames[..., :3, 3]
    rev = ~chain.prismatic
    jac[:, :3, rev] = np.swapaxes(np.cross(z, lever), 1, 2)[:, :, rev]
    jac[:, 3:, rev] = np.swapaxes(z, 1, 2)[:, :, rev]
    jac[:, :3, chain.prismatic] = np.swapaxes(z, 1, 2)[:, :, chain.prismatic]
    return jac, tcp


def pose_error(current: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(B, 6) error from current to target poses (B, 4, 4): position [m], then the rotation
    vector [rad] of target @ current^-1, both in the root frame."""
    err = np.empty((len(current), 6))
    err[:, :3] = target[:, :3, 3] - current[:, :3, 3]
    err[:, 3:] = poses.matrix_to_axis_angle(
        target[:, :3, :3] @ np.swapaxes(current[:, :3, :3], 1, 2)
    )
    return err


@dataclass(frozen=True)
class IKResult:
    """q: (B, n) solutions. position_error [m] and rotation_error [rad]: (B,) residuals at q.
    converged: (B,) within the tolerances asked for."""

    q: np.ndarray
    position_error: np.ndarray
    rotation_error: np.ndarray
    converged: np.ndarray


POSITION_TOL = 1e-3  # [m]
ROTATION_TOL = np.deg2rad(0.5)  # [rad]


def inverse_kinematics(
    chain: Chain,
    targets: np.ndarray,
    q0: np.ndarray,
    iterations: int = 100,
    damping: float = 0.05,
    max_step: float = 0.2,
    position_tol: float = POSITION_TOL,
    rotation_tol: float = ROTATION_TOL,
    restarts: np.ndarray | None = None,
) -> IKResult:
    """Damped least squares: q += J^T (J J^T + damping^2 I)^-1 e, each joint step clipped to
    ``max_step`` [rad or m] and the result to the joint limits; a row stops changing once it
    is within tolerance. targets: (B, 4, 4) TCP poses in the root frame; q0: (n,) or (B, n)
    starts. ``restarts``: (R, n) joint positions to start again from, in turn, for the rows
    not converged yet."""
    targets = np.asarray(targets, np.float64).reshape(-1, 4, 4)
    q = np.array(np.broadcast_to(q0, (len(targets), chain.dof)), np.float64)
    eye = np.eye(6) * damping**2

    def unsolved(err: np.ndarray) -> np.ndarray:
        return (np.linalg.norm(err[:, :3], axis=1) > position_tol) | (
            np.linalg.norm(err[:, 3:], axis=1) > rotation_tol
        )

    for start in [None, *(() if restarts is None else restarts)]:
        if start is not None:
            redo = unsolved(pose_error(forward_kinematics(chain, q)[0], targets))
            if not redo.any():
                break
            q[redo] = start
        for _ in range(iterations):
            jac, tcp = jacobian(chain, q)
            err = pose_error(tcp, targets)
            active = unsolved(err)
            if not active.any():
                break
            j, e = jac[active], err[active]
            dq = np.einsum(
                "bji,bj->bi",
                j,
                np.linalg.solve(j @ np.swapaxes(j, 1, 2) + eye, e[..., None])[..., 0],
            )
            dq = np.clip(dq, -max_step, max_step)
            q[active] = np.clip(q[active] + dq, chain.lower, chain.upper)
    err = pose_error(forward_kinematics(chain, q)[0], targets)
    pos, rot = np.linalg.norm(err[:, :3], axis=1), np.linalg.norm(err[:, 3:], axis=1)
    return IKResult(q, pos, rot, ~unsolved(err))
