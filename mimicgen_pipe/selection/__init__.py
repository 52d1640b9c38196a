"""Selection strategies (paper M.3): which source demo a generation attempt follows in a
subtask. One module per strategy, named as ``generate.selection`` names it
(mimicgen_pipe.registry), each defining

``select(candidate_object_poses, current_object_pose, rng, nn_k) -> int``: the index of the
source demo to follow. candidate_object_poses: (N, 4, 4) world pose [m] of the reference
object at the start of each source demo's segment; current_object_pose: (4, 4) its pose in
the new scene (world [m]); rng: the attempt's numpy Generator, the only source of
randomness; nn_k: ``generate.nn_k``, for strategies that draw among the closest demos.
"""
