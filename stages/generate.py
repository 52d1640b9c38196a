"""generate: MimicGen data generation for one reset variant."""

from __future__ import annotations

import argparse
import functools
from pathlib import Path

import envs
from mimicgen_pipe import layout
from mimicgen_pipe.executors import stage_executor
from mimicgen_pipe.metrics import GENERATE_PURPOSE, metrics_identity, write_metrics
from mimicgen_pipe.outputs import claim, output_set, store_kind
from mimicgen_pipe.params import Params
from mimicgen_pipe.runner import (
    AttemptSeeds,
    attempt_job,
    capped_action_noise,
    check_source_attrs,
    check_workspace,
    generate,
    generated_attrs,
    generation_run_id,
    open_work_dir,
    with_generate_options,
    write_generated,
)
from mimicgen_pipe.transit import TRANSITS
from stages import add_selection_arguments, stage_params


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p, robot=True)
    p.add_argument("--variant", required=True, help="reset variant, e.g. D0 or D1")
    p.add_argument(
        "--parsed",
        help="parsed source store as the pose_noise stage wrote it (default: "
        "data/pose_noise/<task>.zarr); a clean parsed store is accepted at level none",
    )
    p.add_argument(
        "--out",
        help="generated store (default: data/generated/<task>_<variant>.zarr;"
        " failed attempts go to <name>_failed.zarr beside it)",
    )
    p.add_argument(
        "--metrics", help="metrics JSON (default: metrics/generate_<task>_<variant>.json)"
    )
    p.add_argument(
        "--attempts",
        type=int,
        help="run exactly this many attempts (fixed_attempts mode), whatever generate.mode says",
    )
    p.add_argument(
        "--action-noise",
        type=float,
        help="sigma of the action noise, in place of generate.action_noise (the suite's own)",
    )
    p.add_argument(
        "--num-demos",
        type=int,
        help="run until this many attempts succeed (guarantee mode, capped by "
        "generate.max_attempts), whatever generate.mode and num_demos say",
    )
    p.add_argument(
        "--max-attempts",
        type=int,
        help="most attempts before guarantee mode gives up, in place of generate.max_attempts",
    )
    p.add_argument(
        "--transit",
        choices=TRANSITS,
        help="linear or planned transit, in place of generate.transit",
    )


def generate_params(args: argparse.Namespace) -> Params:
    """params.yaml with the command line's options in place of the keys they stand for, each
    held to its key's range."""
    options = (args.attempts, args.action_noise, args.transit, args.num_demos, args.max_attempts)
    return with_generate_options(stage_params(args), *options)


def run(args: argparse.Namespace) -> None:
    params = generate_params(args)
    spec = envs.task_spec(params.backend, params.task)
    envs.check_variant(spec, args.variant)
    params, note = capped_action_noise(params, spec)
    if note is not None:
        print(f"generate: {note}")
    g = params.generate
    envs.check_robot(params.backend, g.robot)
    envs.check_transit(params.backend, g.robot, g.transit, len(spec.arms))
    make_batch = envs.generation_batches(params)  # refuses a batch it cannot run
    executor = stage_executor(params, "generate")  # refuses unsafe Ray settings before any work
    parsed_path = Path(args.parsed or layout.pose_noise_store(params.task))
    out = Path(args.out or layout.generated_store(params.task, args.variant))
    failed_out = layout.failed_store(out)
    metrics_path = Path(args.metrics or layout.metrics_file("generate", params.task, args.variant))
    # one run per output set (fails at once if taken); never over an input or anything else
    claim(
        (out, store_kind("generated")),
        (failed_out, store_kind("failed")),
        metrics_path,
        inputs=[parsed_path],
    )
    make_env = functools.partial(
        envs.make_env, params.backend, params.task, g.robot, params.maniskill.lean_step
    )
    job, store = attempt_job(params, spec, args.variant, parsed_path, make_env, make_batch)
    check_source_attrs(store.attrs, parsed_path, params.backend, spec, envs.control(params.backend))
    seeds = AttemptSeeds(g.seed, args.variant, g.max_attempts)  # each computed when needed
    check_workspace(job, seeds, g.robot)
    run = generation_run_id(params, args.variant, store)
    work = open_work_dir(out, run, seeds, job.block_size)
    num_demos = g.num_demos if g.mode == "guarantee" else None
    label = f"generate {params.task} {args.variant}"
    result = generate(job, seeds, executor, work, num_demos, g.robot, label)
    attrs = generated_attrs(run, params, args.variant, spec, store.attrs)
    # written aside, then renamed failed store, metrics, kept store: a reader that finds the
    # new kept store finds the rest of its run beside it
    with output_set(failed_out, metrics_path, out) as (tmp_failed, tmp_metrics, tmp_out):
        write_generated(tmp_out, tmp_failed, result, spec, attrs)
        write_metrics(
            tmp_metrics,
            metrics_identity(
                "generate",
                params.task,
                params.backend,
                g.robot,
                variant=args.variant,
                purpose=GENERATE_PURPOSE[g.mode],
            )
            | {"run_id": run, **(metrics := result.metrics)},
        )
    work.remove()
    print(
        f"generate: {metrics['successes']}/{metrics['attempts']} attempts succeeded "
        f"(DGR {metrics['dgr']:.1f}%, {metrics['ik_failures']} IK failures, "
        f"median {metrics['seconds_per_attempt_median']:.3f} s/attempt)"
        f" -> {out}"
    )
