"""Parsing source demos into object-centric subtask segments (paper 3.1, J.2)."""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.taskspec import SubtaskSpec, TaskSpec
from mimicgen_pipe.core.yamlfile import load_yaml, read_text


def first_rise(signal: np.ndarray, after: int) -> int | None:
    """The first step t > ``after`` at which ``signal`` (T,) turns from 0 to 1, or None."""
    s = np.asarray(signal, dtype=bool)
    rises = np.flatnonzero(~s[:-1] & s[1:]) + 1
    rises = rises[rises > after]
    return int(rises[0]) if rises.size else None


def subtask_at_steps(
    signals: Mapping[str, np.ndarray], subtasks: Sequence[SubtaskSpec], length: int
) -> np.ndarray:
    """(length,) int64: the subtask each step belongs to, as the generator walks them: subtask i
    ends at the first rise of its term signal after subtask i-1 ended (an episode that fails
    stays in the subtask whose signal never rose)."""
    out = np.zeros(length, np.int64)
    end: int | None = 0
    for i, sub in enumerate(subtasks[:-1]):
        key = f"subtask_signals/{sub.term_signal}"
        end = first_rise(signals[key], end) if key in signals else None
        if end is None:
            break
        out[end:] = i + 1
    return out


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
        end = first_rise(signals[sub.term_signal], prev)
        if end is None:
            raise ValueError(
                f"subtask {sub.name}: signal {sub.term_signal!r} never turns on after step {prev}"
            )
        prev = end
        ends.append(prev)
    return np.asarray(ends, dtype=np.int64)


def subtask_ends(signals: Mapping[str, np.ndarray], spec: TaskSpec) -> np.ndarray:
    """(K,) int64: the detected end of every subtask with a term signal in one demo, in the
    task's order (TaskSpec.ending_subtasks): each arm's subtasks split by its own signals
    (:func:`split_into_segments`; its ValueError names the subtask)."""
    ends = np.zeros(len(spec.ending_subtasks), dtype=np.int64)
    for arm in spec.arms:
        ends[spec.term_columns(arm)] = split_into_segments(signals, spec.arm_subtasks(arm))
    return ends


def check_subtask_ends(ends: np.ndarray, length: int, spec: TaskSpec) -> str | None:
    """Why the subtask ends ``ends`` (K,) (as :func:`subtask_ends` gives them) of one demo of
    ``length`` steps are unusable, for each arm (:func:`validate_segments`); None if
    usable."""
    for arm in spec.arms:
        cols = spec.term_columns(arm)
        why = validate_segments(np.asarray(ends)[cols], length, spec.arm_subtasks(arm))
        if why:
            return why if len(spec.arms) == 1 else f"arm {arm}: {why}"
    return None


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


def gripper_events(gripper: np.ndarray) -> list[tuple[int, str]]:
    """(step, "close" | "open") wherever the gripper action changes sign: the step whose
    action first closes (< 0) or opens (> 0) the gripper. Candidate subtask ends for a person
    annotating demos without term signals (a grasp ends at a close, a placement at an open)."""
    g = np.sign(np.asarray(gripper, np.float64))
    return [
        (int(t), "close" if g[t] < 0 else "open")
        for t in range(1, len(g))
        if g[t] != 0 and g[t] != g[t - 1]
    ]


def read_boundaries(
    path: Path, lengths: Sequence[int], subtasks: Sequence[SubtaskSpec]
) -> np.ndarray:
    """Manual subtask annotation: (N, M-1) int64, the end step of every subtask but the last
    for each of the N demos, from a YAML file (``<demo index>: [end, ...]``) or a CSV file
    (header ``demo,<subtask>,...``, one row per demo). An end is the first step of the next
    subtask, as split_into_segments returns. Raises InputError naming the file, the demo and
    the subtask whose end is missing, not an integer, out of range (1 .. length-1) or out of
    order; a demo given twice; or a file that is not UTF-8 text, valid YAML or CSV."""
    path = Path(path)
    names = [s.name for s in subtasks[:-1]]
    if path.suffix.lower() == ".csv":
        raw = _read_boundaries_csv(path, names)
    else:
        raw = load_yaml(path, "boundaries file")
        if raw is None:  # an empty file: every demo is reported missing below
            raw = {}
        if not isinstance(raw, dict):
            raise InputError(
                f"{path}: expected a mapping of demo index -> list of ends, got "
                f"{type(raw).__name__} {str(raw)[:40]!r}"
            )
    for demo in raw:
        # YAML reads ``true:`` as a boolean and ``0.0:`` as a float, both equal to an index
        if isinstance(demo, bool) or not isinstance(demo, int) or demo < 0:
            raise InputError(f"{path}: key {demo!r}: expected a demo index (an integer >= 0)")
    out = np.zeros((len(lengths), len(names)), np.int64)
    for demo, length in enumerate(lengths):
        ends = raw.get(demo)
        if ends is None:
            raise InputError(f"{path}: demo {demo}: no boundaries (every demo needs a line)")
        ends = ends if isinstance(ends, list) else [ends]
        if len(ends) < len(names):
            raise InputError(f"{path}: demo {demo}: no end for subtask {names[len(ends)]!r}")
        if len(ends) > len(names):
            raise InputError(
                f"{path}: demo {demo}: {len(ends)} ends, expected {len(names)} ({names})"
            )
        prev = 0
        for name, end in zip(names, ends, strict=True):
            # a step is an integer (``true`` is an int to Python, not a step; 3.0 is refused)
            if isinstance(end, bool) or not isinstance(end, int) or not 0 < end < length:
                raise InputError(
                    f"{path}: demo {demo}: subtask {name!r} ends at {end!r}, expected a step "
                    f"in 1..{length - 1} (an integer; the demo has {length} steps)"
                )
            if end <= prev:
                raise InputError(
                    f"{path}: demo {demo}: subtask {name!r} ends at {end}, not after the "
                    f"previous end {prev}"
                )
            prev = end
        out[demo] = ends
    extra = sorted(set(raw) - set(range(len(lengths))))
    if extra:
        raise InputError(f"{path}: demos {extra} are not in the store ({len(lengths)} demos)")
    return out


def _read_boundaries_csv(path: Path, names: list[str]) -> dict[int, list[int]]:
    """A boundaries CSV as demo index -> ends, its rows checked for integers and for a demo
    given twice (InputError naming the file and the line)."""
    text = read_text(path, "boundaries file (CSV)")
    try:
        rows = [(n, row) for n, row in enumerate(csv.reader(text.splitlines()), 1) if row]
    except csv.Error as exc:  # e.g. a NUL byte: a binary file given as the CSV
        raise InputError(f"{path}: not a readable CSV file ({exc})") from exc
    if not rows or rows[0][1][:1] != ["demo"]:
        raise InputError(f"{path}: expected a header 'demo,{','.join(names)}'")
    header = rows[0][1][1:]
    if header != names:
        raise InputError(f"{path}: columns {header}, expected {names} (subtask order)")
    raw: dict[int, list[int]] = {}
    first_line: dict[int, int] = {}
    for line, row in rows[1:]:
        try:
            demo, ends = int(row[0]), [int(v) for v in row[1:]]
        except ValueError as exc:
            raise InputError(f"{path}: line {line}: expected integers, got {row}") from exc
        if demo in raw:
            raise InputError(
                f"{path}: demo {demo} given twice (lines {first_line[demo]} and {line})"
            )
        raw[demo], first_line[demo] = ends, line
    return raw
