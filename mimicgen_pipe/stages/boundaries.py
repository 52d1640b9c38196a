"""boundaries: print candidate subtask ends of every source demo (gripper close/open events)
and a boundaries file to start from, for demos recorded without term signals
(``mimicgen-pipe parse --boundaries FILE``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from mimicgen_pipe import backends
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.run.parsing import BoundariesJob, boundary_candidates
from mimicgen_pipe.stages import add_selection_arguments, stage_params


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument("--source", help="source store (default: data/source/<task>.zarr)")


def resolve(args: argparse.Namespace) -> BoundariesJob:
    """The source demos ``args`` name, their store read with its gripper actions."""
    params = stage_params(args)
    spec = backends.task_spec(params.backend, params.task)
    path = Path(args.source or layout.source_store(params.task))
    store = read_store(path, required=["gripper"], task=params.task, kind="source")
    return BoundariesJob(path, store, tuple(s.name for s in spec.subtasks[:-1]))


def run(job: BoundariesJob) -> None:
    for line in boundary_candidates(job):
        print(line)
