"""A LeRobot dataset (format v3.0, as lerobot 0.4 reads it), written with pyarrow and PyAV.

Per frame (``data/chunk-000/file-000.parquet``), world frame, float32:

- ``observation.state``: the robot's keys of ExportInfo.obs_keys (``eef_*`` but
  ``eef_to_<obj>_pos``, and ``gripper_*``), concatenated in that order;
- ``observation.environment_state``: the other keys (the objects), concatenated in order;
- ``action``: dx, dy, dz [0.1 m per unit], drx, dry, drz [axis-angle, scaled as the back
  end's controller], gripper [+1 open, -1 closed];
- ``subtask_index`` int64: the subtask the frame belongs to (exporters.subtask_labels), a row
  of ``meta/subtasks.parquet``;
- with several arms (ExportInfo.arms): ``action`` holds each arm's 7 in turn, named
  ``<arm>.dx`` ...; ``observation.state`` each arm's keys (``<arm>_eef_pos`` ...); one
  ``subtask_index.<arm>`` per arm (-1 where the arm holds without a subtask);
- ``next.reward`` float32, ``next.done`` and ``next.success`` bool, LeRobot's features of a
  frame's outcome (exporters.step_outcomes): the sparse success reward after the frame's
  action, done on success or at the episode's last frame, success after the action;
- LeRobot's ``timestamp`` [s], ``frame_index``, ``episode_index``, ``index`` (global) and
  ``task_index``.

Per camera of the store, a video feature ``observation.images.<camera>``:
``videos/observation.images.<camera>/chunk-000/file-000.mp4`` (AV1 by libsvtav1, yuv420p, at
the control frequency, LeRobot's encoder settings; a new file past 200 MB), every episode's
frames one after the other; an episode's ``videos/<key>/from_timestamp`` and
``to_timestamp`` [s] in ``meta/episodes`` say where in its file it lies. Its feature's
``info`` in info.json holds the camera's calibration where the store has it:
``camera.intrinsics`` (3x3 K [px]), ``camera.fov_y`` [rad], ``camera.frame``, ``camera.pose``
(4x4, the camera in that frame [m]) and ``camera.axes`` (mimicgen_pipe/core/camera_calibration.py).

``meta/``: ``info.json`` (features with per-dimension names, a quaternion's ``<key>.qw``,
``.qx``, ``.qy``, ``.qz`` in the order written; the videos' ``video.*`` info; fps = control
frequency; ``mimicgen_pipe``: exporters.provenance, what made the data and its conventions),
``tasks.parquet`` (the task sentence),
``subtasks.parquet`` (the subtasks, e.g. "grasp cubeA", indexed by ``subtask_index``),
``episodes/chunk-000/file-000.parquet`` (length, row range, video file and time span per
episode, with per-episode stats) and ``stats.json`` (dataset stats; an image's are per
channel, shape (3, 1, 1), in [0, 1], over the frames LeRobot samples from each episode).

``README.md``: the dataset card, as LeRobot writes one (Hugging Face card metadata, then
the task, episodes, cameras, how the data was made, its conventions and info.json).

A store without term signals or subtask ends has no ``subtask_index`` and no
``subtasks.parquet``; a store without images no videos.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mimicgen_pipe.core.camera_calibration import store_calibration
from mimicgen_pipe.core.observations import QUAT_ORDER, is_quat_key, is_robot_key
from mimicgen_pipe.data.store import EpisodeStore, store_cameras
from mimicgen_pipe.formats.exporters import PROVENANCE_KEY, provenance

FILE_NAME = "lerobot"  # the dataset's folder in the export directory
WRITES = r"lerobot(/.+)?"
REQUIRED = ("actions",)
CODEBASE_VERSION = "v3.0"
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-000/file-000.parquet"
CARD_PATH = "README.md"  # the Hugging Face dataset card, in the dataset's root
CHUNKS_SIZE = 1000  # files per chunk folder, LeRobot's
VIDEO_FILE_MB = 200  # LeRobot's video_files_size_in_mb: the next episode starts a new file
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)  # LeRobot's stats keys q01 ... q99
NEXT = {"next.reward": "float32", "next.done": "bool", "next.success": "bool"}  # LeRobot's
INDEX_FEATURES = {  # LeRobot's default per-frame features
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}
# LeRobot's default encoder (encode_video_frames): AV1 by SVT-AV1 in yuv420p, a key frame
# every 2 frames (a training sampler seeks anywhere), crf 30, preset 12. Fixed, so that the
# same store gives the same bytes (SVT-AV1's output does not depend on its thread count).
VIDEO_CODEC = "libsvtav1"
VIDEO_PIX_FMT = "yuv420p"
VIDEO_OPTIONS = {"g": "2", "crf": "30", "preset": "12"}
MIN_VIDEO_WIDTH = 32  # libsvtav1 3.0 kills the process (SIGFPE) on frames under 25 px wide
_AXES = "xyz"


def check(store: EpisodeStore, info) -> str | None:
    from mimicgen_pipe.formats.exporters import missing_images, missing_keys

    why = missing_keys(store, list(REQUIRED) + [f"obs/{k}" for k in info.obs_keys])
    why = why or (None if store.n_episodes else "no episodes") or missing_images(store)
    narrow = [c for c, (_, w) in store_cameras(store.attrs).items() if w < MIN_VIDEO_WIDTH]
    if why is None and narrow:
        why = f"camera {narrow[0]!r} is narrower than {MIN_VIDEO_WIDTH} px (its video encoder)"
    return why


def state_keys(obs_keys: Sequence[str]) -> dict[str, list[str]]:
    """Feature -> the observation keys it concatenates: observation.state (the robot's) and
    observation.environment_state (the objects'); a feature without keys is left out."""
    robot = [k for k in obs_keys if is_robot_key(k)]
    objects = [k for k in obs_keys if not is_robot_key(k)]
    out = {"observation.state": robot, "observation.environment_state": objects}
    return {feature: keys for feature, keys in out.items() if keys}


def observation_features(
    obs: Mapping[str, np.ndarray], parts: Mapping[str, Sequence[str]]
) -> dict[str, np.ndarray]:
    """The low-dim features of N frames from our observations (key -> (N, ...) array), each
    feature of ``parts`` (:func:`state_keys`) its keys concatenated in order, float32 (N, D).
    The export writes them; a policy trained on it is given them in rollouts
    (mimicgen_pipe.formats.external.lerobot)."""
    return {
        feature: np.concatenate(
            [np.asarray(obs[k]).reshape(len(obs[k]), -1) for k in keys], axis=1
        ).astype(np.float32)
        for feature, keys in parts.items()
    }


def state_names(store: EpisodeStore, obs_keys: Sequence[str]) -> list[str]:
    """Per-dimension names of the keys' concatenation: a quaternion's <key>.qw, .qx, .qy, .qz
    in the order written (observations.QUAT_ORDER), <key>.<x|y|z> for up to 3 values, else
    <key>.<i>."""
    names = []
    for key in obs_keys:
        width = int(np.prod(store.data[f"obs/{key}"].shape[1:]))
        if is_quat_key(key) and width == len(QUAT_ORDER):
            parts = [f"q{c}" for c in QUAT_ORDER]
        else:
            parts = list(_AXES[:width]) if width <= len(_AXES) else [str(i) for i in range(width)]
        names += [f"{key}.{part}" for part in parts]
    return names


def subtask_text(name: str) -> str:
    """A subtask's words as the task sentence has them: grasp_cubeA -> "grasp cubeA"."""
    return name.replace("_", " ")


def _column(x: np.ndarray) -> pa.Array:
    """(N, D) -> fixed_size_list<D> (as LeRobot writes vectors); (N,) -> a plain column."""
    x = np.ascontiguousarray(x)
    if x.ndim == 1:
        return pa.array(x)
    return pa.FixedSizeListArray.from_arrays(pa.array(x.reshape(-1)), x.shape[1])


def _stats(x: np.ndarray) -> dict[str, list]:
    """Per-dimension stats over frames (population std), as LeRobot's stats.json has them."""
    x = x.reshape(len(x), -1)
    f = x.astype(np.float64)
    out = {"min": x.min(0), "max": x.max(0), "mean": f.mean(0), "std": f.std(0)}
    out |= {f"q{round(q * 100):02d}": np.quantile(f, q, axis=0) for q in QUANTILES}
    return {k: v.tolist() for k, v in out.items()} | {"count": [len(x)]}


def sampled_frames(length: int) -> np.ndarray:
    """The frames of an episode LeRobot computes image stats over: all of up to 100, else
    evenly spaced, length ** 0.75 of them (at least 100, at most 10000)."""
    n = min(length, max(100, min(int(length**0.75), 10_000)))
    return np.round(np.linspace(0, length - 1, n)).astype(int)


def image_stats(images: np.ndarray) -> dict[str, np.ndarray]:
    """One episode's image stats as LeRobot computes them: per channel over the pixels of
    its sampled frames, in [0, 1], each (3, 1, 1); count: the frames sampled. Exact, from
    each channel's histogram of its 256 levels (quantiles interpolated as numpy's)."""
    frames = images[sampled_frames(len(images))]
    levels = np.arange(256, dtype=np.float64)
    out: dict[str, list] = {}
    for channel in frames.reshape(-1, 3).T:
        counts = np.bincount(channel, minlength=256)
        n, cum = len(channel), np.cumsum(counts)
        mean = counts @ levels / n
        found = {"min": levels[counts > 0][0], "max": levels[counts > 0][-1], "mean": mean,
                 "std": np.sqrt(counts @ (levels - mean) ** 2 / n)}  # fmt: skip
        for q in QUANTILES:
            at = q * (n - 1)
            lo, hi = np.searchsorted(cum, [np.floor(at), np.ceil(at)], side="right")
            found[f"q{round(q * 100):02d}"] = lo + (at - np.floor(at)) * (hi - lo)
        for k, v in found.items():
            out.setdefault(k, []).append(v / 255.0)
    return {k: np.reshape(v, (3, 1, 1)) for k, v in out.items()} | {
        "count": np.array([len(frames)])
    }


def aggregate_image_stats(per_episode: Sequence[dict[str, np.ndarray]]) -> dict[str, list]:
    """Dataset image stats from per-episode ones, as LeRobot aggregates them: min of mins, max
    of maxes, count-weighted mean, pooled std and count-weighted quantiles."""
    counts = np.array([float(s["count"][0]) for s in per_episode])[:, None, None, None]
    total = counts.sum()
    means = np.stack([s["mean"] for s in per_episode])
    mean = (means * counts).sum(0) / total
    var = (np.stack([s["std"] for s in per_episode]) ** 2 + (means - mean) ** 2) * counts
    out = {
        "min": np.min([s["min"] for s in per_episode], axis=0),
        "max": np.max([s["max"] for s in per_episode], axis=0),
        "mean": mean,
        "std": np.sqrt(var.sum(0) / total),
    }
    for q in QUANTILES:
        key = f"q{round(q * 100):02d}"
        out[key] = (np.stack([s[key] for s in per_episode]) * counts).sum(0) / total
    return {k: v.tolist() for k, v in out.items()} | {"count": [int(total)]}


def _hf_features(features: dict) -> bytes:
    """Hugging Face ``datasets`` feature types (schema metadata), so it restores them exactly;
    videos are not in the parquet files."""
    out = {}
    for key, ft in features.items():
        if ft["dtype"] == "video":
            continue
        value = {"dtype": ft["dtype"], "_type": "Value"}
        out[key] = value if ft["shape"] == [1] else {
            "feature": value, "length": ft["shape"][0], "_type": "List"}  # fmt: skip
    return json.dumps({"info": {"features": out}}).encode()


def _index_table(index_name: str | None, column: str, strings: list[str]) -> pa.Table:
    """A parquet table as pandas writes a DataFrame indexed by strings with one int64 column
    ``column`` = 0, 1, ... (LeRobot reads tasks.parquet and subtasks.parquet with pandas and
    finds a row's string as its index)."""
    field = index_name or "__index_level_0__"
    pandas_meta = {
        "index_columns": [field],
        "column_indexes": [],
        "columns": [
            {"name": column, "field_name": column, "pandas_type": "int64",
             "numpy_type": "int64", "metadata": None},
            {"name": index_name, "field_name": field, "pandas_type": "unicode",
             "numpy_type": "object", "metadata": None},
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.3",
    }  # fmt: skip
    table = pa.table({column: pa.array(np.arange(len(strings), dtype=np.int64)),
                      field: pa.array(strings, type=pa.string())})  # fmt: skip
    return table.replace_schema_metadata({"pandas": json.dumps(pandas_meta).encode()})


def _next_file(chunk: int, file: int) -> tuple[int, int]:
    """The (chunk, file) index after this one, as LeRobot numbers them."""
    return (chunk + 1, 0) if file == CHUNKS_SIZE - 1 else (chunk, file + 1)


def write_video(
    root: Path, video_key: str, episodes: Any, fps: int, size: tuple[int, int]
) -> tuple[dict[str, list], list[dict[str, np.ndarray]], int]:
    """Encode a camera's episodes (an iterable of (T_i, H, W, 3) uint8 arrays, ``size`` (H, W))
    into the videos of ``video_key``, one after the other, a new file when the current one
    passes VIDEO_FILE_MB. Returns the episodes' ``videos/<key>/...`` columns, their image
    stats and the bytes written."""
    import av

    # SVT-AV1 prints its banner and settings to stderr at every encoder start unless told not to
    os.environ.setdefault("SVT_LOG", "1")
    names = ("chunk_index", "file_index", "from_timestamp", "to_timestamp")
    columns: dict[str, list] = {k: [] for k in names}
    stats = []
    index, container, stream, frames, size_now = (0, 0), None, None, 0, 0

    def close() -> None:
        for packet in stream.encode():
            container.mux(packet)
        container.close()

    for images in episodes:
        if container is not None and size_now >= VIDEO_FILE_MB * 1024 * 1024:
            close()
            index, container = _next_file(*index), None
        if container is None:
            path = root / VIDEO_PATH.format(
                video_key=video_key, chunk_index=index[0], file_index=index[1]
            )
            path.parent.mkdir(parents=True, exist_ok=True)
            container = av.open(str(path), "w")
            stream = container.add_stream(VIDEO_CODEC, fps, options=VIDEO_OPTIONS)
            stream.pix_fmt, stream.height, stream.width = VIDEO_PIX_FMT, *size
            frames = size_now = 0
        for image in images:
            for packet in stream.encode(av.VideoFrame.from_ndarray(image, format="rgb24")):
                size_now += packet.size
                container.mux(packet)
        columns["chunk_index"].append(index[0])
        columns["file_index"].append(index[1])
        columns["from_timestamp"].append(frames / fps)
        frames += len(images)
        columns["to_timestamp"].append(frames / fps)
        stats.append(image_stats(images))
    if container is not None:
        close()
    written = sum(f.stat().st_size for f in (root / "videos" / video_key).rglob("*.mp4"))
    return {f"videos/{video_key}/{k}": v for k, v in columns.items()}, stats, written


def video_feature(size: tuple[int, int], fps: int) -> dict[str, Any]:
    """info.json's feature of a camera's video, with the ``info`` LeRobot records."""
    h, w = size
    return {
        "dtype": "video",
        "shape": [h, w, 3],
        "names": ["height", "width", "channels"],
        "info": {
            "video.height": h,
            "video.width": w,
            "video.codec": "av1",
            "video.pix_fmt": VIDEO_PIX_FMT,
            "video.is_depth_map": False,
            "video.fps": int(fps),
            "video.channels": 3,
            "has_audio": False,
        },
    }


@dataclass(frozen=True)
class Videos:
    """What the cameras' videos add to a dataset: meta/episodes' columns (each episode's video
    file and time span [s], its image stats), stats.json's entries and info.json's features,
    one per camera, and the videos' size [bytes]."""

    episodes: dict[str, list]
    stats: dict[str, dict]
    features: dict[str, dict]
    size: int


def write(
    store: EpisodeStore, path: Path, info, step_success: np.ndarray | None = None
) -> dict[str, int]:
    """``store`` as a LeRobot dataset in the new folder ``path`` (the module's layout), with
    the export's ``info`` (exporters.ExportInfo); ``step_success``: the task's success after
    every step where the export stage evaluated it (exporters.step_outcomes). Its figures:
    image_bytes, the videos' size."""
    path = Path(path)
    (path / "meta").mkdir(parents=True)
    frames, features, labelled = frame_columns(store, info, step_success)
    write_frames(path, frames, features)
    episodes, stats = episode_columns(store, info, frames)
    videos = write_videos(path, store, info.fps)
    episodes |= videos.episodes
    episodes["meta/episodes/chunk_index"] = [0] * store.n_episodes
    episodes["meta/episodes/file_index"] = [0] * store.n_episodes
    write_meta(path, store, info, episodes, stats | videos.stats, labelled)
    meta = info_json(store, info, features | videos.features)
    (path / "meta/info.json").write_text(json.dumps(meta, indent=2))
    (path / CARD_PATH).write_text(dataset_card(store, info, meta))
    return {"image_bytes": videos.size}


def frame_columns(
    store: EpisodeStore, info, step_success: np.ndarray | None = None
) -> tuple[dict[str, np.ndarray], dict[str, dict], bool]:
    """Every frame's columns (the module's list), their info.json features, and whether the
    frames carry subtask labels (a store with term signals or subtask ends)."""
    from mimicgen_pipe.formats.exporters import step_outcomes, subtask_labels

    n_steps = int(store.episode_ends[-1])
    lengths = store.lengths
    episode_index = np.repeat(np.arange(store.n_episodes, dtype=np.int64), lengths)
    frame_index = np.arange(n_steps, dtype=np.int64) - np.repeat(store.episode_starts, lengths)
    parts = state_keys(info.obs_keys)
    frames = observation_features({k: store.data[f"obs/{k}"] for k in info.obs_keys}, parts)
    frames |= {
        "action": store.data["actions"].astype(np.float32),
        "timestamp": (frame_index / info.fps).astype(np.float32),
        "frame_index": frame_index,
        "episode_index": episode_index,
        "index": np.arange(n_steps, dtype=np.int64),
        "task_index": np.zeros(n_steps, np.int64),
    }
    outcomes = step_outcomes(store, step_success)
    frames |= {
        "next.reward": outcomes["reward"].astype(np.float32),
        "next.done": outcomes["done"],
        "next.success": outcomes["success"],
    }
    features: dict[str, dict] = {
        feature: {"dtype": "float32", "shape": [frames[feature].shape[1]],
                  "names": state_names(store, keys)}
        for feature, keys in parts.items()
    }  # fmt: skip
    action_names = info.action_names
    features["action"] = {"dtype": "float32", "shape": [len(action_names)], "names": action_names}
    features |= {key: {"dtype": dtype, "shape": [1], "names": None} for key, dtype in NEXT.items()}
    labels = {
        ("subtask_index" if not info.arms else f"subtask_index.{a}"): subtask_labels(
            store, info.subtasks, a
        )
        for a in info.label_arms
    }
    labelled = all(v is not None for v in labels.values())
    if labelled:
        for key, rows in labels.items():
            frames[key] = rows
            features[key] = {"dtype": "int64", "shape": [1], "names": None}
    return frames, features | INDEX_FEATURES, labelled


def write_frames(path: Path, frames: Mapping[str, np.ndarray], features: dict[str, dict]) -> None:
    """The frames' parquet file, with the Hugging Face feature types of ``features``."""
    table = pa.table({k: _column(v) for k, v in frames.items()})
    data_file = path / DATA_PATH.format(chunk_index=0, file_index=0)
    data_file.parent.mkdir(parents=True)
    pq.write_table(
        table.replace_schema_metadata({"huggingface": _hf_features(features)}), data_file
    )


def episode_columns(
    store: EpisodeStore, info, frames: Mapping[str, np.ndarray]
) -> tuple[dict[str, list], dict[str, dict]]:
    """meta/episodes' columns for the frames (each episode's task, length, row range and
    per-episode stats of every frame column), and the dataset's stats of every frame column."""
    starts, ends = store.episode_starts, store.episode_ends
    episodes: dict[str, list] = {
        "episode_index": list(range(store.n_episodes)),
        "tasks": [[info.task_description]] * store.n_episodes,
        "length": store.lengths.tolist(),
        "data/chunk_index": [0] * store.n_episodes,
        "data/file_index": [0] * store.n_episodes,
        "dataset_from_index": starts.tolist(),
        "dataset_to_index": ends.tolist(),
    }
    stats = {key: _stats(values) for key, values in frames.items()}
    for key, values in frames.items():
        per_episode = [_stats(values[s:e]) for s, e in zip(starts, ends, strict=True)]
        for stat in per_episode[0]:
            episodes[f"stats/{key}/{stat}"] = [p[stat] for p in per_episode]
    return episodes, stats


def write_videos(path: Path, store: EpisodeStore, fps: int) -> Videos:
    """Each camera's video (write_video), at ``fps`` [Hz], and what it adds to the dataset;
    a camera's feature info carries its calibration, ``camera.<key>`` for each key of
    mimicgen_pipe/core/camera_calibration.py's (where the store has it)."""
    from mimicgen_pipe.formats.exporters import episode_images

    calibration = store_calibration(store.attrs, str(store.path))

    episodes: dict[str, list] = {}
    stats: dict[str, dict] = {}
    features: dict[str, dict] = {}
    size = 0
    for camera, frame_size in store_cameras(store.attrs).items():
        key = f"observation.images.{camera}"
        columns, per_episode, written = write_video(
            path, key, episode_images(store, camera), fps, frame_size
        )
        episodes |= columns
        for stat in per_episode[0]:
            episodes[f"stats/{key}/{stat}"] = [p[stat].tolist() for p in per_episode]
        stats[key] = aggregate_image_stats(per_episode)
        features[key] = video_feature(frame_size, fps)
        calib = calibration.get(camera, {})
        features[key]["info"] |= {f"camera.{k}": v for k, v in calib.items()}
        size += written
    return Videos(episodes, stats, features, size)


def write_meta(
    path: Path,
    store: EpisodeStore,
    info,
    episodes: dict[str, list],
    stats: dict[str, dict],
    labelled: bool,
) -> None:
    """meta/: the episodes' parquet file, the task and (``labelled``) subtask tables and
    stats.json."""
    (path / EPISODES_PATH).parent.mkdir(parents=True)
    pq.write_table(pa.table(episodes), path / EPISODES_PATH)
    tasks = _index_table(None, "task_index", [info.task_description])
    pq.write_table(tasks, path / "meta/tasks.parquet")
    if labelled:
        names = [subtask_text(s.name) for s in info.subtasks]
        pq.write_table(
            _index_table("subtask", "subtask_index", names), path / "meta/subtasks.parquet"
        )
    (path / "meta/stats.json").write_text(json.dumps(stats, indent=2))


def info_json(store: EpisodeStore, info, features: dict[str, dict]) -> dict[str, Any]:
    """meta/info.json: the dataset's layout, sizes, fps and ``features``."""
    return {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": info.env_args["env_kwargs"]["robot"],
        "total_episodes": store.n_episodes,
        "total_frames": int(store.episode_ends[-1]),
        "total_tasks": 1,
        "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": 100,
        "video_files_size_in_mb": VIDEO_FILE_MB,
        "fps": int(info.fps),
        "splits": {"train": f"0:{store.n_episodes}"},
        "data_path": DATA_PATH,
        "video_path": VIDEO_PATH if store_cameras(store.attrs) else None,
        "features": features,
        PROVENANCE_KEY: provenance(store.attrs),
    }


# a Hugging Face dataset card's metadata as LeRobot's create_lerobot_dataset_card writes it
CARD_HEADER = """---
task_categories:
- robotics
tags:
- LeRobot
- mimicgen-pipe
configs:
- config_name: default
  data_files: data/*/*.parquet
---
"""


def dataset_card(store: EpisodeStore, info, meta: Mapping[str, Any]) -> str:
    """README.md, the dataset's card as LeRobot writes one (its metadata, then the layout
    as meta/info.json): the task, episodes, cameras, how the data was made and its
    conventions; ``meta``: info.json's content."""
    made = meta[PROVENANCE_KEY]
    conv = made["conventions"]
    cameras = store_cameras(store.attrs)
    seen = ", ".join(f"{c} ({h}x{w} px)" for c, (h, w) in cameras.items()) or "none"
    run = f"run id `{made['run_id']}`" if made["run_id"] else "no run id"
    lines = [
        CARD_HEADER,
        f"Episodes of a {made['kind']} store of mimicgen-pipe (MimicGen data generation), "
        f"exported by mimicgen-pipe {made['tool_version']} in LeRobot's dataset format "
        f"{CODEBASE_VERSION}.",
        "",
        "## Dataset Description",
        "",
        f"- **Task:** {info.task_description}",
        f"- **Episodes:** {meta['total_episodes']}, **frames:** {meta['total_frames']}, "
        f"**fps:** {meta['fps']}",
        f"- **Robot:** {made['robot']} on the {made['backend']} back end, variant "
        f"{made['variant']}",
        f"- **Cameras:** {seen}",
        f"- **How it was made:** the {made['kind']} store ({run}); the params that made it "
        f"are `{PROVENANCE_KEY}.params` in [meta/info.json](meta/info.json).",
        "",
        "## Conventions",
        "",
        f"- Positions and poses in the {conv['pose_frame']} frame; lengths in "
        f"{conv['units']['length']}, angles in {conv['units']['angle']}.",
        f"- Quaternions {conv['quaternion_order']} (feature names `<key>.qw`, ...).",
        f"- `action`: {', '.join(info.action_names)}; control mode {conv['control_mode']} "
        f"at {conv['control_freq_hz']} Hz.",
        "",
        "## Dataset Structure",
        "",
        "[meta/info.json](meta/info.json):",
        f"```json\n{json.dumps(meta, indent=4)}\n```",
        "",
    ]
    return "\n".join(lines)
