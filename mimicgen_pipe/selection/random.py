"""``random``: every source demo equally likely (the paper's default)."""

from __future__ import annotations

import numpy as np


def select(
    candidate_object_poses: np.ndarray,
    current_object_pose: np.ndarray,
    rng: np.random.Generator,
    nn_k: int,
) -> int:
    """One draw, uniform over the N candidates."""
    return int(rng.integers(len(candidate_object_poses)))
