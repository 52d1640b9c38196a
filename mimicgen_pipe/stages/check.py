"""check: validate a pipeline's whole params file, and the files it names, before any stage
runs. Each pipeline's first stage runs it on every edit of its params file, so that a typo
stops `dvc repro` before DVC removes any stage's earlier outputs (DVC deletes a stage's
outputs before running its command; a stage that then refused its params had lost them).
With ``--stamp`` it then writes that file, one constant line: every other stage depends on
it, which makes DVC run the check first, and its unchanged bytes re-run nothing."""

from __future__ import annotations

import argparse
from pathlib import Path

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.plain_files import regular_file
from mimicgen_pipe.data.params import CheckJob, Params, load_params, write_stamp
from mimicgen_pipe.sources import source_inputs


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--params", default="params.yaml", help="params file (default: params.yaml)")
    p.add_argument("--stamp", help="file to write once the params are valid (the pipeline's check)")


def named_files(params: Params) -> dict[str, str]:
    """The files a params file names, key -> path (relative to the working directory)."""
    return {"source.from_file": params.source.from_file} if params.source.from_file else {}


def check_named_file(params_file: str, key: str, path: str) -> None:
    """A file a params key names must exist and be a regular file (not a folder, a FIFO or
    a device, which a reader would block on or read without end): plain_files'
    check, its error led by the params file and key."""
    try:
        regular_file(path, "file")
    except InputError as exc:
        raise InputError(f"{params_file}: {key}: {exc}") from None


def resolve(args: argparse.Namespace) -> CheckJob:
    """The params file of ``args``, checked whole with the files it names; writes nothing."""
    params = load_params(args.params)
    if params.source.from_file is not None:  # in the folder its pipeline's source stage tracks
        source_inputs.check_place(args.params, params.source.from_file)
    for key, path in named_files(params).items():
        check_named_file(args.params, key, path)
    return CheckJob(Path(args.params), Path(args.stamp) if args.stamp else None)


def run(job: CheckJob) -> None:
    write_stamp(job)
    print(f"check: {job.params_file}: valid")
