"""observe: camera images (observe.cameras) of the first episodes of a generated or source
store, rendered from each step's stored simulator state, written beside a copy of its arrays
as an observed store."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import time
from pathlib import Path

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.metrics import metrics_identity, split_timings, write_metrics, write_timings
from mimicgen_pipe.data.outputs import claim, output_set, store_kind
from mimicgen_pipe.data.store import open_store, store_writer
from mimicgen_pipe.media.camera_images import (
    ImageBlockCodec,
    ObserveJob,
    check_input,
    episode_blocks,
    frame_progress,
    observe_metrics,
    observe_run_id,
    observed_attrs,
    open_work_dir,
    render_blocks,
    write_observed,
)
from mimicgen_pipe.run.executors import Executor
from mimicgen_pipe.stages import add_selection_arguments, episode_count, output_path, stage_params


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument("--variant", required=True, help="reset variant, e.g. D0")
    p.add_argument(
        "--store",
        help="the store to observe (default: data/generated/<task>_<variant>.zarr); a "
        "generated, failed or source store",
    )
    p.add_argument(
        "--episodes",
        type=episode_count,
        help="observe the store's first N episodes (default: params observe.episodes)",
    )
    p.add_argument("--out", help="observed store (default: data/observed/<task>_<variant>.zarr)")
    p.add_argument(
        "--metrics", help="metrics JSON (default: metrics/observe_<task>_<variant>.json)"
    )


def run(args: argparse.Namespace) -> None:
    params = stage_params(args)
    if args.episodes is not None:  # in place of observe.episodes, held to the store below
        observe = dataclasses.replace(params.observe, episodes=args.episodes)
        params = dataclasses.replace(params, observe=observe)
    o = params.observe
    store_path = Path(args.store or layout.generated_store(params.task, args.variant))
    out = output_path(args.out, layout.observed_store(params.task, args.variant))
    metrics_path = output_path(
        args.metrics, layout.metrics_file("observe", params.task, args.variant)
    )
    view = open_store(store_path, task=params.task)
    if args.episodes is not None and args.episodes > view.n_episodes:
        raise InputError(f"--episodes {args.episodes}: {store_path} has {view.n_episodes} episodes")
    n = check_input(view, params, args.params, backends.check_cameras)
    a = view.attrs
    kind = a["kind"]
    claim((out, store_kind(kind)), metrics_path, inputs=[store_path])
    # the store's own back end renders it, in every worker
    make_renderer = functools.partial(backends.make_renderer, a["backend"])
    job = ObserveJob(store_path, a["backend"], params.task, a["robot"], tuple(o.cameras),
                     o.height, o.width, make_renderer)  # fmt: skip
    blocks = episode_blocks(n)
    run_id = observe_run_id(params, a, view.read_rows("env_state", range(n)))
    work = open_work_dir(out, run_id, ImageBlockCodec(blocks, view.lengths, job))
    # each camera's K and pose (mimicgen_pipe/core/camera_calibration.py), from the back end
    attrs = observed_attrs(a, params, backends.camera_calibration(o.cameras, o.height, o.width))
    t0 = time.perf_counter()
    frames = int(view.episode_ends[n - 1]) if n else 0
    label = f"observe {params.task} {args.variant}"
    with (
        output_set(metrics_path, out) as (tmp_metrics, tmp_out),
        frame_progress(label, frames, o.workers) as progress,
    ):
        rendering = dataclasses.replace(job, progress=progress.directory)
        images = render_blocks(rendering, blocks, Executor("local", o.workers), work)
        try:
            with store_writer(tmp_out, kind, view.episode_ends[:n], attrs) as writer:
                seconds = write_observed(writer, view, job, images, blocks, progress, work)
        finally:
            images.close()
        wall = time.perf_counter() - t0
        metrics, timings = split_timings(observe_metrics(tmp_out, job, frames, n, seconds, wall))
        identity = metrics_identity(
            "observe", params.task, a["backend"], a["robot"], variant=args.variant
        )
        write_metrics(tmp_metrics, identity | metrics)
    work.remove()
    write_timings(metrics_path, identity, timings)
    print(
        f"observe: {metrics['frames']} steps x {len(o.cameras)} cameras of {n} episodes "
        f"({metrics['image_mb_per_1000_demos']} MB of images per 1000 demos) -> {out}"
    )
