"""Parsing source demos into object-centric subtask segments (paper 3.1): the parse stage's
job, the parsed store it writes, and the candidate subtask ends the boundaries stage prints
for demos recorded without term signals. Each stage resolves its job, its source store
read and every demo's subtask ends checked, before anything is written
(mimicgen_pipe.stages.parse, mimicgen_pipe.stages.boundaries)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mimicgen_pipe.core.taskspec import TaskSpec
from mimicgen_pipe.data.store import EpisodeStore, write_store
from mimicgen_pipe.method.segments import gripper_events


@dataclass(frozen=True)
class ParseJob:
    """One parse run, checked: the source demos of the store at ``source`` (``store``, read
    whole), split into the subtasks of ``spec`` at ``term_index``, (N_demos, K) int64, the
    end step of each subtask that ends (TaskSpec.ending_subtasks) of every demo, found from
    its term signals or read from the manual annotation at ``boundaries`` (None: the
    signals); written as the parsed store ``out``."""

    source: Path
    boundaries: Path | None
    out: Path
    spec: TaskSpec
    store: EpisodeStore
    term_index: np.ndarray


def write_parsed(job: ParseJob) -> None:
    """The parsed store: the source store's steps, episodes and attributes, with every
    demo's subtask ends (meta/episodes/subtask_term_index) and the task's subtasks, each with
    its reference object, term signal and term offset range (and its arm, on a task of
    several arms)."""
    store, spec = job.store, job.spec
    steps = [store.episode(i) for i in range(store.n_episodes)]
    episodes = dict(store.episodes)
    episodes["subtask_term_index"] = job.term_index
    attrs = dict(store.attrs)
    attrs["subtasks"] = [
        {
            "name": s.name,
            "reference_object": s.reference_object,
            "term_signal": s.term_signal,
            "term_offset_range": list(s.term_offset_range),
        }
        | ({"arm": s.arm} if len(spec.arms) > 1 else {})
        for s in spec.subtasks
    ]
    write_store(job.out, "parsed", steps, episodes, attrs)


@dataclass(frozen=True)
class BoundariesJob:
    """The source demos of the store at ``source`` (``store``, read with its gripper
    actions), whose candidate ends of the subtasks ``ending`` (each but the last, in order)
    the boundaries stage prints."""

    source: Path
    store: EpisodeStore
    ending: tuple[str, ...]


def boundary_candidates(job: BoundariesJob) -> list[str]:
    """The lines of a boundaries file to start from (YAML, ``<demo>: [end, ...]``): comments
    listing each demo's gripper events (close, open: segments.gripper_events), and as its
    proposed ends the first events, one per subtask that ends."""
    store = job.store
    lines = [
        f"# {job.source}: {store.n_episodes} demos; subtasks ending here: {', '.join(job.ending)}",
        "# candidates: steps where the gripper action closes or opens; an end is the first",
        "# step of the next subtask. Proposed ends: the first events, one per subtask.",
    ]
    for i in range(store.n_episodes):
        ep = store.episode(i)
        events = gripper_events(ep["gripper"])
        described = ", ".join(f"{kind} at {t}" for t, kind in events) or "none"
        proposal = [t for t, _ in events[: len(job.ending)]]
        lines.append(f"# demo {i} ({len(ep['gripper'])} steps): {described}")
        lines.append(f"{i}: {proposal}")
    return lines
