"""Pose-estimation error (paper T) on the parsed source demos: the pose_noise stage's job and
the pose-noised store it writes (mimicgen_pipe.method.pose_noise draws the noise). The stage
resolves its job, the parsed store read and checked to be clean, before anything is written
(mimicgen_pipe.stages.pose_noise)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mimicgen_pipe.data.store import EpisodeStore, write_store
from mimicgen_pipe.method.pose_noise import PoseNoise, perturb_pose, store_attrs


@dataclass(frozen=True)
class PoseNoiseJob:
    """One pose_noise run, checked: the clean parsed store at ``parsed`` (``store``, read
    whole), every pose of its ``objects`` perturbed by ``noise`` (params' pose_noise.level
    ``level``; position [m] and rotation [rad] bounds) drawn from ``seed``, written as the
    pose-noised store ``out`` (at level none an unperturbed copy)."""

    parsed: Path
    out: Path
    store: EpisodeStore
    objects: tuple[str, ...]
    level: str | list[float]
    noise: PoseNoise
    seed: int


def write_pose_noised(job: PoseNoiseJob) -> None:
    """The pose-noised store: the parsed store with each object pose (world frame) replaced
    by an independent noisy estimate, as a per-frame pose estimator would give, its initial
    object poses the first noisy ones, and the noise recorded in attrs["pose_noise"]."""
    store = job.store
    keys = [f"object_poses/{o}" for o in job.objects]
    rng = np.random.default_rng(job.seed)
    noisy = {k: perturb_pose(store.poses(k), job.noise, rng) for k in keys}
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
    attrs = {**store.attrs, "pose_noise": store_attrs(job.level, job.noise, job.seed)}
    write_store(job.out, "parsed", steps, episodes, attrs)
