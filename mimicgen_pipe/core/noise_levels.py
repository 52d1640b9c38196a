"""The pose-estimation noise levels of paper T by name (L1, L2), and the check of a level
that a params file gives (a name, or [position_mm, rotation_deg]); the noise itself is the
method's (mimicgen_pipe.method.pose_noise)."""

from __future__ import annotations

from typing import Any

# Named levels of paper T, as (position [mm], rotation [deg]).
NAMED_LEVELS: dict[str, tuple[float, float]] = {
    "none": (0.0, 0.0),
    "L1": (5.0, 5.0),
    "L2": (10.0, 10.0),
}
MAX_POSITION_MM = 1000.0  # noise beyond a metre says the level was given in the wrong unit
MAX_ROTATION_DEG = 180.0


def level_error(level: Any) -> str | None:
    """Why ``level`` is not a pose-noise level (None when it is): one of the names of
    NAMED_LEVELS, or a pair [position_mm, rotation_deg] of non-negative numbers."""
    expected = f"expected one of {', '.join(NAMED_LEVELS)} or [position_mm, rotation_deg]"
    if isinstance(level, str):
        return None if level in NAMED_LEVELS else f"{expected}, got {level!r}"
    if (
        isinstance(level, (list, tuple))
        and len(level) == 2
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in level)
    ):
        mm, deg = level
        if not (0 <= mm <= MAX_POSITION_MM and 0 <= deg <= MAX_ROTATION_DEG):
            return (
                f"expected position_mm in [0, {MAX_POSITION_MM:g}] and rotation_deg in "
                f"[0, {MAX_ROTATION_DEG:g}], got {list(level)!r}"
            )
        return None
    return f"{expected}, got {level!r}"
