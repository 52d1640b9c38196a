"""pose_noise: the parsed source demos with pose-estimation error on every object pose."""

from __future__ import annotations

import argparse
from pathlib import Path

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.outputs import claim, store_kind
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.method.pose_noise import pose_noise_level
from mimicgen_pipe.run.pose_noising import PoseNoiseJob, write_pose_noised
from mimicgen_pipe.stages import add_selection_arguments, output_path, stage_params


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument("--parsed", help="parsed source store (default: data/parsed/<task>.zarr)")
    p.add_argument(
        "--out",
        help="pose-noised store (default: data/pose_noise/<task>.zarr; at level none an "
        "unperturbed copy)",
    )


def resolve(args: argparse.Namespace) -> PoseNoiseJob:
    """The pose_noise run ``args`` ask for: the params, and the parsed store read whole and
    checked to carry no pose noise yet; writes nothing."""
    params = stage_params(args)
    pn = params.pose_noise
    noise = pose_noise_level(pn.level)  # validated with the params
    spec = backends.task_spec(params.backend, params.task)
    parsed_path = Path(args.parsed or layout.parsed_store(params.task))
    out = output_path(args.out, layout.pose_noise_store(params.task))
    store = read_store(
        parsed_path,
        required=[f"object_poses/{o}" for o in spec.objects],
        task=params.task,
        kind="parsed",
        required_episodes=["subtask_term_index"],
    )
    if "pose_noise" in store.attrs:
        raise InputError(f"{parsed_path}: already carries pose noise; give the clean parsed store")
    return PoseNoiseJob(parsed_path, out, store, spec.objects, pn.level, noise, pn.seed)


def run(job: PoseNoiseJob) -> None:
    claim((job.out, store_kind("parsed")), inputs=[job.parsed])
    write_pose_noised(job)
    print(
        f"pose_noise: {job.store.n_episodes} demos, level {job.level} "
        f"({job.noise.describe()}, seed {job.seed}) -> {job.out}"
    )
