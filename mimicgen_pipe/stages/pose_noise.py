"""pose_noise: the parsed source demos with pose-estimation error on every object pose."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.outputs import claim, store_kind
from mimicgen_pipe.data.store import read_store, write_store
from mimicgen_pipe.method.pose_noise import perturb_pose, pose_noise_level, store_attrs
from mimicgen_pipe.stages import add_selection_arguments, output_path, stage_params


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument("--parsed", help="parsed source store (default: data/parsed/<task>.zarr)")
    p.add_argument(
        "--out",
        help="pose-noised store (default: data/pose_noise/<task>.zarr; at level none an "
        "unperturbed copy)",
    )


def run(args: argparse.Namespace) -> None:
    params = stage_params(args)
    pn = params.pose_noise
    noise = pose_noise_level(pn.level)  # validated with the params
    spec = backends.task_spec(params.backend, params.task)
    parsed_path = Path(args.parsed or layout.parsed_store(params.task))
    out = output_path(args.out, layout.pose_noise_store(params.task))
    keys = [f"object_poses/{o}" for o in spec.objects]
    claim((out, store_kind("parsed")), inputs=[parsed_path])
    store = read_store(
        parsed_path,
        required=keys,
        task=params.task,
        kind="parsed",
        required_episodes=["subtask_term_index"],
    )
    if "pose_noise" in store.attrs:
        raise InputError(f"{parsed_path}: already carries pose noise; give the clean parsed store")
    rng = np.random.default_rng(pn.seed)
    # Every recorded pose is an independent estimate, as a per-frame pose estimator would give.
    noisy = {k: perturb_pose(store.poses(k), noise, rng) for k in keys}
    starts, ends = store.episode_starts, store.episode_ends
    steps = []
    for i in range(store.n_episodes):
        ep = store.episode(i)
        ep.update({k: v[starts[i] : ends[i]] for k, v in noisy.items()})
        steps.append(ep)
    episodes = dict(store.episodes)
    if "initial_object_poses" in episodes:
        # keep the store self-consistent: the initial poses are the first observed ones
        episodes["initial_object_poses"] = np.stack([noisy[k][starts] for k in keys], axis=1)
    attrs = {**store.attrs, "pose_noise": store_attrs(pn.level, noise, pn.seed)}
    write_store(out, "parsed", steps, episodes, attrs)
    print(
        f"pose_noise: {store.n_episodes} demos, level {pn.level} ({noise.describe()}, "
        f"seed {pn.seed}) -> {out}"
    )
