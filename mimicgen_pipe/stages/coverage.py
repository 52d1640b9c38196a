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
    bin_table,
    coverage_metrics,
    plot_heatmaps,
    reset_bounds,
    support_coverage,
    write_table,
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


def run(args: argparse.Namespace) -> None:
    params = stage_params(args)
    bins = params.coverage.bins
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
    claim(metrics_path, table_path, heatmap_path, inputs=[kept_path, failed_path])
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
    gen_cov = support_coverage(kept, bounds, bins)
    att_cov = support_coverage(attempted, bounds, bins)
    metrics = coverage_metrics(spec.objects, gen_cov, att_cov, bins)
    write_table(table_path, bin_table(spec.objects, bounds, gen_cov, att_cov))
    plot_heatmaps(
        heatmap_path,
        f"{params.task} {args.variant}: initial object positions ({bins} coverage bins per "
        f"dimension, edges in white)\njoint support coverage {gen_cov.joint_coverage:.1f}% "
        f"generated, {att_cov.joint_coverage:.1f}% attempted",
        spec.objects,
        bounds,
        kept,
        attempted,
        bins,
    )
    # the run measured, so that the report can check it is the run generate's metrics describe
    robot = store.attrs.get("robot")  # of the stores' one run (checked above)
    write_metrics(
        metrics_path,
        metrics_identity("coverage", params.task, params.backend, robot, variant=args.variant)
        | {"run_id": run_ids[str(kept_path)], **metrics},
    )
    per_object = ", ".join(f"{o} {metrics[f'support_coverage_{o}']:.1f}%" for o in spec.objects)
    print(
        f"coverage: {params.task} {args.variant}: {gen_cov.episodes} generated of "
        f"{att_cov.episodes} attempted; joint {gen_cov.joint_coverage:.1f}% "
        f"(attempted {att_cov.joint_coverage:.1f}%), {per_object} -> {metrics_path}"
    )
