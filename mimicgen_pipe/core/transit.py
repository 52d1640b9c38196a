"""Planned transit (generate.transit: planned): instead of the straight interpolation of paper
M.2, the arm moves to each subtask's segment along a collision-free path that a motion planner
finds among the scene's objects as they are at that moment.

MimicGen's segment of a subtask carries the source demo's whole motion since the previous
subtask ended, free-space part included, moved with the reference object; around an obstacle
that did not move with it, that part collides. With planned transit the segment starts at
its approach: its first target within ``approach_distance`` of the reference object; the
planner brings the arm there, and the rest of the segment runs as MimicGen runs it.

The search here is plain numpy: RRT-Connect in joint space, then random shortcuts, then one
point per control step; a back end supplies the collision check and the kinematics
(mimicgen_pipe/backends/maniskill/planner.py). Everything random comes from the attempt's generator,
so the same seed gives the same path.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

TRANSITS = ("linear", "planned")
CHECK_RESOLUTION = 0.02  # [rad] largest joint move between two collision checks on an edge
EXTEND_STEP = 0.3  # [rad] largest joint move of one RRT extension


@dataclass(frozen=True)
class PlannerSettings:
    """The planner's knobs (params.yaml generate.planner).

    approach_distance [m]: a segment starts at its first target this close to the reference
    object (the whole segment when none is). clearance [m]: how far the arm and what it holds
    keep from obstacles (every object but the table and those subtasks refer to), for the
    controller's tracking error. max_joint_step [rad]: the largest move of any
    joint in one control step along the planned path. max_iterations: RRT-Connect extensions
    before the planner gives up. shortcuts: random shortcut tries on the path found. ik_tries:
    IK starts (the arm's joints now, then random ones) for the approach's joint positions.
    """

    approach_distance: float = 0.1
    clearance: float = 0.02
    max_joint_step: float = 0.02
    max_iterations: int = 2000
    shortcuts: int = 50
    ik_tries: int = 20


def approach_start(targets: np.ndarray, reference_pose: np.ndarray, distance: float) -> int:
    """Index of a transformed segment's first target (``targets`` (K, 4, 4), world) whose
    position is within ``distance`` [m] of the reference object's (``reference_pose``, world),
    or 0 when none is."""
    near = np.linalg.norm(targets[:, :3, 3] - reference_pose[:3, 3], axis=-1) <= distance
    return int(np.argmax(near)) if near.any() else 0


def _edge_free(a: np.ndarray, b: np.ndarray, free: Callable[[np.ndarray], bool]) -> bool:
    """Whether every point of the straight joint-space edge a -> b, ``b`` included, is free
    (checked every CHECK_RESOLUTION rad)."""
    n = int(np.ceil(np.abs(b - a).max() / CHECK_RESOLUTION))
    return all(free(a + (b - a) * (k / n)) for k in range(1, n + 1))


def _steer(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = np.abs(b - a).max()
    return b if d <= EXTEND_STEP else a + (b - a) * (EXTEND_STEP / d)


def _rrt_connect(
    start: np.ndarray,
    goal: np.ndarray,
    free: Callable[[np.ndarray], bool],
    rng: np.random.Generator,
    lower: np.ndarray,
    upper: np.ndarray,
    iterations: int,
) -> list[np.ndarray] | None:
    """Waypoints start ... goal of a free path, or None after ``iterations`` extensions."""
    trees = [([start], [-1]), ([goal], [-1])]  # (nodes, parent index) from start / goal

    def extend(tree, q) -> int | None:
        nodes, parents = tree
        near = int(np.argmin([np.abs(n - q).max() for n in nodes]))
        new = _steer(nodes[near], q)
        if not _edge_free(nodes[near], new, free):
            return None
        nodes.append(new)
        parents.append(near)
        return len(nodes) - 1

    def branch(tree, i) -> list[np.ndarray]:
        nodes, parents = tree
        out = []
        while i >= 0:
            out.append(nodes[i])
            i = parents[i]
        return out  # from node i back to the root

    for it in range(iterations):
        grow, other = (trees[0], trees[1]) if it % 2 == 0 else (trees[1], trees[0])
        i = extend(grow, rng.uniform(lower, upper))
        if i is None:
            continue
        target = grow[0][i]
        while (j := extend(other, target)) is not None:  # connect: grow the other tree to it
            if np.array_equal(other[0][j], target):
                a, b = branch(grow, i), branch(other, j)
                path = a[::-1] + b[1:] if grow is trees[0] else b[::-1] + a[1:]
                return path
    return None


def _shortcut(
    path: list[np.ndarray], free: Callable[[np.ndarray], bool], rng: np.random.Generator, tries: int
) -> list[np.ndarray]:
    """``path`` with random shortcuts: two points drawn anywhere on it (on two different
    edges), joined straight where that edge is free."""
    for _ in range(tries):
        if len(path) < 3:
            break
        i, j = sorted(rng.choice(len(path) - 1, 2, replace=False))
        s, t = rng.uniform(size=2)
        a = path[i] + (path[i + 1] - path[i]) * s  # on edge i
        b = path[j] + (path[j + 1] - path[j]) * t  # on edge j > i
        if _edge_free(a, b, free):
            path = path[: i + 1] + [a, b] + path[j + 1 :]
    return path


def densify(waypoints: list[np.ndarray], max_step: float) -> np.ndarray:
    """(K, dof): the path through ``waypoints`` with no joint moving more than ``max_step``
    between two points; the first waypoint left out, the last one included."""
    out = []
    for a, b in zip(waypoints[:-1], waypoints[1:], strict=True):
        n = max(1, int(np.ceil(np.abs(b - a).max() / max_step)))
        out += [a + (b - a) * (k / n) for k in range(1, n + 1)]
    return np.asarray(out)


def joint_path(
    start: np.ndarray,
    goal: np.ndarray,
    free: Callable[[np.ndarray], bool],
    settings: PlannerSettings,
    rng: np.random.Generator,
    lower: np.ndarray,
    upper: np.ndarray,
) -> np.ndarray | None:
    """(K, dof) joint positions, one per control step, from ``start`` (left out) to ``goal``
    (included) through configurations where ``free`` holds, inside [lower, upper]; None when
    RRT-Connect finds no path within settings.max_iterations. The straight edge is taken when
    it is free."""
    if _edge_free(start, goal, free):
        waypoints = [start, goal]
    else:
        found = _rrt_connect(start, goal, free, rng, lower, upper, settings.max_iterations)
        if found is None:
            return None
        waypoints = _shortcut(found, free, rng, settings.shortcuts)
    return densify(waypoints, settings.max_joint_step)
