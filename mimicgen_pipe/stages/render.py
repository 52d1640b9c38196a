"""render: MP4s (and GIFs for the report) of the first kept and failed generated episodes of
one variant, replayed from their stored states, captioned with the subtask and source demo."""

from __future__ import annotations

import argparse
import functools
from pathlib import Path

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.metrics import metrics_identity, write_metrics, write_timings
from mimicgen_pipe.data.outputs import check_same_run, claim, directory_kind, output_set
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.media.video import RenderJob, render_videos
from mimicgen_pipe.stages import (
    add_generated_arguments,
    add_selection_arguments,
    output_path,
    stage_params,
)

# what the stage writes in its media directory: videos of kept and failed attempts
MEDIA_DIR = directory_kind("media directory", r"(kept|failed)_\d+\.(mp4|gif)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    add_generated_arguments(p)
    p.add_argument("--out", help="output directory (default: media/<task>_<variant>)")
    p.add_argument("--metrics", help="metrics JSON (default: metrics/render_<task>_<variant>.json)")


def resolve(args: argparse.Namespace) -> RenderJob:
    """The render run ``args`` ask for: the params, and the kept and failed stores of one
    generate run read whole, with the states to render; writes nothing."""
    params = stage_params(args)
    r = params.render
    spec = backends.task_spec(params.backend, params.task)
    backends.check_variant(spec, args.variant)
    kept_path = Path(args.generated or layout.generated_store(params.task, args.variant))
    failed_path = layout.failed_store(kept_path)
    out = output_path(args.out, layout.media_dir(params.task, args.variant))
    metrics_path = output_path(
        args.metrics, layout.metrics_file("render", params.task, args.variant)
    )
    stores = {
        kind: read_store(path, kind=kind, task=params.task)
        for kind, path in (("generated", kept_path), ("failed", failed_path))
    }
    for store in stores.values():  # an empty store (no failures) has no arrays at all
        if store.n_episodes and "env_state" not in store.data:
            raise InputError(f"{store.path}: missing data keys ['env_state']")
    check_same_run({k: s.attrs.get("run_id") for k, s in stores.items()})
    attrs = stores["generated"].attrs
    make_renderer = functools.partial(
        backends.make_renderer, params.backend, params.task, attrs["robot"], r.width, r.height
    )
    return RenderJob(
        task=params.task,
        variant=args.variant,
        backend=params.backend,
        robot=attrs["robot"],
        subtasks=spec.subtasks,
        stores=stores,
        episodes=r.episodes,
        fps=int(attrs["control_freq"]),
        make_renderer=make_renderer,
        out=out,
        metrics_path=metrics_path,
    )


def run(job: RenderJob) -> None:
    inputs = [s.path for s in job.stores.values()]
    claim((job.out, MEDIA_DIR), job.metrics_path, inputs=inputs)
    with output_set(job.metrics_path, job.out) as (tmp_metrics, tmp_out):
        frames_total, seconds = render_videos(job, tmp_out)
        identity = metrics_identity("render", job.task, job.backend, job.robot, variant=job.variant)
        write_metrics(tmp_metrics, identity | {"frames": frames_total})
    ms_per_frame = round(1000 * seconds / max(1, frames_total), 1)
    write_timings(job.metrics_path, identity, {"ms_per_frame": ms_per_frame})
