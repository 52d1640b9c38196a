"""source: record source demos on D0 (the back end's demonstrator, or a trajectory file)."""

from __future__ import annotations

import argparse
import dataclasses
import functools

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.plain_files import regular_file
from mimicgen_pipe.core.taskspec import version_record
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.metrics import metrics_identity, write_metrics
from mimicgen_pipe.data.outputs import claim, output_set, store_kind
from mimicgen_pipe.data.params import Params, data_params
from mimicgen_pipe.sources import robomimic_source, source_inputs
from mimicgen_pipe.sources.recording import SourceJob, record_source_demos
from mimicgen_pipe.sources.source_files import check_file_states
from mimicgen_pipe.stages import add_selection_arguments, output_path, stage_params


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument("--out", help="output store (default: data/source/<task>.zarr)")
    p.add_argument("--metrics", help="metrics JSON (default: metrics/source_<task>.json)")
    p.add_argument(
        "--from-file",
        metavar="PATH",
        help="source demos from this file instead of params' source.from_file (a hand run "
        "may name any file; in a pipeline, params' source.from_file lies in its inputs/)",
    )


def with_source_file(params: Params, args: argparse.Namespace) -> Params:
    """``params`` with --from-file applied, the file checked to be a regular file; without
    it, params' own source.from_file checked to lie in the inputs folder that its
    pipeline's source stage tracks (source_inputs.check_place), as the check stage does."""
    if args.from_file is None:
        if params.source.from_file is not None:
            source_inputs.check_place(args.params, params.source.from_file)
        return params
    try:
        regular_file(args.from_file, "file")
    except InputError as exc:
        raise InputError(f"--from-file {exc}") from None
    source = dataclasses.replace(params.source, from_file=args.from_file)
    return dataclasses.replace(params, source=source)


def check_source_file(params: Params, params_path: str) -> int:
    """Read and check every episode of ``source.from_file`` (not None) before the simulator
    starts, as the back end's reader will: a robomimic ``.hdf5``/``.hdf`` on any back end,
    else a file format of the back end's own (maniskill: a trajectory ``.h5`` with its
    ``.json``). Returns the number of episodes; InputError naming the file and key when it
    is unreadable or broken, or has fewer episodes than source.num_demos (of which the first
    num_demos are used)."""
    p = params.source
    assert p.from_file is not None
    if robomimic_source.is_robomimic_file(p.from_file):
        n = len(robomimic_source.read(p.from_file, params.backend, params.task))
    else:
        n = backends.source_file_episodes(params.backend, p.from_file, params.task)
    if n is None:
        raise InputError(
            f"{params_path}: source.from_file: {p.from_file}: backend {params.backend} reads "
            "no source file format of its own; give a robomimic .hdf5 (as the export stage "
            "writes) or null for the scripted demonstrator"
        )
    if n < p.num_demos:
        raise InputError(
            f"{p.from_file}: {n} episode{'s' if n != 1 else ''}, fewer than source.num_demos "
            f"= {p.num_demos} in {params_path}; ask for {n} or fewer, or give a file with more"
        )
    return n


def resolve(args: argparse.Namespace) -> SourceJob:
    """The source run ``args`` ask for: the params, the robot, and source.from_file (if any)
    read and checked whole, a robomimic file's states against an env's; writes nothing."""
    params = with_source_file(stage_params(args), args)
    spec = backends.task_spec(params.backend, params.task)
    p = params.source
    backends.check_robot(params.backend, p.robot)
    make_env = functools.partial(
        backends.make_env, params.backend, params.task, p.robot, params.maniskill.lean_step
    )
    if p.from_file is not None:  # read and checked whole before the simulator starts
        check_source_file(params, args.params)
        if robomimic_source.is_robomimic_file(p.from_file):
            check_file_states(params.backend, p.from_file, p.num_demos, make_env)
    return SourceJob(
        spec=spec,
        backend=params.backend,
        source=p,
        make_env=make_env,
        demonstrator=functools.partial(backends.source_episodes, params.backend),
        brought_in=source_inputs.file_identity(p.from_file),  # {} for the demonstrator
        data_params=data_params(params, "source"),
        out=output_path(args.out, layout.source_store(params.task)),
        metrics_path=output_path(args.metrics, layout.metrics_file("source", params.task)),
    )


def run(job: SourceJob) -> None:
    p, task, backend = job.source, job.spec.name, job.backend
    # fails at once if another run writes them, or if they would replace anything else
    claim((job.out, store_kind("source")), job.metrics_path, inputs=job.inputs)
    env = job.make_env()
    print(
        f"source: {p.num_demos} demos of {task} on {backend} (D0)"
        + source_inputs.describe(job.brought_in)
    )
    demos = record_source_demos(job, env)
    from mimicgen_pipe.data.store import write_store

    # store and metrics written aside, then renamed together (the store last)
    with output_set(job.metrics_path, job.out) as (tmp_metrics, tmp_out):
        write_store(
            tmp_out,
            "source",
            demos.steps,
            demos.episode_fields(),
            {
                "task": task,
                "variant": "D0",
                "backend": backend,
                "robot": p.robot,
                "control_mode": env.control_mode,
                "control_freq": env.control_freq,
                "objects": list(job.spec.objects),
                "source_file": str(p.from_file or "demonstrator"),
                "params": job.data_params,
                **version_record(job.spec),
            },
        )
        write_metrics(
            tmp_metrics,
            metrics_identity("source", task, backend, p.robot, variant="D0")
            | demos.metrics()
            | job.brought_in,
        )
    print(
        f"source: {len(demos.steps)} demos -> {job.out} ({demos.demonstrator_failures} "
        f"demonstrator and {demos.replay_failures} replay failures dropped)"
    )
