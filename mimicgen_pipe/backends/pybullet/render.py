"""Rendering stored PyBullet states with its CPU TinyRenderer: the render stage's video view
and the observation cameras (mimicgen_pipe/core/cameras.py)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pybullet as p

from mimicgen_pipe.core.cameras import (
    AGENTVIEW_EYE,
    AGENTVIEW_FOV,
    AGENTVIEW_TARGET,
    VIDEO,
    WRIST_FORWARD,
    WRIST_FOV,
    WRIST_POS,
    WRIST_UP,
    CameraRenderer,
)

EYE, TARGET, FOV_DEG = (0.45, 0.6, 0.6), (-0.15, 0.0, 0.25), 55.0  # the render stage's view
NEAR, FAR = 0.01, 5.0  # [m] clipping planes (the wrist camera sees the fingertips up close)


class Renderer(CameraRenderer):
    """Images of flat states (PyBulletEnv.get_state() layout) of ``task`` with ``robot`` from
    ``cameras``: ``video`` (the render stage's view) and those of CAMERAS, each (height,
    width, 3) uint8 RGB. One scene, built once: a state only moves its joints and bodies,
    which is all a picture shows."""

    def __init__(
        self,
        task: str,
        robot: str,
        width: int,
        height: int,
        cameras: Sequence[str] = (VIDEO,),
    ) -> None:
        from mimicgen_pipe.backends.pybullet.env import PyBulletEnv

        super().__init__(cameras)
        self._env = PyBulletEnv(task, robot)
        self._size = (width, height)
        self._video = (
            p.computeViewMatrix(EYE, TARGET, [0, 0, 1]),
            p.computeProjectionMatrixFOV(FOV_DEG, width / height, 0.02, 5.0),
        )
        self._agentview = (
            p.computeViewMatrix(AGENTVIEW_EYE, AGENTVIEW_TARGET, [0, 0, 1]),
            p.computeProjectionMatrixFOV(np.degrees(AGENTVIEW_FOV), width / height, NEAR, FAR),
        )
        self._wrist_proj = p.computeProjectionMatrixFOV(
            np.degrees(WRIST_FOV), width / height, NEAR, FAR
        )
        env = self._env
        sim = env._sim
        links = [
            sim.getJointInfo(env._robot, j)[12].decode()
            for j in range(sim.getNumJoints(env._robot))
        ]
        self._hand = links.index("panda_hand")  # every arm carries the Franka hand

    def _set_scene(self, state: np.ndarray) -> None:
        """Joints and bodies where ``state`` has them (velocities play no part in a picture)."""
        env, sim = self._env, self._env._sim
        state = np.asarray(state, np.float64)
        joints = env._arm + env._fingers
        for j, qj in zip(joints, state[: len(joints)], strict=True):
            sim.resetJointState(env._robot, j, float(qj))
        k = 2 * len(joints)
        for name in env.spec.objects:
            s = state[k : k + 13]
            sim.resetBasePositionAndOrientation(env._bodies[name], s[:3].tolist(), s[3:7].tolist())
            k += 13

    def _wrist_view(self) -> list[float]:
        env = self._env
        pos, quat = env._sim.getLinkState(env._robot, self._hand, computeForwardKinematics=True)[
            4:6
        ]
        rot = np.reshape(p.getMatrixFromQuaternion(quat), (3, 3))
        eye = np.asarray(pos) + rot @ WRIST_POS
        return p.computeViewMatrix(
            eye.tolist(), (eye + rot @ WRIST_FORWARD).tolist(), (rot @ WRIST_UP).tolist()
        )

    def _camera_picture(self, view, proj) -> np.ndarray:
        w, h = self._size
        _, _, rgba, _, _ = self._env._sim.getCameraImage(
            w, h, viewMatrix=view, projectionMatrix=proj,
            renderer=p.ER_TINY_RENDERER, shadow=0, lightDirection=[0.4, 0.6, 1.0],
            flags=p.ER_NO_SEGMENTATION_MASK,
        )  # fmt: skip
        return np.reshape(np.asarray(rgba, np.uint8), (h, w, 4))[..., :3].copy()

    def _picture(self, camera: str) -> np.ndarray:
        if camera == VIDEO:
            return self._camera_picture(*self._video)
        if camera == "agentview":
            return self._camera_picture(*self._agentview)
        return self._camera_picture(self._wrist_view(), self._wrist_proj)

    def close(self) -> None:
        self._env.close()
