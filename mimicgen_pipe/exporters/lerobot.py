"""A LeRobot dataset (format v3.0, as lerobot 0.4 reads it), written with pyarrow alone.

Per frame (``data/chunk-000/file-000.parquet``): ``observation.state`` float32 (the store's
``obs/<key>`` for ExportInfo.obs_keys, concatenated in that order, world frame), ``action``
float32 (dx, dy, dz [0.1 m per unit], drx, dry, drz [axis-angle, scaled as the back end's
controller], gripper [+1 open, -1 closed]), and LeRobot's ``timestamp`` [s],
``frame_index``, ``episode_index``, ``index`` (global) and ``task_index``. ``meta/``:
``info.json`` (features with per-dimension names, fps = control frequency),
``tasks.parquet`` (the task sentence), ``episodes/chunk-000/file-000.parquet`` (length and
row range per episode, with per-episode stats) and ``stats.json`` (dataset stats).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mimicgen_pipe.store import EpisodeStore

FILE_NAME = "lerobot"  # the dataset's folder in the export directory
WRITES = r"lerobot(/.+)?"
REQUIRED = ("actions",)
CODEBASE_VERSION = "v3.0"
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-000/file-000.parquet"
ACTION_NAMES = ["dx", "dy", "dz", "drx", "dry", "drz", "gripper"]
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)  # LeRobot's stats keys q01 ... q99
INDEX_FEATURES = {  # LeRobot's default per-frame features
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}
_AXES = "xyzw"


def check(store: EpisodeStore, info) -> str | None:
    from mimicgen_pipe.exporters import missing_keys

    why = missing_keys(store, list(REQUIRED) + [f"obs/{k}" for k in info.obs_keys])
    return why or (None if store.n_episodes else "no episodes")


def state_names(store: EpisodeStore, obs_keys) -> list[str]:
    """Per-dimension names of observation.state: <key>.<x|y|z|w> for up to 4 values (a
    quaternion's are w, x, y, z: <key>.0 ... <key>.3), else <key>.<i>."""
    names = []
    for key in obs_keys:
        width = int(np.prod(store.data[f"obs/{key}"].shape[1:]))
        axes = _AXES if width <= 3 else None
        names += [f"{key}.{axes[i] if axes else i}" for i in range(width)]
    return names


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


def _hf_features(features: dict) -> bytes:
    """Hugging Face ``datasets`` feature types (schema metadata), so it restores them exactly."""
    out = {}
    for key, ft in features.items():
        value = {"dtype": ft["dtype"], "_type": "Value"}
        out[key] = value if ft["shape"] == [1] else {
            "feature": value, "length": ft["shape"][0], "_type": "List"}  # fmt: skip
    return json.dumps({"info": {"features": out}}).encode()


def _tasks_table(tasks: list[str]) -> pa.Table:
    """meta/tasks.parquet: LeRobot reads it with pandas, indexed by the task string."""
    pandas_meta = {
        "index_columns": ["__index_level_0__"],
        "column_indexes": [],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64",
             "numpy_type": "int64", "metadata": None},
            {"name": None, "field_name": "__index_level_0__", "pandas_type": "unicode",
             "numpy_type": "object", "metadata": None},
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.3",
    }  # fmt: skip
    table = pa.table({"task_index": pa.array(np.arange(len(tasks), dtype=np.int64)),
                      "__index_level_0__": pa.array(tasks, type=pa.string())})  # fmt: skip
    return table.replace_schema_metadata({"pandas": json.dumps(pandas_meta).encode()})


def write(store: EpisodeStore, path: Path, info) -> None:
    path = Path(path)
    (path / "meta").mkdir(parents=True)
    n_steps = int(store.episode_ends[-1])
    lengths = store.lengths
    episode_index = np.repeat(np.arange(store.n_episodes, dtype=np.int64), lengths)
    frame_index = np.arange(n_steps, dtype=np.int64) - np.repeat(store.episode_starts, lengths)
    frames = {
        "observation.state": np.concatenate(
            [store.data[f"obs/{k}"].reshape(n_steps, -1) for k in info.obs_keys], axis=1
        ).astype(np.float32),
        "action": store.data["actions"].astype(np.float32),
        "timestamp": (frame_index / info.fps).astype(np.float32),
        "frame_index": frame_index,
        "episode_index": episode_index,
        "index": np.arange(n_steps, dtype=np.int64),
        "task_index": np.zeros(n_steps, np.int64),
    }
    features = {
        "observation.state": {"dtype": "float32", "shape": [frames["observation.state"].shape[1]],
                              "names": state_names(store, info.obs_keys)},
        "action": {"dtype": "float32", "shape": [7], "names": ACTION_NAMES},
    } | INDEX_FEATURES  # fmt: skip
    table = pa.table({k: _column(v) for k, v in frames.items()})
    data_file = path / DATA_PATH.format(chunk_index=0, file_index=0)
    data_file.parent.mkdir(parents=True)
    pq.write_table(
        table.replace_schema_metadata({"huggingface": _hf_features(features)}), data_file
    )

    starts, ends = store.episode_starts, store.episode_ends
    episodes: dict[str, list] = {
        "episode_index": list(range(store.n_episodes)),
        "tasks": [[info.task_description]] * store.n_episodes,
        "length": lengths.tolist(),
        "data/chunk_index": [0] * store.n_episodes,
        "data/file_index": [0] * store.n_episodes,
        "dataset_from_index": starts.tolist(),
        "dataset_to_index": ends.tolist(),
    }
    for key, values in frames.items():
        per_episode = [_stats(values[s:e]) for s, e in zip(starts, ends, strict=True)]
        for stat in per_episode[0]:
            episodes[f"stats/{key}/{stat}"] = [p[stat] for p in per_episode]
    episodes["meta/episodes/chunk_index"] = [0] * store.n_episodes
    episodes["meta/episodes/file_index"] = [0] * store.n_episodes
    (path / EPISODES_PATH).parent.mkdir(parents=True)
    pq.write_table(pa.table(episodes), path / EPISODES_PATH)
    pq.write_table(_tasks_table([info.task_description]), path / "meta/tasks.parquet")
    stats = {key: _stats(values) for key, values in frames.items()}
    (path / "meta/stats.json").write_text(json.dumps(stats, indent=2))
    meta = {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": info.env_args["env_kwargs"]["robot"],
        "total_episodes": store.n_episodes,
        "total_frames": n_steps,
        "total_tasks": 1,
        "chunks_size": 1000,
        "data_files_size_in_mb": 100,
        "video_files_size_in_mb": 200,
        "fps": int(info.fps),
        "splits": {"train": f"0:{store.n_episodes}"},
        "data_path": DATA_PATH,
        "video_path": None,
        "features": features,
    }
    (path / "meta/info.json").write_text(json.dumps(meta, indent=2))
