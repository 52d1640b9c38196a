"""robomimic HDF5, with MimicGen's per-demo ``datagen_info`` (the source stage reads such a
file back as source demos: mimicgen_pipe/robomimic_source.py).

Layout written (robomimic's dataset schema; MimicGen's generated files add datagen_info)::

  data                  attrs: total (steps), env_args (JSON: env_name, type, env_kwargs),
                        subtasks (JSON: the task's subtask names, in order)
  data/demo_<i>         attrs: num_samples, seed, success
      actions           (T, 7) float32, the normalised delta-pose actions
      states            (T, S) float32, the back end's flat simulator state before each action
      rewards, dones    (T,) float64 / int64: 1 at the last step of a successful demo / last step
      subtask_index     (T,) int64: the subtask each step belongs to, an index into
                        data.attrs["subtasks"] (exporters.subtask_labels)
      obs/<key>         (T, ...) float32, the low-dim observations (mimicgen_pipe.observations)
      obs/<camera>_image  (T, H, W, 3) uint8 RGB, one per camera of the store, row t seen
                        with obs/<key> row t; HDF5 chunks of 4 images, gzip level 4
      next_obs/<key>    obs/<key> one step on (the last step repeated); an image's is a
                        virtual dataset over its obs/ rows (no second copy of the images)
      datagen_info/eef_pose, target_pose, object_poses/<obj>   (T, 4, 4) float64, world frame
      datagen_info/subtask_term_signals/<signal>               (T,) int64
      datagen_info/gripper_action                              (T, 1) float32
      src_demo_inds     (M,) int64: the source demo each subtask's segment came from
  mask/train, mask/valid  demo names (bytes): the last valid_fraction of demos are valid

A task with several arms (ExportInfo.arms) has actions (T, 7 x arms), each arm's 7 in the
order of ``data.attrs["arms"]`` (JSON), named by ``data.attrs["action_names"]`` (JSON:
``left.dx`` ... ``right.gripper``); per arm ``subtask_index/<arm>`` (-1 where the arm holds
without a subtask), ``datagen_info/eef_pose/<arm>``, ``target_pose/<arm>`` and
``gripper_action/<arm>``; the observations carry each arm's keys prefixed with its name.

A store without term signals or subtask ends (a source store brought in from a file) has no
``subtask_index`` and no ``subtasks`` attribute.
"""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np

from mimicgen_pipe.store import EpisodeStore, image_key, store_cameras
from mimicgen_pipe.taskspec import arm_key

# Images: gzip (HDF5's own deflate filter, which every HDF5 reader has; h5py's lzf is h5py's
# alone and kept 1.38x of 84x84 renders against gzip's 1.56x) at level 4, over chunks of 4
# frames: deflate then finds each frame's likeness to the one before (2.16x, 28% less than
# one frame a chunk), while a sampler's 10-frame window reads as fast and one frame in
# 1.5 ms rather than 0.7 ms (stack_cube, 84x84, measured for docs/exports.md)
IMAGE_ROWS_PER_CHUNK = 4
IMAGE_COMPRESSION = {"compression": "gzip", "compression_opts": 4}

FILE_NAME = "demos.hdf5"  # what write() makes in the export directory
WRITES = r"demos\.hdf5"
REQUIRED = ("actions", "env_state", "eef_pose", "target_pose", "gripper")


def _required(info) -> list[str]:
    """The arrays a store needs: REQUIRED, each arm's own under its name (arm_key)."""
    own = ("eef_pose", "target_pose", "gripper")
    arms = [arm_key(k, a) for a in info.label_arms for k in own]
    return [k for k in REQUIRED if k not in own] + arms + [f"obs/{k}" for k in info.obs_keys]


def check(store: EpisodeStore, info) -> str | None:
    from mimicgen_pipe.exporters import missing_images, missing_keys

    why = missing_keys(store, _required(info))
    if why is None and store.n_episodes == 0:
        why = "no episodes"
    return why or missing_images(store)


def split(n: int, valid_fraction: float) -> tuple[list[int], list[int]]:
    """(train, valid) demo indices: the last round(n * valid_fraction) demos are valid (at
    least one when the fraction is positive and there are two demos or more)."""
    n_valid = int(round(n * valid_fraction))
    if valid_fraction > 0 and n >= 2:
        n_valid = min(max(n_valid, 1), n - 1)
    return list(range(n - n_valid)), list(range(n - n_valid, n))


def _write_images(g: h5py.Group, key: str, images: np.ndarray) -> int:
    """``obs/<camera>_image`` and its next_obs (a virtual dataset: rows 1 .. T-1, then T-1
    again); returns the bytes the images take in the file."""
    t = len(images)
    chunks = (min(IMAGE_ROWS_PER_CHUNK, t), *images.shape[1:])
    obs = g.create_dataset(key, data=images, chunks=chunks, **IMAGE_COMPRESSION)
    layout = h5py.VirtualLayout(images.shape, images.dtype)
    source = h5py.VirtualSource(obs)
    if t > 1:
        layout[: t - 1] = source[1:]
    layout[t - 1] = source[t - 1]
    g.create_virtual_dataset("next_" + key, layout)
    return int(obs.id.get_storage_size())


def write(store: EpisodeStore, path: Path, info) -> dict[str, int]:
    from mimicgen_pipe.exporters import episode_images, subtask_labels

    objects = [k.removeprefix("object_poses/") for k in store.data if k.startswith("object_poses/")]
    signals = [k for k in store.data if k.startswith("subtask_signals/")]
    images = {image_key(c): episode_images(store, c) for c in store_cameras(store.attrs)}
    obs_keys = [k for k in store.data if k.startswith("obs/") and k not in images]
    success = store.episodes.get("success", np.ones(store.n_episodes, bool))
    arms = info.label_arms
    own = [arm_key(k, a) for k in ("eef_pose", "target_pose") for a in arms]
    pose_keys = own + [f"object_poses/{o}" for o in objects]
    matrices = {key: store.poses(key) for key in pose_keys}  # (N_steps, 4, 4) each
    labels = {arm_key("subtask_index", a): subtask_labels(store, info.subtasks, a) for a in arms}
    labelled = all(v is not None for v in labels.values())
    image_bytes = 0
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        for i in range(store.n_episodes):
            ep = store.episode(i)
            steps = len(ep["actions"])
            g = data.create_group(f"demo_{i}")
            g.attrs["num_samples"] = steps
            g.attrs["success"] = bool(success[i])
            if "seed" in store.episodes:
                g.attrs["seed"] = int(store.episodes["seed"][i])
            g.create_dataset("actions", data=ep["actions"])
            g.create_dataset("states", data=ep["env_state"])
            last = np.zeros(steps, np.int64)
            last[-1] = 1
            g.create_dataset("rewards", data=(last * bool(success[i])).astype(np.float64))
            g.create_dataset("dones", data=last)
            s, e = store.episode_starts[i], store.episode_ends[i]
            if labelled:
                for key, rows in labels.items():
                    g.create_dataset(key, data=rows[s:e])
            for key, per_episode in images.items():
                image_bytes += _write_images(g, key, next(per_episode))
            for key in obs_keys:
                g.create_dataset(key, data=ep[key])
                # the observation after each step; the store has none after the last one,
                # which repeats (robomimic reads next_obs by default, BC ignores it)
                nxt = np.concatenate([ep[key][1:], ep[key][-1:]])
                g.create_dataset("next_" + key, data=nxt)
            info_g = g.create_group("datagen_info")
            for key in pose_keys:
                info_g.create_dataset(key, data=matrices[key][s:e])
            for key in signals:
                name = key.removeprefix("subtask_signals/")
                info_g.create_dataset(f"subtask_term_signals/{name}", data=ep[key].astype(np.int64))
            for a in arms:
                info_g.create_dataset(
                    arm_key("gripper_action", a), data=ep[arm_key("gripper", a)][:, None]
                )
            if "source_demo" in store.episodes:
                g.create_dataset("src_demo_inds", data=store.episodes["source_demo"][i])
        data.attrs["total"] = int(store.episode_ends[-1])
        data.attrs["env_args"] = json.dumps(info.env_args)
        if labelled:
            data.attrs["subtasks"] = json.dumps([sub.name for sub in info.subtasks])
        if info.arms:
            data.attrs["arms"] = json.dumps(list(info.arms))
            data.attrs["action_names"] = json.dumps(info.action_names)
        train, valid = split(store.n_episodes, info.valid_fraction)
        for name, idx in (("train", train), ("valid", valid)):
            f.create_dataset(f"mask/{name}", data=np.array([f"demo_{i}" for i in idx], dtype="S"))
    return {"image_bytes": image_bytes}
