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
from mimicgen_pipe.data.store import open_store
from mimicgen_pipe.media.camera_images import (
    ImageBlockCodec,
    ImageJob,
    ObserveJob,
    check_input,
    episode_blocks,
    frame_progress,
    observe,
    observe_metrics,
    observe_run_id,
    observed_attrs,
    open_work_dir,
)
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


def resolve(args: argparse.Namespace) -> ObserveJob:
    """The observe run ``args`` ask for: the params, and the store opened and checked to be
    one that can be observed as they say, its states to render read; writes nothing."""
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
    # the store's own back end renders it, in every worker
    make_renderer = functools.partial(backends.make_renderer, a["backend"])
    images = ImageJob(store_path, a["backend"], params.task, a["robot"], tuple(o.cameras),
                      o.height, o.width, make_renderer)  # fmt: skip
    # each camera's K and pose (mimicgen_pipe/core/camera_calibration.py), from the back end
    calibration = backends.camera_calibration(o.cameras, o.height, o.width)
    return ObserveJob(
        task=params.task,
        variant=args.variant,
        backend=a["backend"],
        robot=a["robot"],
        kind=a["kind"],
        store_path=store_path,
        view=view,
        episodes=n,
        images=images,
        blocks=episode_blocks(n),
        workers=o.workers,
        run_id=observe_run_id(params, a, view.read_rows("env_state", range(n))),
        attrs=observed_attrs(a, params, calibration),
        out=out,
        metrics_path=metrics_path,
    )


def run(job: ObserveJob) -> None:
    claim((job.out, store_kind(job.kind)), job.metrics_path, inputs=[job.store_path])
    codec = ImageBlockCodec(job.blocks, job.view.lengths, job.images)
    work = open_work_dir(job.out, job.run_id, codec)
    t0 = time.perf_counter()
    with (
        output_set(job.metrics_path, job.out) as (tmp_metrics, tmp_out),
        frame_progress(job.label, job.frames, job.workers) as progress,
    ):
        seconds = observe(job, tmp_out, work, progress)
        wall = time.perf_counter() - t0
        metrics, timings = split_timings(
            observe_metrics(tmp_out, job.images, job.frames, job.episodes, seconds, wall)
        )
        identity = metrics_identity(
            "observe", job.task, job.backend, job.robot, variant=job.variant
        )
        write_metrics(tmp_metrics, identity | metrics)
    work.remove()
    write_timings(job.metrics_path, identity, timings)
    print(
        f"observe: {metrics['frames']} steps x {len(job.images.cameras)} cameras of "
        f"{job.episodes} episodes ({metrics['image_mb_per_1000_demos']} MB of images per 1000 "
        f"demos) -> {job.out}"
    )
