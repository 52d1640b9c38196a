"""``nearest_neighbor``: one of the source demos whose reference object started closest to
where it is in the new scene."""

from __future__ import annotations

import numpy as np

from mimicgen_pipe.method.generation import draw_nearest, pose_distance
from mimicgen_pipe.method.selection import Candidates


def select(candidates: Candidates, rng: np.random.Generator, nn_k: int) -> int:
    """Candidates ranked by pose_distance from their reference object's pose to its pose now
    (ties in index order), then one draw, uniform over the first ``nn_k``."""
    return draw_nearest(pose_distance(candidates.object_poses, candidates.object_pose), rng, nn_k)
