"""Drawing a scene from a reset variant (taskspec.ResetVariant, paper D0/D1/D2): every
object's initial planar pose, for every back end.

The back end supplies the random stream (``uniform``) and the draw order; the arithmetic is
done here in the dtype of its draws, so that a back end gets the same scenes from the same
seeds whatever calls this.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Literal

import numpy as np

from mimicgen_pipe.core.taskspec import ResetVariant

# (shape) -> uniform draws in [0, 1) of that shape, the next ones of the back end's stream
Uniform = Callable[[tuple[int, ...]], np.ndarray]
DrawOrder = Literal["positions_then_yaws", "object_by_object"]
MAX_REDRAWS = 1000  # per object; the accepted area is most of each box


def _distance(d: np.ndarray) -> np.ndarray:
    """(n, 2) -> (n,) Euclidean norms, rounded as a fused multiply-add chain (dx^2 rounded,
    dy^2 added to it with one rounding), the way torch's and BLAS's vector norms compute a
    2-vector: float32 through float64, where each step is exact before its rounding; float64
    through BLAS (matmul)."""
    if d.dtype == np.float32:
        dx2 = (d[:, 0] * d[:, 0]).astype(np.float64)
        dy = d[:, 1].astype(np.float64)
        return np.sqrt((dy * dy + dx2).astype(np.float32))
    return np.sqrt((d[:, None, :] @ d[:, :, None])[:, 0, 0])


def sample_planar_poses(
    variant: ResetVariant,
    objects: Sequence[str],
    base_xy: tuple[float, float],
    uniform: Uniform,
    n: int = 1,
    draw_order: DrawOrder = "positions_then_yaws",
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Initial planar poses of ``objects`` for ``n`` scenes drawn from ``variant``: per
    object, (n, 2) world x, y [m] and (n,) yaw [rad] about world z, in the dtype of
    ``uniform``'s draws.

    Objects are drawn in order, x, y uniform in the object's bounds; a scene's position is
    redrawn (up to MAX_REDRAWS times) while it is farther than ``variant.max_reach``
    horizontally from the robot base at ``base_xy`` (world [m]) or closer than
    ``variant.min_distance`` to an object drawn before it. Yaw is uniform in its bounds (a
    full turn exactly ``u * 2 pi``). draw_order: "positions_then_yaws" draws every object's
    position, then every yaw; "object_by_object" each object's yaw right after its
    position. A native variant is the simulator's own reset and has nothing to draw here.
    """
    if variant.native:
        raise ValueError("a native reset variant is drawn by the simulator's own reset")
    xys: list[np.ndarray] = []
    yaws: list[np.ndarray] = []

    def draw_yaw(name: str) -> None:
        b = variant.bounds[name]
        u = uniform((n,))
        t = u.dtype.type
        turns = (b.yaw[1] - b.yaw[0]) / (2 * math.pi)
        yaws.append(t(b.yaw[0]) + u * t(2) * t(math.pi) * t(turns))

    for name in objects:
        b = variant.bounds[name]
        xy = uniform((n, 2))
        t = xy.dtype.type
        lo = np.array([b.x[0], b.y[0]], xy.dtype)
        span = np.array([b.x[1] - b.x[0], b.y[1] - b.y[0]], xy.dtype)
        base = np.array(base_xy, xy.dtype)
        xy = lo + xy * span
        for _ in range(MAX_REDRAWS):
            bad = np.zeros(n, bool)
            if variant.max_reach is not None:
                bad |= _distance(xy - base) > t(variant.max_reach)
            for other in xys:
                bad |= _distance(xy - other) < t(variant.min_distance)
            if not bad.any():
                break
            xy[bad] = lo + uniform((int(bad.sum()), 2)) * span
        else:
            raise RuntimeError(f"reset: no room for {name} in {MAX_REDRAWS} draws")
        xys.append(xy)
        if draw_order == "object_by_object":
            draw_yaw(name)
    if draw_order == "positions_then_yaws":
        for name in objects:
            draw_yaw(name)
    return xys, yaws
