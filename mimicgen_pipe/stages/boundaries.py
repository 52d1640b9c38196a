"""boundaries: print candidate subtask ends of every source demo (gripper close/open events)
and a boundaries file to start from, for demos recorded without term signals
(``mimicgen-pipe parse --boundaries FILE``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from mimicgen_pipe import backends
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.method.segments import gripper_events
from mimicgen_pipe.stages import add_selection_arguments, stage_params


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument("--source", help="source store (default: data/source/<task>.zarr)")


def run(args: argparse.Namespace) -> None:
    params = stage_params(args)
    spec = backends.task_spec(params.backend, params.task)
    path = Path(args.source or layout.source_store(params.task))
    store = read_store(path, required=["gripper"], task=params.task, kind="source")
    names = [s.name for s in spec.subtasks[:-1]]
    print(f"# {path}: {store.n_episodes} demos; subtasks ending here: {', '.join(names)}")
    print("# candidates: steps where the gripper action closes or opens; an end is the first")
    print("# step of the next subtask. Proposed ends: the first events, one per subtask.")
    for i in range(store.n_episodes):
        ep = store.episode(i)
        events = gripper_events(ep["gripper"])
        described = ", ".join(f"{kind} at {t}" for t, kind in events) or "none"
        proposal = [t for t, _ in events[: len(names)]]
        print(f"# demo {i} ({len(ep['gripper'])} steps): {described}")
        print(f"{i}: {proposal}")
