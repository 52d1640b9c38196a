"""Where the observation cameras (envs.CAMERAS, named as robomimic names them) sit; every
back end's render.py renders them. Free of simulator imports.

- ``agentview``: fixed, in front of the table, facing the arm across the workspace: arm,
  gripper and objects in one view.
- ``eye_in_hand``: on the Franka hand, where ManiSkill's ``panda_wristcam`` mounts its camera
  (the URDF's realsense mount on ``panda_hand``), looking along the fingers. Every arm of
  both back ends carries the Franka hand, so every arm has it.

World frame, metres; the table top is z = 0 with the workspace around the origin on both
back ends (the robot base at x = -0.615 on ManiSkill, -0.5 on PyBullet).
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from envs import CAMERAS

VIDEO = "video"  # the render stage's view, beside the observation cameras

# agentview: eye and target [m, world], vertical field of view [rad]
AGENTVIEW_EYE, AGENTVIEW_TARGET, AGENTVIEW_FOV = (0.6, 0.0, 0.6), (-0.3, 0.0, 0.15), 1.0

# eye_in_hand, in the panda_hand frame (z along the fingers, x across them): the camera's
# position [m], its viewing direction and its image's up direction; vertical field of view
# [rad] as panda_wristcam's
WRIST_POS = np.array([0.0465, -0.02, 0.036])
WRIST_FORWARD = np.array([0.0, 0.0, 1.0])
WRIST_UP = np.array([1.0, 0.0, 0.0])
WRIST_FOV = np.pi / 2


class CameraRenderer:
    """What every back end's Renderer shares: images of flat states from ``cameras``
    (``video`` and those of CAMERAS), each (height, width, 3) uint8 RGB, with the seconds
    spent per camera. A back end sets its scene to a state (``_set_scene``) and takes one
    camera's picture of it (``_picture``)."""

    def __init__(self, cameras: Sequence[str]) -> None:
        unknown = [c for c in cameras if c not in (VIDEO, *CAMERAS)]
        if unknown:
            raise ValueError(f"cameras {unknown}: expected among {(VIDEO, *CAMERAS)}")
        self.cameras = tuple(cameras)
        self.seconds = dict.fromkeys(self.cameras, 0.0)  # spent per camera, in images()

    def _set_scene(self, state: np.ndarray) -> None:
        raise NotImplementedError

    def _picture(self, camera: str) -> np.ndarray:
        raise NotImplementedError

    def images(self, state: np.ndarray) -> dict[str, np.ndarray]:
        """Camera name -> (H, W, 3) uint8 RGB of the scene in ``state``; adds each camera's
        seconds (its picture, and its share of setting the scene) to ``seconds``."""
        t0 = time.perf_counter()
        self._set_scene(state)
        share = (time.perf_counter() - t0) / len(self.cameras)
        out = {}
        for name in self.cameras:
            t0 = time.perf_counter()
            out[name] = self._picture(name)
            self.seconds[name] += time.perf_counter() - t0 + share
        return out

    def frame(self, state: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 RGB of the scene in ``state`` from the first camera."""
        return self.images(state)[self.cameras[0]]
