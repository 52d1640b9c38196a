"""generate: MimicGen data generation for one reset variant."""

from __future__ import annotations

import argparse

from mimicgen_pipe.core.transit import TRANSITS
from mimicgen_pipe.data.metrics import split_timings, write_metrics, write_timings
from mimicgen_pipe.data.outputs import claim, output_set, store_kind
from mimicgen_pipe.run.runner import generate, open_work_dir, write_generated
from mimicgen_pipe.stages import add_selection_arguments
from mimicgen_pipe.stages.generate_job import resolve


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p, robot=True)
    p.add_argument("--variant", required=True, help="reset variant, e.g. D0 or D1")
    p.add_argument(
        "--parsed",
        help="parsed source store as the pose_noise stage wrote it (default: "
        "data/pose_noise/<task>.zarr, or data/parsed/<task>.zarr in a pipeline without a "
        "pose_noise stage); a clean parsed store is accepted at level none",
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


def run(args: argparse.Namespace) -> None:
    job = resolve(args)  # every refusal, before any work and before any output is claimed
    if job.note is not None:
        print(f"generate: {job.note}")
    # one run per output set (fails at once if taken); never over an input or anything else
    claim(
        (job.out, store_kind("generated")),
        (job.failed_out, store_kind("failed")),
        job.metrics_path,
        inputs=[job.parsed_path],
    )
    work = open_work_dir(job.out, job.run_id, job.seeds, job.attempts.block_size)
    result = generate(
        job.attempts, job.seeds, job.executor, work, job.num_demos, job.robot, job.label
    )
    # written aside, then renamed failed store, metrics, kept store: a reader that finds the
    # new kept store finds the rest of its run beside it
    outs = (job.failed_out, job.metrics_path, job.out)
    identity = job.identity | {"run_id": job.run_id}
    metrics, timings = split_timings(result.metrics)
    with output_set(*outs) as (tmp_failed, tmp_metrics, tmp_out):
        write_generated(tmp_out, tmp_failed, result, job.spec, job.attrs)
        write_metrics(tmp_metrics, identity | metrics)
    work.remove()
    write_timings(job.metrics_path, identity, timings)
    print(
        f"generate: {metrics['successes']}/{metrics['attempts']} attempts succeeded "
        f"(DGR {metrics['dgr']:.1f}%, {metrics['ik_failures']} IK failures, "
        f"median {timings['seconds_per_attempt_median']:.3f} s/attempt)"
        f" -> {job.out}"
    )
