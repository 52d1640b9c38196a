"""coverage: support coverage of a generated dataset's initial scenes (paper Q)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.metrics import metrics_identity, write_metrics
from mimicgen_pipe.data.outputs import check_same_run, claim
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.method.coverage import (
    CoverageJob,
    coverage_metrics,
    measure_coverage,
    reset_bounds,
)
from mimicgen_pipe.stages import (
    add_generated_arguments,
    add_selection_arguments,
    output_path,
    stage_params,
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    add_generated_arguments(p)
    p.add_argument(
        "--metrics", help="metrics JSON (default: metrics/coverage_<task>_<variant>.json)"
    )
    p.add_argument(
        "--table", help="per-bin counts, CSV (default: plots/coverage_<task>_<variant>.csv)"
    )
    p.add_argument(
        "--heatmap", help="heat maps, PNG (default: plots/coverage_<task>_<variant>.png)"
    )


def resolve(args: argparse.Namespace) -> CoverageJob:
    """The coverage run ``args`` ask for: the params, the variant's reset bounds, and the
    initial scenes of the kept and failed stores of one generate run of this task and
    variant, with at least one attempt; writes nothing."""
    params = stage_params(args)
    spec = backends.task_spec(params.backend, params.task)
    backends.check_variant(spec, args.variant)
    bounds = reset_bounds(spec, args.variant)
    kept_path = Path(args.generated or layout.generated_store(params.task, args.variant))
    failed_path = layout.failed_store(kept_path)
    metrics_path = output_path(
        args.metrics, layout.metrics_file("coverage", params.task, args.variant)
    )
    table_path = output_path(args.table, layout.plot_file("coverage", params.task, args.variant))
    heatmap_path = output_path(args.heatmap, layout.heatmap_file(params.task, args.variant))
    n_obj = len(spec.objects)
    initial, run_ids = {}, {}
    for path, kind in ((kept_path, "generated"), (failed_path, "failed")):
        store = read_store(path, kind=kind, required_episodes=["initial_object_poses"])
        if store.attrs.get("task") != params.task or store.attrs.get("variant") != args.variant:
            raise InputError(
                f"{path}: holds {store.attrs.get('task')!r} {store.attrs.get('variant')!r}, "
                f"expected {params.task!r} {args.variant!r}"
            )
        initial[path] = store.poses("initial_object_poses").reshape(-1, n_obj, 4, 4)
        run_ids[str(path)] = store.attrs.get("run_id")
    check_same_run(run_ids)  # e.g. a new kept store beside the failed store of an older run
    kept = initial[kept_path]
    attempted = np.concatenate([kept, initial[failed_path]])
    if len(attempted) == 0:
        raise InputError(f"{kept_path}: no attempts recorded (kept or failed)")
    return CoverageJob(
        task=params.task,
        variant=args.variant,
        backend=params.backend,
        robot=store.attrs.get("robot"),  # of the stores' one run (checked above)
        run_id=run_ids[str(kept_path)],
        objects=spec.objects,
        bounds=tuple(bounds),
        bins=params.coverage.bins,
        kept=kept,
        attempted=attempted,
        kept_path=kept_path,
        failed_path=failed_path,
        metrics_path=metrics_path,
        table=table_path,
        heatmap=heatmap_path,
    )


def run(job: CoverageJob) -> None:
    claim(job.metrics_path, job.table, job.heatmap, inputs=[job.kept_path, job.failed_path])
    gen_cov, att_cov = measure_coverage(job)
    metrics = coverage_metrics(job.objects, gen_cov, att_cov, job.bins)
    # the run measured, so that the report can check it is the run generate's metrics describe
    write_metrics(
        job.metrics_path,
        metrics_identity("coverage", job.task, job.backend, job.robot, variant=job.variant)
        | {"run_id": job.run_id, **metrics},
    )
    per_object = ", ".join(f"{o} {metrics[f'support_coverage_{o}']:.1f}%" for o in job.objects)
    print(
        f"coverage: {job.task} {job.variant}: {gen_cov.episodes} generated of "
        f"{att_cov.episodes} attempted; joint {gen_cov.joint_coverage:.1f}% "
        f"(attempted {att_cov.joint_coverage:.1f}%), {per_object} -> {job.metrics_path}"
    )
