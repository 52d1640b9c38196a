"""Where the observation cameras (CAMERAS, named as robomimic names them) sit; every
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

# the observation cameras a back end may have, named as robomimic names them
CAMERAS = ("agentview", "eye_in_hand")

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
WRIST_LINK = "panda_hand"  # the link the wrist camera is mounted on, on every arm


def _opencv_rotation(forward: np.ndarray, up: np.ndarray) -> np.ndarray:
    """The rotation whose columns are a camera's OpenCV axes (x right, y down, z forward),
    for a camera looking along ``forward`` with ``up`` up in its image."""
    z = np.asarray(forward, np.float64) / np.linalg.norm(forward)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def intrinsics(fov_y: float, height: int, width: int) -> np.ndarray:
    """The 3x3 pinhole matrix K [px] of a camera of vertical field of view ``fov_y`` [rad]
    and square pixels, images ``height`` x ``width`` [px], its principal point at the image
    centre (pixel (u, v) covers [u, u + 1) x [v, v + 1); u right, v down)."""
    f = height / 2 / np.tan(fov_y / 2)
    return np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])


def camera_pose(camera: str) -> tuple[str, np.ndarray]:
    """(frame, 4x4 pose [m]) of ``camera`` of CAMERAS, its axes OpenCV's: ``agentview`` in
    the world frame (looking from AGENTVIEW_EYE at AGENTVIEW_TARGET, world z up in its
    image), ``eye_in_hand`` in the frame of WRIST_LINK (it moves with the hand)."""
    pose = np.eye(4)
    if camera == "agentview":
        eye, target = np.array(AGENTVIEW_EYE), np.array(AGENTVIEW_TARGET)
        pose[:3, :3] = _opencv_rotation(target - eye, np.array([0.0, 0.0, 1.0]))
        pose[:3, 3] = eye
        return "world", pose
    if camera == "eye_in_hand":
        pose[:3, :3] = _opencv_rotation(WRIST_FORWARD, WRIST_UP)
        pose[:3, 3] = WRIST_POS
        return WRIST_LINK, pose
    raise ValueError(f"camera {camera!r}: expected one of {CAMERAS}")


def calibration(camera: str, height: int, width: int) -> dict[str, object]:
    """``camera``'s calibration for images ``height`` x ``width`` [px], as plain lists
    (JSON): ``intrinsics`` (3x3 K [px]), ``fov_y`` [rad], ``frame`` (``world``, or the link
    it is mounted on), ``pose`` (4x4: the camera in ``frame`` [m], p_frame = pose @ p_camera)
    and ``axes`` (the camera frame's: OpenCV's)."""
    fov = AGENTVIEW_FOV if camera == "agentview" else WRIST_FOV
    frame, pose = camera_pose(camera)
    return {
        "intrinsics": intrinsics(fov, height, width).tolist(),
        "fov_y": float(fov),
        "frame": frame,
        "pose": pose.tolist(),
        "axes": "opencv: x right, y down, z forward",
    }


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
