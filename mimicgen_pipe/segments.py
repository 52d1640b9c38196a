"""Parsing source demos into object-centric subtask segments (paper 3.1, J.2)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from mimicgen_pipe.taskspec import SubtaskSpec


def split_into_segments(
    signals: Mapping[str, np.ndarray], subtasks: Sequence[SubtaskSpec]
) -> np.ndarray:
    """Detected end of every non-final subtask in one demo.

    signals: name -> (T,) bool, the signal observed before each step's action.
    Returns (M-1,) int64: for subtask i, the first step t > end of subtask i-1 at which its
    term signal turns from 0 to 1 (the segment's actions are [previous end, t)). Raises
    ValueError naming the subtask when a signal is missing or never rises in order.
    """
    ends: list[int] = []
    prev = 0
    for sub in subtasks[:-1]:
        if sub.term_signal not in signals:
            raise ValueError(f"subtask {sub.name}: no signal {sub.term_signal!r}")
        s = np.asarray(signals[sub.term_signal], dtype=bool)
        rises = np.flatnonzero(~s[:-1] & s[1:]) + 1
        rises = rises[rises > prev]
        if rises.size == 0:
            raise ValueError(
                f"subtask {sub.name}: signal {sub.term_signal!r} never turns on after step {prev}"
            )
        prev = int(rises[0])
        ends.append(prev)
    return np.asarray(ends, dtype=np.int64)


def segment_bounds(term_index: np.ndarray, offsets: Sequence[int], length: int) -> np.ndarray:
    """(M, 2) [start, end) step ranges of the M segments of one demo of ``length`` steps,
    with ``offsets`` (M-1,) added to the detected subtask ends ``term_index`` (M-1,)."""
    ends = np.minimum(np.asarray(term_index) + np.asarray(offsets, dtype=np.int64), length - 1)
    ends = np.concatenate([ends, [length]])
    starts = np.concatenate([[0], ends[:-1]])
    return np.stack([starts, ends], -1).astype(np.int64)


def validate_segments(
    term_index: np.ndarray, length: int, subtasks: Sequence[SubtaskSpec]
) -> str | None:
    """Why the boundaries of one demo are unusable for some offset in range, or None if usable:
    every segment must be non-empty and ordered for the largest offsets."""
    max_off = [s.term_offset_range[1] for s in subtasks[:-1]]
    ends = np.asarray(term_index) + np.asarray(max_off, dtype=np.int64)
    if np.any(np.diff(term_index) <= 0):
        return f"subtask ends {term_index.tolist()} are not strictly increasing"
    for i in range(len(ends)):
        nxt = term_index[i + 1] if i + 1 < len(term_index) else length
        if ends[i] >= nxt:
            return (
                f"subtask {subtasks[i].name}: end {term_index[i]} + offset {max_off[i]} reaches "
                f"the next boundary {nxt}"
            )
    return None
