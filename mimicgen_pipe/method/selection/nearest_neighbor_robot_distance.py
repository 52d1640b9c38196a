"""``nearest_neighbor_robot_distance``: one of the source demos whose segment starts closest
to where the end effector is now, so that the transit to it is short (MimicGen's
``nearest_neighbor_robot_distance`` strategy)."""

from __future__ import annotations

import numpy as np

from mimicgen_pipe.method.generation import draw_nearest, pose_distance
from mimicgen_pipe.method.selection import Candidates


def select(candidates: Candidates, rng: np.random.Generator, nn_k: int) -> int:
    """Candidates ranked by pose_distance from their segment's first target pose, carried to
    the new scene, to the end effector's pose now (ties in index order), then one draw,
    uniform over the first ``nn_k``."""
    return draw_nearest(pose_distance(candidates.first_targets, candidates.eef_pose), rng, nn_k)
