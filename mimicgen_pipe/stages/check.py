"""check: validate a pipeline's whole params file, and the files it names, before any stage
runs. Each pipeline's first stage runs it on every edit of its params file, so that a typo
stops `dvc repro` before DVC removes any stage's earlier outputs (DVC deletes a stage's
outputs before running its command; a stage that then refused its params had lost them).
With ``--stamp`` it then writes that file, one constant line: every other stage depends on
it, which makes DVC run the check first, and its unchanged bytes re-run nothing. The rules
that tie the lists of one pipeline's own section together (the suite's, robot transfer's)
are checked here once, not by every stage."""

from __future__ import annotations

import argparse
from pathlib import Path

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.plain_files import regular_file
from mimicgen_pipe.data.params import (
    CheckJob,
    Params,
    SuiteParams,
    load_params,
    read_yaml,
    write_stamp,
)
from mimicgen_pipe.sources import source_inputs
from mimicgen_pipe.stages import check_variant_lists, check_variants


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


def check_suite(params: Params, path: str) -> None:
    """The suite's rules (suite/params.yaml): InputError naming the key when a suite task
    with policies or the scaling task is not a suite task (or, with policies, is listed
    twice), a policy cell is wrong (:func:`check_policy_cells`), a task of
    suite.robomimic_tasks has no D0 policy data, a task of suite.ablation_tasks is not a
    suite task, or a suite task (suite.variants, suite.object_transfer, the scaling task's
    variant, the ablation tasks' ablations.variant) lacks a listed reset variant."""
    u = params.suite
    seen: set[str] = set()
    for key in ("suite.policy_tasks", "suite.d0_policy_tasks", "suite.seeded_policy_tasks"):
        for task in getattr(u, key.split(".")[1]):
            if task not in u.tasks or task in seen:
                why = "not in suite.tasks" if task not in u.tasks else "listed twice"
                raise InputError(f"{path}: {key}: {task!r} is {why}")
            seen.add(task)
    check_policy_cells(u, path)
    for task in u.robomimic_tasks:
        if f"{task}-D0" not in u.policy_data:
            raise InputError(f"{path}: suite.robomimic_tasks: {task!r} has no D0 policy data "
                             f"({task}-D0 in suite.policy_data)")  # fmt: skip
    scaling = u.scaling
    if scaling.task is not None and scaling.task not in u.tasks:
        raise InputError(f"{path}: suite.scaling.task: {scaling.task!r} is not in suite.tasks")
    if max(scaling.num_demos) > scaling.demos:
        raise InputError(
            f"{path}: suite.scaling.num_demos: {max(scaling.num_demos)} is more than the "
            f"{scaling.demos} demos of suite.scaling.demos"
        )
    lists = [("suite.variants", u.backend, task, u.variants) for task in u.tasks]
    lists += [("suite.object_transfer", u.backend, task, ["O1"]) for task in u.object_transfer]
    if scaling.task is not None:
        lists += [("suite.scaling.variant", u.backend, scaling.task, [scaling.variant])]
    for task in u.ablation_tasks:
        if task not in u.tasks:
            raise InputError(f"{path}: suite.ablation_tasks: {task!r} is not in suite.tasks")
        lists += [("ablations.variant", u.backend, task, [params.ablations.variant])]
    check_variant_lists(lists, path)


def check_transfer(params: Params, path: str) -> None:
    """Robot transfer's rules (transfer/params.yaml): InputError naming the key when a task
    of transfer.policy_tasks is not in transfer.tasks or a transfer task lacks one of
    transfer.variants."""
    t = params.transfer
    for task in t.policy_tasks:
        if task not in t.tasks:
            raise InputError(
                f"{path}: transfer.policy_tasks: {task!r} is not in transfer.tasks (its "
                "policy data is generated from transfer's source demos)"
            )
    check_variant_lists(
        [("transfer.variants", t.backend, task, t.variants) for task in t.tasks], path
    )


def check_policy_cells(u: SuiteParams, path: str) -> None:
    """InputError unless each cell of suite.policy_data and suite.evaluations is named by
    its fields and names a suite task, every policy's store has its policy_data cell, and
    every evaluation rolls out a policy the suite trains."""
    data = {
        **{t: ("D0", "D1") for t in u.policy_tasks},
        **{t: ("D0",) for t in u.d0_policy_tasks + u.seeded_policy_tasks},
    }
    policies = {t: ("source", *v) for t, v in data.items() if t not in u.seeded_policy_tasks}
    policies |= {t: ("D0",) for t in u.seeded_policy_tasks}
    cells = [
        (f"suite.policy_data.{k}", k, c, f"{c.task}-{c.variant}") for k, c in u.policy_data.items()
    ]
    cells += [(f"suite.evaluations.{k}", k, c, f"{c.task}-{c.data}-on-{c.variant}")
              for k, c in u.evaluations.items()]  # fmt: skip
    for where, key, cell, name in cells:
        if key != name:
            raise InputError(f"{path}: {where}: expected the key {name!r}, which its fields name")
        if cell.task not in u.tasks:
            raise InputError(f"{path}: {where}: {cell.task!r} is not in suite.tasks")
    for task, variants in data.items():
        for v in variants:
            if f"{task}-{v}" not in u.policy_data:
                raise InputError(f"{path}: suite.policy_data: no {task}-{v}, the store of "
                                 f"{task}'s {v} policy")  # fmt: skip
    for key, e in u.evaluations.items():
        if e.data not in policies.get(e.task, ()):
            raise InputError(f"{path}: suite.evaluations.{key}: the suite trains no {e.data} "
                             f"policy of {e.task}")  # fmt: skip


def check_image_size(params: Params, path: str) -> None:
    """An image profile trains on the observe stage's images: InputError naming the keys
    unless observe.height and observe.width are train.cpu_image.image_size."""
    size = list(params.train.cpu_image.image_size)
    observed = [params.observe.height, params.observe.width]
    if params.train.profile == "cpu_image" and observed != size:
        raise InputError(
            f"{path}: observe.height, observe.width: {observed[0]}x{observed[1]} px, but the "
            f"image agents (train.profile cpu_image) train on {size[0]}x{size[1]} px images "
            "(train.cpu_image.image_size): set both to one size"
        )


# the sections of one pipeline only, checked where that pipeline's params file has them
SECTION_CHECKS = {"suite": check_suite, "transfer": check_transfer}


def resolve(args: argparse.Namespace) -> CheckJob:
    """The params file of ``args``, checked whole with the files it names, and the rules of
    the pipeline sections it has (SECTION_CHECKS); writes nothing."""
    params = load_params(args.params)
    check_variants(params, args.params)
    check_image_size(params, args.params)
    present = read_yaml(Path(args.params), "params file")
    for section, check in SECTION_CHECKS.items():
        if section in present:
            check(params, args.params)
    if params.source.from_file is not None:  # in the folder its pipeline's source stage tracks
        source_inputs.check_place(args.params, params.source.from_file)
    for key, path in named_files(params).items():
        check_named_file(args.params, key, path)
    return CheckJob(Path(args.params), Path(args.stamp) if args.stamp else None)


def run(job: CheckJob) -> None:
    write_stamp(job)
    print(f"check: {job.params_file}: valid")
