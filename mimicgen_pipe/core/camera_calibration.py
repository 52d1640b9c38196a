"""Camera calibration as stores and exports carry it: per camera, its intrinsics and where it
sits. The back end computes it from where it renders the cameras
(mimicgen_pipe/core/cameras.py, handed over by ``mimicgen_pipe.backends.camera_calibration``);
the observe stage writes it into the observed store's attrs (``camera_calibration``) and the
exporters copy it into their formats. Nothing here imports a simulator.

A camera's calibration, as plain lists (JSON):

- ``intrinsics``: the 3x3 pinhole matrix K [px]: a point (x, y, z) of the camera frame
  (z > 0 in front) lands on the pixel (u, v) = (K @ p)[:2] / z, u to the right, v down,
  pixel (u, v) covering [u, u + 1) x [v, v + 1) of the image;
- ``fov_y``: the vertical field of view [rad] (K's focal length is H / 2 / tan(fov_y / 2));
- ``frame``: the frame ``pose`` is in: ``world`` for a fixed camera, or the robot link it is
  mounted on (``panda_hand`` for ``eye_in_hand``: it moves with the hand);
- ``pose``: 4x4 homogeneous, the camera frame in ``frame`` [m]: p_frame = pose @ p_camera
  (its inverse is the extrinsic matrix, frame to camera);
- ``axes``: the camera frame's axes, OpenCV's (x right, y down, z forward).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from mimicgen_pipe.core.errors import InputError

ATTR = "camera_calibration"  # the store attribute: camera -> calibration
AXES = "opencv: x right, y down, z forward"
KEYS = ("intrinsics", "fov_y", "frame", "pose", "axes")


def _matrix(value: Any, shape: tuple[int, int]) -> np.ndarray | None:
    try:
        m = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        return None
    return m if m.shape == shape and np.isfinite(m).all() else None


def _why_not(calib: Any, size: tuple[int, int]) -> tuple[str, str] | None:
    """(key, what it should be) for the first thing wrong with one camera's calibration of
    images ``size`` (height, width) [px], or None."""
    if not isinstance(calib, Mapping):
        return "", f"a mapping of {', '.join(KEYS)}"
    missing = [k for k in KEYS if k not in calib]
    if missing:
        return missing[0], "present"
    k = _matrix(calib["intrinsics"], (3, 3))
    h, w = size
    if k is None or not (k[0, 0] > 0 and k[1, 1] > 0) or not np.allclose(k[2], [0, 0, 1]):
        return "intrinsics", "a 3x3 matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], fx, fy > 0"
    fov = calib["fov_y"]
    if not isinstance(fov, (int, float)) or not np.isclose(k[1, 1], h / 2 / np.tan(fov / 2)):
        return "fov_y", f"the vertical field of view [rad] of K's fy {k[1, 1]:.4g} at height {h}"
    if not isinstance(calib["frame"], str) or not calib["frame"]:
        return "frame", "the name of the frame pose is in"
    pose = _matrix(calib["pose"], (4, 4))
    rotation_ok = pose is not None and np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3))
    if not rotation_ok or not np.allclose(pose[3], [0, 0, 0, 1]):
        return "pose", "a 4x4 homogeneous transform with a rotation"
    if calib["axes"] != AXES:
        return "axes", repr(AXES)
    return None


def store_calibration(attrs: Mapping[str, Any], where: str) -> dict[str, dict[str, Any]]:
    """Camera -> calibration of a store with images (its attrs ``camera_calibration``), for
    every camera of its attrs ``cameras``, checked; empty for a store without it (observed
    before calibration was recorded) or without images. InputError naming ``where`` (the
    store) and the key for one that is wrong."""
    calibs = attrs.get(ATTR)
    if calibs is None:
        return {}
    cameras = {c: (int(v["height"]), int(v["width"])) for c, v in attrs["cameras"].items()}
    if not isinstance(calibs, Mapping) or set(calibs) != set(cameras):
        have = sorted(calibs) if isinstance(calibs, Mapping) else type(calibs).__name__
        raise InputError(
            f"{where}: attrs {ATTR} has {have}, expected one entry per camera {list(cameras)}"
        )
    for camera, size in cameras.items():
        wrong = _why_not(calibs[camera], size)
        if wrong is not None:
            key = f"{ATTR}.{camera}" + (f".{wrong[0]}" if wrong[0] else "")
            raise InputError(f"{where}: attrs {key}: expected {wrong[1]}")
    return {c: dict(calibs[c]) for c in cameras}


def project(calib: Mapping[str, Any], points: np.ndarray) -> np.ndarray:
    """(N, 2) pixel coordinates (u right, v down) of (N, 3) points given in the camera's
    ``frame`` [m] (for a hand-mounted camera: in the hand link's frame); NaN for a point
    behind the camera."""
    pose = np.asarray(calib["pose"], np.float64)
    k = np.asarray(calib["intrinsics"], np.float64)
    p = np.asarray(points, np.float64).reshape(-1, 3)
    camera = (p - pose[:3, 3]) @ pose[:3, :3]  # inverse pose: rotation transposed
    pix = camera @ k.T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = pix[:, :2] / pix[:, 2:]
    uv[camera[:, 2] <= 0] = np.nan
    return uv
