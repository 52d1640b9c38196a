"""Stage scripts: argument parsing and I/O around the layers of mimicgen_pipe. Imports any
layer: a stage composes them.

Every stage module has one shape: ``add_arguments(p)``; ``resolve(args)``, the run its
command line and params file ask for as a frozen job (``<Stage>Job``), every refusal raised
there (InputError) before any output is claimed or anything written; and ``run(job)``, which
claims the job's outputs, does the work and writes them. The command line calls
``run(resolve(args))``. A job type lives in the library, beside the function that does its
work, which takes it whole (docs/extending.md, "A stage")."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.observations import is_robot_key
from mimicgen_pipe.data import layout, outputs, pipelines
from mimicgen_pipe.data.params import Params, load_params, with_overrides


def add_selection_arguments(p: argparse.ArgumentParser, robot: bool = False) -> None:
    """--params, and --backend/--task (and --robot) overriding params.yaml's choices."""
    p.add_argument(
        "--params",
        default="params.yaml",
        help="params file (default: params.yaml); default paths lie where the dvc.yaml "
        "beside it puts them (e.g. quickstart/data/... for quickstart/params.yaml)",
    )
    p.add_argument("--backend", help="simulator back end (default: params.yaml's backend)")
    p.add_argument("--task", help="task name (default: params.yaml's task)")
    if robot:
        p.add_argument("--robot", help="arm to generate with (default: generate.robot)")


def add_generated_arguments(p: argparse.ArgumentParser) -> None:
    """--variant and --generated, for stages that read a generate run's kept and failed
    stores (layout.generated_store, layout.failed_store)."""
    p.add_argument("--variant", required=True, help="reset variant, e.g. D0 or D1")
    p.add_argument(
        "--generated",
        help="generated store (default: data/generated/<task>_<variant>.zarr, where the "
        "params file's dvc.yaml keeps data; its failed "
        "attempts are read from <name>_failed.zarr beside it)",
    )


# options whose values become parts of file and folder names (data/generated/<task>_<variant>
# .zarr, data/policies/<task>_<data>): a name, never a path such as ../..
PATH_NAME_OPTIONS = ("backend", "task", "robot", "variant", "data")
PATH_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")


def check_path_names(args: argparse.Namespace) -> None:
    """InputError, before any work, for a value of :data:`PATH_NAME_OPTIONS` that is not a
    name of letters, digits, _ and - (the known names are checked where they are used)."""
    for dest in PATH_NAME_OPTIONS:
        value = getattr(args, dest, None)
        for v in value if isinstance(value, list) else [value]:
            if v is not None:
                check_path_name(f"--{dest}", v)


def check_path_name(option: str, value: str) -> None:
    """InputError unless ``value`` (given as ``option``) is a name of letters, digits, _
    and -, starting with a letter or digit."""
    if not PATH_NAME.fullmatch(value):
        raise InputError(f"{option} {value!r}: expected letters, digits, _ and - only")


def episode_count(text: str) -> int:
    """--episodes: a whole number, at least 1."""
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number, at least 1")
    return int(text)


def check_variants(params: Params, path: str) -> None:
    """InputError naming generate.variants (or ablations.variant) when the main task lacks
    one of its reset variants (the suite's and robot transfer's lists: the check stage of
    their pipelines)."""
    lists = [("generate.variants", params.backend, params.task, params.generate.variants)]
    if params.ablations.runs:
        lists += [("ablations.variant", params.backend, params.task, [params.ablations.variant])]
    check_variant_lists(lists, path)


def check_variant_lists(lists: list[tuple[str, str, str, list[str]]], path: str) -> None:
    """InputError naming the params key of the first (key, back end, task, variants) whose
    task lacks one of the variants."""
    for key, backend, task, variants in lists:
        spec = backends.task_spec(backend, task)
        for v in variants:
            if v not in spec.variants:
                raise InputError(
                    f"{path}: {key}: {v!r} is not a reset variant of {task} on {backend} "
                    f"(known: {', '.join(spec.variants)})"
                )


def stage_params(args: argparse.Namespace) -> Params:
    """params.yaml, validated (including its variant lists and obs keys against the task
    specs), with the command line's --backend/--task/--robot applied and train.obs_keys
    filled in from the task file where params leave it null. Default paths follow the
    pipeline of the params file's folder (pipelines.use_pipeline)."""
    params = load_params(args.params)
    pipelines.use_pipeline(args.params)
    check_variants(params, args.params)
    params = with_overrides(
        params,
        getattr(args, "backend", None),
        getattr(args, "task", None),
        getattr(args, "robot", None),
    )
    spec = backends.task_spec(params.backend, params.task)  # the task the stage runs
    # an image policy sees the objects in its cameras: its low-dim keys are the robot's own
    image = bool(params.train.active.cameras)
    if params.train.obs_keys is not None:
        where = f"{args.params}: train.obs_keys"
        backends.check_obs_keys(spec, params.train.obs_keys, where)
        objects = [k for k in params.train.obs_keys if not is_robot_key(k)]
        if image and objects:
            raise InputError(
                f"{where}: {objects} are the objects' keys, but train.profile "
                f"{params.train.profile!r} is an image policy, which reads the robot's own "
                "keys beside its cameras (paper N); drop them or set train.obs_keys: null"
            )
        return params
    keys = [k for k in spec.default_obs_keys if not image or is_robot_key(k)]
    return dataclasses.replace(params, train=dataclasses.replace(params.train, obs_keys=keys))


def check_data(params: Params, data: str, named: bool) -> None:
    """InputError, before any work, unless --data names training data the task has:
    "source" or one of its reset variants; or, where the store or policies are given by path
    (``named``), any name of letters, digits, _ and - (it goes into output file names)."""
    if named:
        check_path_name("--data", data)
        return
    variants = backends.task_spec(params.backend, params.task).variants
    if data != "source" and data not in variants:
        raise InputError(
            f'--data {data!r}: expected "source" or a reset variant of {params.task} '
            f"({', '.join(variants)})"
        )


def output_path(given: str | None, default: Path) -> Path:
    """Where a stage writes one output: the path given on the command line; else its
    default, except that a stage run by hand (outside DVC, without --replace-tracked) writes a
    default a pipeline tracks under scratch/ instead, and says so, so that the pipeline's
    committed results stay its own."""
    if given is not None:
        return Path(given)
    o = None if outputs.tracked_allowed() else pipelines.owner(default)
    if o is None:
        return default
    moved = layout.SCRATCH / default
    print(
        f"{default} is {o.dvc_file}'s (stage {o.stage}): a run by hand writes {moved} "
        f"instead (`{o.repro}` remakes the pipeline's)",
        file=sys.stderr,
    )
    return moved


def camera_renderer(
    params: Params, robot: str, cameras: tuple[str, ...], size: tuple[int, int] | None
) -> Callable[[], Any] | None:
    """How a worker makes the renderer of the cameras a policy reads (None: it reads none)."""
    if not cameras or size is None:
        return None
    height, width = size
    return functools.partial(
        backends.make_renderer, params.backend, params.task, robot, width, height, cameras
    )
