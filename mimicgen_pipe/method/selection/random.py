"""``random``: every source demo equally likely (the paper's default)."""

from __future__ import annotations

import numpy as np

from mimicgen_pipe.method.selection import Candidates


def select(candidates: Candidates, rng: np.random.Generator, nn_k: int) -> int:
    """One draw, uniform over the N candidates."""
    return int(rng.integers(len(candidates.object_poses)))
