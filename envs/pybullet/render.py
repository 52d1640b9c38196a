"""Rendering stored PyBullet states with its CPU TinyRenderer: the render stage's video view
and the observation cameras (envs/_cameras.py)."""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
import pybullet as p

from envs import CAMERAS
from envs._cameras import (
    AGENTVIEW_EYE,
    AGENTVIEW_FOV,
    AGENTVIEW_TARGET,
    WRIST_FORWARD,
    WRIST_FOV,
    WRIST_POS,
    WRIST_UP,
)

EYE, TARGET, FOV_DEG = (0.45, 0.6, 0.6), (-0.15, 0.0, 0.25), 55.0  # the render stage's view
VIDEO = "video"
NEAR, FAR = 0.01, 5.0  # [m] clipping planes (the wrist camera sees the fingertips up close)


class Renderer:
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
        from envs.pybullet import make_env

        unknown = [c for c in cameras if c not in (VIDEO, *CAMERAS)]
        if unknown:
            raise ValueError(f"cameras {unknown}: expected among {(VIDEO, *CAMERAS)}")
        self.cameras = tuple(cameras)
        self.seconds = dict.fromkeys(self.cameras, 0.0)  # spent per camera, in images()
        self._env = make_env(task, robot)
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

    def _pose_scene(self, state: np.ndarray) -> None:
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

    def _picture(self, view, proj) -> np.ndarray:
        w, h = self._size
        _, _, rgba, _, _ = self._env._sim.getCameraImage(
            w, h, viewMatrix=view, projectionMatrix=proj,
            renderer=p.ER_TINY_RENDERER, shadow=0, lightDirection=[0.4, 0.6, 1.0],
            flags=p.ER_NO_SEGMENTATION_MASK,
        )  # fmt: skip
        return np.reshape(np.asarray(rgba, np.uint8), (h, w, 4))[..., :3].copy()

    def images(self, state: np.ndarray) -> dict[str, np.ndarray]:
        """Camera name -> (H, W, 3) uint8 RGB of the scene in ``state``; adds each camera's
        seconds (its picture, and its share of setting the scene) to ``seconds``."""
        t0 = time.perf_counter()
        self._pose_scene(state)
        share = (time.perf_counter() - t0) / len(self.cameras)
        out = {}
        for name in self.cameras:
            t0 = time.perf_counter()
            if name == VIDEO:
                out[name] = self._picture(*self._video)
            elif name == "agentview":
                out[name] = self._picture(*self._agentview)
            else:
                out[name] = self._picture(self._wrist_view(), self._wrist_proj)
            self.seconds[name] += time.perf_counter() - t0 + share
        return out

    def frame(self, state: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 RGB of the scene in ``state`` from the first camera."""
        return self.images(state)[self.cameras[0]]

    def close(self) -> None:
        self._env.close()
