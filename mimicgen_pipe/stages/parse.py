"""parse: split every source demo into object-centric subtask segments."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.taskspec import TaskSpec, arm_key
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.outputs import claim, store_kind
from mimicgen_pipe.data.store import EpisodeStore, read_store
from mimicgen_pipe.method.segments import check_subtask_ends, read_boundaries, subtask_ends
from mimicgen_pipe.run.parsing import ParseJob, write_parsed
from mimicgen_pipe.stages import add_selection_arguments, output_path, stage_params


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument("--source", help="source store (default: data/source/<task>.zarr)")
    p.add_argument("--out", help="parsed store (default: data/parsed/<task>.zarr)")
    p.add_argument(
        "--boundaries",
        help="manual annotation instead of term signals: a YAML (<demo>: [end, ...]) or CSV "
        "file with the end step of every subtask but the last, per demo (see "
        "`mimicgen-pipe boundaries` for candidates)",
    )


def resolve(args: argparse.Namespace) -> ParseJob:
    """The parse run ``args`` ask for: the params, the source store read whole and every
    demo's subtask ends found and checked; writes nothing."""
    if args.boundaries == "":  # would fall back to the term signals without a word
        raise InputError("--boundaries: expected a file path, got ''")
    params = stage_params(args)
    spec = backends.task_spec(params.backend, params.task)
    if args.boundaries and len(spec.arms) > 1:
        raise InputError(f"--boundaries: a file of one arm's subtask ends; {spec.name} has arms "
                         f"{', '.join(spec.arms)} (each is split by its own signals)")  # fmt: skip
    src_path = Path(args.source or layout.source_store(params.task))
    out = output_path(args.out, layout.parsed_store(params.task))
    pose_keys = [arm_key(k, a) for k in ("eef_pose", "target_pose") for a in spec.arms]
    pose_keys += [f"object_poses/{o}" for o in spec.objects]
    sig_keys = [] if args.boundaries else [f"subtask_signals/{s}" for s in term_signals(spec)]
    store = read_store(
        src_path,
        required=["actions", *(arm_key("gripper", a) for a in spec.arms), *pose_keys, *sig_keys],
        task=params.task,
        kind="source",
    )
    term_index = subtask_term_index(store, spec, args.boundaries)
    boundaries = Path(args.boundaries) if args.boundaries else None
    return ParseJob(src_path, boundaries, out, spec, store, term_index)


def run(job: ParseJob) -> None:
    given = [job.source, *([job.boundaries] if job.boundaries else [])]
    claim((job.out, store_kind("parsed")), inputs=given)
    write_parsed(job)
    print(
        f"parse: {job.store.n_episodes} demos, subtask ends {job.term_index.tolist()}"
        f" of lengths {job.store.lengths.tolist()} -> {job.out}"
    )


def term_signals(spec: TaskSpec) -> list[str]:
    """The term signals that end ``spec``'s subtasks, sorted."""
    return sorted({s.term_signal for s in spec.subtasks if s.term_signal})


def subtask_term_index(store: EpisodeStore, spec: TaskSpec, boundaries: str | None) -> np.ndarray:
    """(N_demos, K) int64: the subtask ends of every demo of the source ``store``, from
    its term signals or the manual annotation in the file ``boundaries``; InputError naming
    the demo where they are unusable (segments.check_subtask_ends)."""
    if boundaries:
        annotated = read_boundaries(Path(boundaries), store.lengths.tolist(), spec.subtasks)
    signals = term_signals(spec)
    term_index = []
    for i in range(store.n_episodes):
        ep = store.episode(i)
        if boundaries:
            ends, where = annotated[i], f"{boundaries}: demo {i}"
        else:
            sig = {s: ep[f"subtask_signals/{s}"] for s in signals}
            try:
                ends = subtask_ends(sig, spec)
            except ValueError as exc:
                raise InputError(f"{store.path}: episode {i}: {exc}") from exc
            where = f"{store.path}: episode {i}"
        why = check_subtask_ends(ends, len(ep["actions"]), spec)
        if why:
            raise InputError(f"{where}: {why}")
        term_index.append(ends)
    return np.asarray(term_index, np.int64).reshape(store.n_episodes, -1)
