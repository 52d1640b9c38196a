"""robomimic HDF5, with MimicGen's per-demo ``datagen_info`` (the source stage reads such a
file back as source demos: mimicgen_pipe/sources/robomimic_source.py).

Layout written (robomimic's dataset schema, MimicGen's key names; MimicGen's generated files
add datagen_info)::

  data                  attrs: total (steps), env_args (JSON: robomimic's env_meta fields
                        env_name, type, env_kwargs, and a note that robomimic cannot build
                        it, not being a robosuite env; with images env_kwargs also has
                        camera_names, camera_heights and camera_widths, as robomimic's
                        env_meta), mimicgen_pipe (JSON: exporters.provenance, what made the
                        data and its conventions, quaternions xyzw), subtasks (JSON: the task's
                        subtask names, in order), object_keys (JSON: what obs/object
                        concatenates), camera_calibration (JSON, with images: robomimic
                        camera name -> mimicgen_pipe/core/camera_calibration.py's calibration)
  data/demo_<i>         attrs: num_samples, seed, success
      actions           (T, 7) float32, the normalised delta-pose actions
      states            (T, S) float32, the back end's flat simulator state before each action
      rewards           (T,) float64: 1.0 where the task is achieved after the step, else 0.0
      dones             (T,) int64: 1 on success or at the last step (robomimic's done_mode 2;
                        exporters.step_outcomes)
      subtask_index     (T,) int64: the subtask each step belongs to, an index into
                        data.attrs["subtasks"] (exporters.subtask_labels)
      obs/<key>         (T, ...) float32, the low-dim observations by MimicGen's names
                        (obs_name): robot0_eef_pos, robot0_eef_quat, robot0_gripper_qpos,
                        the objects' keys as the store names them (cubeA_pos, ...), and
                        ``object``: train.obs_keys' object keys concatenated in their order;
                        world frame, every quaternion xyzw as robosuite's (the store's wxyz
                        reordered: robosuite_quat)
      obs/<camera>_image  (T, H, W, 3) uint8 RGB, one per camera of the store (agentview_image,
                        robot0_eye_in_hand_image), row t seen with obs/<key> row t; HDF5
                        chunks of 4 images, gzip level 4
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
``gripper_action/<arm>``; arm i's own observations are ``robot<i>_eef_pos`` ... (robosuite's
names for a task's robots), its other keys keep the arm's name (``left_eef_to_cubeA_pos``).

A store without term signals or subtask ends (a source store brought in from a file) has no
``subtask_index`` and no ``subtasks`` attribute.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import h5py
import numpy as np

from mimicgen_pipe.core.camera_calibration import store_calibration
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.observations import QUAT_ORDER as OUR_QUAT_ORDER
from mimicgen_pipe.core.observations import is_quat_key
from mimicgen_pipe.core.taskspec import arm_key
from mimicgen_pipe.data.store import EpisodeStore, store_cameras
from mimicgen_pipe.formats import hdf5
from mimicgen_pipe.formats.exporters import PROVENANCE_KEY, provenance

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
OBJECT_KEY = "object"  # MimicGen's (robosuite's) concatenated object observation
# an arm's own observations, which robosuite names robot<i>_<key>
_ROBOT_KEY = re.compile(r"(?:(?P<arm>[A-Za-z0-9]+)_)?(?P<key>eef_pos|eef_quat|gripper_qpos)")
_HAND_CAMERAS = ("eye_in_hand",)  # robosuite names a robot's wrist camera robot0_eye_in_hand
# robosuite's quaternion order (its robot0_eef_quat, an object's <obj>_quat), which robomimic
# and MimicGen datasets hold: every quaternion of obs/ is written so
QUAT_ORDER = "xyzw"
# env_args' word that it is not an env robomimic builds (robomimic's env_meta has no such key)
ENV_NOTE = (
    "not a robosuite or gym env: env_name is mimicgen-pipe's <backend>:<task>, which "
    "mimicgen-pipe's mimicgen_pipe.backends.make_env(backend, task, robot) rebuilds; robomimic "
    "cannot build it (train with rollouts off)"
)


def obs_name(key: str, arms: Sequence[str] = ()) -> str:
    """The export's (MimicGen's) name of our observation key: eef_pos, eef_quat and
    gripper_qpos are robot0_eef_pos ...; with several ``arms``, <arm>_eef_pos is
    robot<i>_eef_pos, i the arm's index in ``arms``; a camera's ``<camera>_image`` is
    ``camera_name(camera)_image``; every other key (the objects') keeps its name."""
    if key.endswith("_image"):
        return f"{camera_name(key.removesuffix('_image'))}_image"
    m = _ROBOT_KEY.fullmatch(key)
    if m is None or (m["arm"] is None) != (not arms) or (arms and m["arm"] not in arms):
        return key
    return f"robot{list(arms).index(m['arm']) if arms else 0}_{m['key']}"


def camera_name(camera: str) -> str:
    """robosuite's name of a camera: the wrist camera is the robot's, robot0_eye_in_hand."""
    return f"robot0_{camera}" if camera in _HAND_CAMERAS else camera


def arms_of(keys: Sequence[str]) -> tuple[str, ...]:
    """The arms of a task of several from its observation keys (``<arm>_eef_pos`` ...), in
    the order they first appear (mimicgen_pipe.core.observations lists them in the task's)."""
    found = (m["arm"] for k in keys if (m := _ROBOT_KEY.fullmatch(k)) and m["arm"])
    return tuple(dict.fromkeys(found))


def object_keys(obs_keys: Sequence[str]) -> list[str]:
    """The keys of ``obs_keys`` that ``obs/object`` concatenates: the objects' (those
    LeRobot's export puts in observation.environment_state), in order."""
    from mimicgen_pipe.core.observations import is_robot_key

    return [k for k in obs_keys if not is_robot_key(k)]


def robosuite_quat(key: str, value: np.ndarray) -> np.ndarray:
    """``value`` of our observation ``key`` in robosuite's convention: a quaternion's
    (observations.is_quat_key) components reordered from ours (observations.QUAT_ORDER,
    wxyz) to QUAT_ORDER (xyzw); any other key's as it is."""
    value = np.asarray(value)
    if not is_quat_key(key) or value.shape[-1:] != (4,):
        return value
    return value[..., [OUR_QUAT_ORDER.index(c) for c in QUAT_ORDER]]


def robomimic_obs(
    obs: Mapping[str, np.ndarray], obs_keys: Sequence[str], arms: Sequence[str] = ()
) -> dict[str, np.ndarray]:
    """The export's ``obs/`` arrays of T steps from ours (key -> (T, ...) array): every key
    by its :func:`obs_name`, quaternions xyzw (:func:`robosuite_quat`), and ``object``,
    :func:`object_keys` of ``obs_keys`` flattened and concatenated, float32 (T, D) (absent
    when there are none)."""
    obs = {k: robosuite_quat(k, v) for k, v in obs.items()}
    out = {obs_name(k, arms): v for k, v in obs.items()}
    parts = [obs[k].reshape(len(obs[k]), -1) for k in object_keys(obs_keys)]
    if parts:
        out[OBJECT_KEY] = np.concatenate(parts, axis=1).astype(np.float32)
    return out


def _required(info) -> list[str]:
    """The arrays a store needs: REQUIRED, each arm's own under its name (arm_key)."""
    own = ("eef_pose", "target_pose", "gripper")
    arms = [arm_key(k, a) for a in info.label_arms for k in own]
    return [k for k in REQUIRED if k not in own] + arms + [f"obs/{k}" for k in info.obs_keys]


def check(store: EpisodeStore, info) -> str | None:
    from mimicgen_pipe.formats.exporters import missing_images, missing_keys

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
    obs = hdf5.dataset(g, key, data=images, chunks=chunks, **IMAGE_COMPRESSION)
    layout = hdf5.virtual_layout(g.file, images.shape, images.dtype)
    source = h5py.VirtualSource(obs)
    if t > 1:
        layout[: t - 1] = source[1:]
    layout[t - 1] = source[t - 1]
    hdf5.virtual_dataset(g, "next_" + key, layout)
    return int(obs.id.get_storage_size())


def env_args(store: EpisodeStore, info) -> dict:
    """``data.attrs["env_args"]``: the export's (exporters.ExportInfo.env_args: robomimic's
    env_meta fields env_name, type, env_kwargs) with ``note`` (ENV_NOTE), with a store
    of images its cameras as robomimic's env_meta names them in ``env_kwargs``:
    ``camera_names`` (robosuite's names, their images ``obs/<name>_image``), and
    ``camera_heights``, ``camera_widths`` [px] (one number for cameras of one size, as
    robomimic writes them, else one per camera)."""
    args = dict(info.env_args, note=ENV_NOTE)
    cameras = store_cameras(store.attrs)
    if cameras:
        heights, widths = ([size[i] for size in cameras.values()] for i in (0, 1))
        args["env_kwargs"] = dict(args["env_kwargs"]) | {
            "camera_names": [camera_name(c) for c in cameras],
            "camera_heights": heights[0] if len(set(heights)) == 1 else heights,
            "camera_widths": widths[0] if len(set(widths)) == 1 else widths,
        }
    return args


def _write_obs(g: h5py.Group, ep: Mapping[str, np.ndarray], info) -> None:
    """A demo's low-dim ``obs/`` and ``next_obs/`` (robomimic_obs of its observations)."""
    ours = {k.removeprefix("obs/"): v for k, v in ep.items() if k.startswith("obs/")}
    ours = {k: v for k, v in ours.items() if not k.endswith("_image")}
    for key, value in robomimic_obs(ours, info.obs_keys, info.arms).items():
        hdf5.dataset(g, f"obs/{key}", data=value)
        # the observation after each step; the store has none after the last one, which
        # repeats (robomimic reads next_obs by default, BC ignores it)
        hdf5.dataset(g, f"next_obs/{key}", data=np.concatenate([value[1:], value[-1:]]))


def _write_datagen_info(g: h5py.Group, store: EpisodeStore, i: int, info, matrices) -> None:
    """A demo's MimicGen ``datagen_info`` (the poses as 4x4 matrices) and src_demo_inds."""
    ep = store.episode(i)
    s, e = store.episode_starts[i], store.episode_ends[i]
    info_g = hdf5.group(g, "datagen_info")
    for key, rows in matrices.items():
        hdf5.dataset(info_g, key, data=rows[s:e])
    for key in (k for k in store.data if k.startswith("subtask_signals/")):
        name = key.removeprefix("subtask_signals/")
        hdf5.dataset(info_g, f"subtask_term_signals/{name}", data=ep[key].astype(np.int64))
    for a in info.label_arms:
        gripper = ep[arm_key("gripper", a)][:, None]
        hdf5.dataset(info_g, arm_key("gripper_action", a), data=gripper)
    if "source_demo" in store.episodes:
        hdf5.dataset(g, "src_demo_inds", data=store.episodes["source_demo"][i])


def write(
    store: EpisodeStore, path: Path, info, step_success: np.ndarray | None = None
) -> dict[str, int]:
    """``store`` as robomimic HDF5 at ``path``; ``step_success``: the task's success after
    every step where the export stage evaluated it (exporters.step_outcomes). Its figures:
    image_bytes, the bytes the images take in the file."""
    from mimicgen_pipe.formats.exporters import episode_images, step_outcomes, subtask_labels

    objects = [k.removeprefix("object_poses/") for k in store.data if k.startswith("object_poses/")]
    cameras = store_cameras(store.attrs)
    images = {f"obs/{camera_name(c)}_image": episode_images(store, c) for c in cameras}
    success = store.episodes.get("success", np.ones(store.n_episodes, bool))
    arms = info.label_arms
    own = [arm_key(k, a) for k in ("eef_pose", "target_pose") for a in arms]
    pose_keys = own + [f"object_poses/{o}" for o in objects]
    matrices = {key: store.poses(key) for key in pose_keys}  # (N_steps, 4, 4) each
    labels = {arm_key("subtask_index", a): subtask_labels(store, info.subtasks, a) for a in arms}
    labelled = all(v is not None for v in labels.values())
    outcomes = step_outcomes(store, step_success)
    image_bytes = 0
    with hdf5.create(path) as f:
        data = hdf5.group(f, "data")
        for i in range(store.n_episodes):
            ep = store.episode(i)
            s, e = store.episode_starts[i], store.episode_ends[i]
            g = hdf5.group(data, f"demo_{i}")
            g.attrs["num_samples"] = int(e - s)
            g.attrs["success"] = bool(success[i])
            if "seed" in store.episodes:
                g.attrs["seed"] = int(store.episodes["seed"][i])
            hdf5.dataset(g, "actions", data=ep["actions"])
            hdf5.dataset(g, "states", data=ep["env_state"])
            hdf5.dataset(g, "rewards", data=outcomes["reward"][s:e])
            hdf5.dataset(g, "dones", data=outcomes["done"][s:e].astype(np.int64))
            if labelled:
                for key, rows in labels.items():
                    hdf5.dataset(g, key, data=rows[s:e])
            for key, per_episode in images.items():
                image_bytes += _write_images(g, key, next(per_episode))
            _write_obs(g, ep, info)
            _write_datagen_info(g, store, i, info, matrices)
        _write_data_attrs(data, store, info, labelled)
        train, valid = split(store.n_episodes, info.valid_fraction)
        for name, idx in (("train", train), ("valid", valid)):
            names = np.array([f"demo_{i}" for i in idx], dtype="S")
            hdf5.dataset(f, f"mask/{name}", data=names)
    return {"image_bytes": image_bytes}


def _write_data_attrs(data: h5py.Group, store: EpisodeStore, info, labelled: bool) -> None:
    """The ``data`` group's attrs (the module's list)."""
    data.attrs["total"] = int(store.episode_ends[-1])
    data.attrs["env_args"] = json.dumps(env_args(store, info))
    data.attrs["object_keys"] = json.dumps(object_keys(info.obs_keys))
    data.attrs[PROVENANCE_KEY] = json.dumps(provenance(store.attrs, QUAT_ORDER))
    if labelled:
        data.attrs["subtasks"] = json.dumps([sub.name for sub in info.subtasks])
    if info.arms:
        data.attrs["arms"] = json.dumps(list(info.arms))
        data.attrs["action_names"] = json.dumps(info.action_names)
    calibration = store_calibration(store.attrs, str(store.path))
    if calibration:
        named = {camera_name(c): v for c, v in calibration.items()}
        data.attrs["camera_calibration"] = json.dumps(named)


_CHECK_ROWS = 1 << 16  # rows of a dataset checked at a time: memory stays small


def check_finite(path: Path) -> None:
    """InputError naming the file and the dataset unless every float ``actions`` and
    ``obs/<key>`` of each ``data/<demo>`` of the robomimic file at ``path`` is finite: a
    NaN handed to robomimic ends its training pages later, in its own traceback."""
    try:
        with h5py.File(path, "r") as f:
            data = f.get("data")
            if not isinstance(data, h5py.Group):
                raise InputError(f"{path}: no data group (not a robomimic dataset)")
            for name, demo in data.items():
                if not isinstance(demo, h5py.Group):
                    continue
                obs = demo.get("obs")
                keys = [f"obs/{k}" for k in obs] if isinstance(obs, h5py.Group) else []
                for key in ["actions", *keys]:
                    _check_finite_rows(path, f"data/{name}/{key}", demo.get(key))
    except OSError as exc:
        raise InputError(f"{path}: not a readable HDF5 file ({exc})") from exc


def _check_finite_rows(path: Path, key: str, dataset: object) -> None:
    if not isinstance(dataset, h5py.Dataset) or dataset.dtype.kind != "f" or not dataset.shape:
        return
    for start in range(0, dataset.shape[0], _CHECK_ROWS):
        rows = dataset[start : start + _CHECK_ROWS]
        bad = ~np.isfinite(rows.reshape(len(rows), -1)).all(axis=1)
        if bad.any():
            raise InputError(
                f"{path}: {key}: NaN or infinite value at step {start + int(np.argmax(bad))}"
            )
