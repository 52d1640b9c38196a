"""Rendering stored PyBullet states with its CPU TinyRenderer."""

from __future__ import annotations

import numpy as np
import pybullet as p

EYE, TARGET, FOV_DEG = (0.45, 0.6, 0.6), (-0.15, 0.0, 0.25), 55.0


class Renderer:
    """Frames of flat states (PyBulletEnv.get_state() layout) of ``task`` with ``robot``."""

    def __init__(self, task: str, robot: str, width: int, height: int) -> None:
        from envs.pybullet import make_env

        self._env = make_env(task, robot)
        self._size = (width, height)
        self._view = p.computeViewMatrix(EYE, TARGET, [0, 0, 1])
        self._proj = p.computeProjectionMatrixFOV(FOV_DEG, width / height, 0.02, 5.0)

    def frame(self, state: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 RGB of the scene in ``state``."""
        self._env.set_state(state)
        w, h = self._size
        _, _, rgba, _, _ = self._env._sim.getCameraImage(
            w, h, viewMatrix=self._view, projectionMatrix=self._proj,
            renderer=p.ER_TINY_RENDERER, shadow=0, lightDirection=[0.4, 0.6, 1.0],
            flags=p.ER_NO_SEGMENTATION_MASK,
        )  # fmt: skip
        return np.reshape(np.asarray(rgba, np.uint8), (h, w, 4))[..., :3].copy()

    def close(self) -> None:
        self._env.close()
