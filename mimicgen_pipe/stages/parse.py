"""parse: split every source demo into object-centric subtask segments."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.taskspec import arm_key
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.outputs import claim, store_kind
from mimicgen_pipe.data.store import read_store, write_store
from mimicgen_pipe.method.segments import check_subtask_ends, read_boundaries, subtask_ends
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


def run(args: argparse.Namespace) -> None:
    if args.boundaries == "":  # would fall back to the term signals without a word
        raise InputError("--boundaries: expected a file path, got ''")
    params = stage_params(args)
    spec = backends.task_spec(params.backend, params.task)
    if args.boundaries and len(spec.arms) > 1:
        raise InputError(f"--boundaries: a file of one arm's subtask ends; {spec.name} has arms "
                         f"{', '.join(spec.arms)} (each is split by its own signals)")  # fmt: skip
    src_path = Path(args.source or layout.source_store(params.task))
    out = output_path(args.out, layout.parsed_store(params.task))
    signals = sorted({s.term_signal for s in spec.subtasks if s.term_signal})
    pose_keys = [arm_key(k, a) for k in ("eef_pose", "target_pose") for a in spec.arms]
    pose_keys += [f"object_poses/{o}" for o in spec.objects]
    sig_keys = [] if args.boundaries else [f"subtask_signals/{s}" for s in signals]
    given = [src_path, *([args.boundaries] if args.boundaries else [])]
    claim((out, store_kind("parsed")), inputs=given)
    store = read_store(
        src_path,
        required=["actions", *(arm_key("gripper", a) for a in spec.arms), *pose_keys, *sig_keys],
        task=params.task,
        kind="source",
    )
    lengths = store.lengths
    if args.boundaries:
        annotated = read_boundaries(Path(args.boundaries), lengths.tolist(), spec.subtasks)
    term_index = []
    for i in range(store.n_episodes):
        ep = store.episode(i)
        if args.boundaries:
            ends, where = annotated[i], f"{args.boundaries}: demo {i}"
        else:
            sig = {s: ep[f"subtask_signals/{s}"] for s in signals}
            try:
                ends = subtask_ends(sig, spec)
            except ValueError as exc:
                raise InputError(f"{src_path}: episode {i}: {exc}") from exc
            where = f"{src_path}: episode {i}"
        why = check_subtask_ends(ends, len(ep["actions"]), spec)
        if why:
            raise InputError(f"{where}: {why}")
        term_index.append(ends)
    steps = [store.episode(i) for i in range(store.n_episodes)]
    episodes = dict(store.episodes)
    episodes["subtask_term_index"] = np.asarray(term_index, np.int64).reshape(store.n_episodes, -1)
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
    write_store(out, "parsed", steps, episodes, attrs)
    print(
        f"parse: {store.n_episodes} demos, subtask ends {episodes['subtask_term_index'].tolist()}"
        f" of lengths {lengths.tolist()} -> {out}"
    )
