"""``nearest_neighbor``: one of the source demos whose reference object started closest to
where it is in the new scene."""

from __future__ import annotations

import numpy as np

from mimicgen_pipe.generation import pose_distance


def select(
    candidate_object_poses: np.ndarray,
    current_object_pose: np.ndarray,
    rng: np.random.Generator,
    nn_k: int,
) -> int:
    """Candidates ranked by pose_distance to the current pose (ties in index order), then
    one draw, uniform over the first ``nn_k``."""
    order = np.argsort(pose_distance(candidate_object_poses, current_object_pose), kind="stable")
    return int(order[rng.integers(min(nn_k, len(candidate_object_poses)))])
