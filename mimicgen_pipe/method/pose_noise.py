"""Pose-estimation error (paper T): uniform noise on the object poses the generator observes.

The paper adds two levels of uniform noise to the object poses, in the source demonstrations
and in each new scene: L1 is 5 mm position and 5 deg rotation noise, L2 10 mm and 10 deg.
Here a level bounds the noise:

- position: each world axis (x, y, z) is offset by an independent draw from U[-p, p];
- rotation: the pose is turned about a uniformly random axis through the object's origin by
  an angle drawn from U[-r, r], so the rotation error never exceeds r.

The simulator's true poses are never changed; only what the generator sees is.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mimicgen_pipe.core import poses
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.noise_levels import NAMED_LEVELS, level_error

# Generation draws its pose noise from its own stream of each attempt's seed, so that turning
# the noise on leaves every other draw (offsets, selection, action noise) of the attempt as it
# was: runs at different levels see the same scenes and are compared pair by pair.
GENERATION_STREAM = 0x9053


@dataclass(frozen=True)
class PoseNoise:
    """Bounds of the uniform pose noise. position: [m] per world axis. rotation: [rad] of the
    rotation angle about a uniformly random axis."""

    position: float = 0.0
    rotation: float = 0.0

    @property
    def is_zero(self) -> bool:
        return self.position == 0.0 and self.rotation == 0.0

    def describe(self) -> str:
        """The level in the paper's units, e.g. '5 mm / 5 deg'."""
        return f"{1000 * self.position:g} mm / {math.degrees(self.rotation):g} deg"


def pose_noise_level(level: str | Sequence[float]) -> PoseNoise:
    """The noise bounds of a level: a name of NAMED_LEVELS or [position_mm, rotation_deg].
    Raises ValueError for anything else."""
    why = level_error(level)
    if why:
        raise ValueError(why)
    mm, deg = NAMED_LEVELS[level] if isinstance(level, str) else level
    return PoseNoise(position=float(mm) / 1000.0, rotation=math.radians(float(deg)))


def perturb_pose(pose: np.ndarray, noise: PoseNoise, rng: np.random.Generator) -> np.ndarray:
    """``pose`` (..., 4, 4) world frame with independent uniform noise on each pose (see the
    module docstring); a zero level returns an unchanged copy without drawing from ``rng``."""
    pose = np.array(pose, dtype=np.float64, copy=True)
    if noise.is_zero:
        return pose
    batch = pose.shape[:-2]
    dpos = rng.uniform(-noise.position, noise.position, batch + (3,))
    axis = rng.standard_normal(batch + (3,))
    axis /= np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True), 1e-12)
    angle = rng.uniform(-noise.rotation, noise.rotation, batch + (1,))
    # turning about the object's own origin: R' = dR R, p' = p + dp (world frame)
    pose[..., :3, :3] = poses.axis_angle_to_matrix(axis * angle) @ pose[..., :3, :3]
    pose[..., :3, 3] += dpos
    return pose


def generation_rng(attempt_seed: int) -> np.random.Generator:
    """The pose-noise stream of one generation attempt (see GENERATION_STREAM)."""
    return np.random.default_rng([int(attempt_seed), GENERATION_STREAM])


def store_attrs(level: str | Sequence[float], noise: PoseNoise, seed: int) -> dict[str, Any]:
    """What a pose-noised store records about its noise (attrs["pose_noise"])."""
    return {
        "level": level if isinstance(level, str) else list(level),
        "position_m": noise.position,
        "rotation_deg": math.degrees(noise.rotation),
        "seed": int(seed),
    }


def check_store_noise(
    attrs: Mapping[str, Any], noise: PoseNoise, seed: int, path: str | Path
) -> None:
    """Source demos and new scenes must carry the same pose-noise level (paper T). A store
    without attrs["pose_noise"] is a clean parsed store (level none). Raises InputError
    naming the store when its level or seed differs from the params'."""
    recorded = attrs.get("pose_noise")
    if recorded is None:
        if noise.is_zero:
            return
        raise InputError(
            f"{path}: source demos carry no pose noise but pose_noise.level is "
            f"{noise.describe()}; generate from the pose_noise stage's output"
        )
    stored = PoseNoise(recorded["position_m"], math.radians(recorded["rotation_deg"]))
    same_level = math.isclose(stored.position, noise.position, abs_tol=1e-12) and math.isclose(
        stored.rotation, noise.rotation, abs_tol=1e-12
    )
    if not same_level or (not noise.is_zero and int(recorded["seed"]) != int(seed)):
        raise InputError(
            f"{path}: source demos carry pose noise {stored.describe()} (seed "
            f"{recorded['seed']}), params ask for {noise.describe()} (pose_noise.seed {seed}); "
            "re-run the pose_noise stage"
        )
