"""Selection strategies (paper M.3): which source demo a generation attempt follows in a
subtask. One module per strategy, named as ``generate.selection`` names it
(mimicgen_pipe.core.registry), each defining

``select(candidates: Candidates, rng, nn_k) -> int``: the index of the source demo to follow.
rng: the attempt's numpy Generator, the only source of randomness; nn_k: ``generate.nn_k``,
for strategies that draw among the closest demos.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Candidates:
    """What a strategy knows of the N source demos' segments for one subtask and of the new
    scene. All poses are 4x4 homogeneous transforms, world frame [m].

    object_poses: (N, 4, 4) the reference object at the start of each source demo's segment.
    object_pose: (4, 4) the reference object in the new scene (as the pose estimator reports
    it). first_targets: (N, 4, 4) each segment's first target pose carried to the new scene
    (paper L), where the arm has to go before the segment starts. eef_pose: (4, 4) the end
    effector in the new scene now.
    """

    object_poses: np.ndarray
    object_pose: np.ndarray
    first_targets: np.ndarray
    eef_pose: np.ndarray
