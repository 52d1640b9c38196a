"""ablation: one of the paper's generation ablations (``ablations.runs`` of the params file),
as the pose_noise, generate and coverage stages run on the run's own params: the pipeline's,
with the run's changes, on ``ablations.variant`` for exactly ``ablations.attempts`` attempts.
The run's params file and metrics go where the report reads them."""

from __future__ import annotations

import argparse
import functools
from pathlib import Path
from types import ModuleType

import yaml

from mimicgen_pipe import backends
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.outputs import TEXT, claim, directory_kind
from mimicgen_pipe.data.params import ablation_params, as_dict, read_yaml
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.run.ablation_runs import AblationJob, run_ablation
from mimicgen_pipe.stages import (
    add_selection_arguments,
    check_path_name,
    coverage,
    generate,
    output_path,
    pose_noise,
    stage_params,
)
from mimicgen_pipe.stages.generate import with_generate_options

# what the run's stores folder holds: the three stages' outputs and the params they ran on
WORK = directory_kind(
    "ablation run's stores",
    r"params\.yaml|[\w-]+\.zarr/.*|coverage_[\w-]+\.(csv|png)|\..*",
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument("--run", required=True, help="a run of the params file's ablations.runs")
    p.add_argument(
        "--action-noise",
        type=float,
        help="the base's action noise, in place of generate.action_noise (the suite's own); "
        "a run that changes generate.action_noise sets its own",
    )
    p.add_argument("--parsed", help="clean parsed store (default: data/parsed/<task>.zarr)")
    p.add_argument("--work", help="the run's stores (default: data/ablations/<run>)")
    p.add_argument(
        "--out",
        help="the run's params.yaml and metrics, where the report reads them "
        "(default: metrics/ablations/<run>)",
    )


def resolve(args: argparse.Namespace) -> AblationJob:
    """The run's params (every change checked against its key), its variant against the
    task, and the parsed store read and checked to be a parsed store of the task; writes
    nothing."""
    check_path_name("--run", args.run)
    base = with_generate_options(stage_params(args), None, args.action_noise)
    params = ablation_params(base, args.run, args.params)
    a = params.ablations
    spec = backends.task_spec(params.backend, params.task)
    backends.check_variant(spec, a.variant)
    parsed = Path(args.parsed or layout.parsed_store(params.task))
    read_store(parsed, kind="parsed", task=params.task)
    work = output_path(args.work, layout.ablation_stores(args.run))
    out = output_path(args.out, layout.ablations_dir() / args.run)
    # the params file as given, with the run's task, back end and the two sections it may
    # change; without the list of runs: the run is one
    record = read_yaml(Path(args.params), "params file")
    del record["ablations"]
    record |= {"task": params.task, "backend": params.backend}
    record |= {"generate": as_dict(params.generate), "pose_noise": as_dict(params.pose_noise)}
    text = f"# ablation run {args.run}: {a.runs[args.run].what}\n"
    text += yaml.safe_dump(record, sort_keys=False)
    run_params = ["--params", str(work / "params.yaml")]
    noised, kept = work / "pose_noise.zarr", work / f"{params.task}_{a.variant}.zarr"
    name = f"{params.task}_{a.variant}"
    steps = (
        (pose_noise, [*run_params, "--parsed", str(parsed), "--out", str(noised)]),
        (generate, [*run_params, "--variant", a.variant, "--parsed", str(noised),
                    "--out", str(kept), "--metrics", str(out / f"generate_{name}.json")]),
        (coverage, [*run_params, "--variant", a.variant, "--generated", str(kept),
                    "--metrics", str(out / f"coverage_{name}.json"),
                    "--table", str(work / f"coverage_{name}.csv"),
                    "--heatmap", str(work / f"coverage_{name}.png")]),
    )  # fmt: skip
    return AblationJob(
        run=args.run,
        what=a.runs[args.run].what,
        params_text=text,
        work=work,
        out=out,
        steps=tuple(functools.partial(_run_stage, stage, argv) for stage, argv in steps),
    )


def _run_stage(stage: ModuleType, argv: list[str]) -> None:
    """``stage`` on the command line ``argv``, resolved when its inputs exist (the previous
    stage's outputs)."""
    p = argparse.ArgumentParser()
    stage.add_arguments(p)
    stage.run(stage.resolve(p.parse_args(argv)))


def run(job: AblationJob) -> None:
    claim((job.work, WORK), (job.out / "params.yaml", TEXT))
    seconds = run_ablation(job)
    print(f"ablation {job.run} ({job.what}): {seconds:.0f} s -> {job.out}")
