"""Zarr v3 episode stores (DESIGN.md data contract), written atomically.

Layout: ``data/<key>`` (N_steps, ...) concatenated over episodes; ``meta/episode_ends``
(N_episodes,) cumulative exclusive ends; ``meta/episodes/<key>`` (N_episodes, ...);
group attributes carry the schema version, task, variant, back end and params used.
Poses are stored as (..., 7) [x, y, z, qw, qx, qy, qz], metres, in the world frame.
Each array is one chunk, so a store is a few dozen files for DVC to hash.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import uuid
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from mimicgen_pipe import poses
from mimicgen_pipe.errors import InputError

SCHEMA_VERSION = 1


@dataclass(frozen=True)
class EpisodeStore:
    """An episode store read into memory: ``data`` key -> (N_steps, ...) array,
    ``episodes`` key -> (N_episodes, ...) array, ``attrs`` the group attributes."""

    path: Path
    data: Mapping[str, np.ndarray]
    episode_ends: np.ndarray
    episodes: Mapping[str, np.ndarray]
    attrs: Mapping[str, Any]

    @property
    def n_episodes(self) -> int:
        return len(self.episode_ends)

    @property
    def episode_starts(self) -> np.ndarray:
        return np.concatenate([[0], self.episode_ends[:-1]]).astype(np.int64)

    def episode(self, i: int) -> dict[str, np.ndarray]:
        s, e = self.episode_starts[i], self.episode_ends[i]
        return {k: v[s:e] for k, v in self.data.items()}

    def poses(self, key: str) -> np.ndarray:
        """A stored pose array as (..., 4, 4) matrices."""
        arr = self.data[key] if key in self.data else self.episodes[key]
        return poses.pose_from_pq(arr[..., :3], arr[..., 3:])


def as_stored(value: np.ndarray) -> np.ndarray:
    """4x4 pose arrays become (..., 7) pq rows; everything else is stored as is."""
    value = np.asarray(value)
    if value.ndim >= 2 and value.shape[-2:] == (4, 4):
        return poses.pose_to_pq(value)
    return value


def _write_array(group: zarr.Group, name: str, value: np.ndarray) -> None:
    value = np.ascontiguousarray(value)
    chunks = value.shape if value.size else tuple(max(1, s) for s in value.shape)
    arr = group.create_array(name, shape=value.shape, dtype=value.dtype, chunks=chunks)
    if value.size:
        arr[...] = value


def write_store(
    path: str | os.PathLike,
    steps: Sequence[Mapping[str, np.ndarray]],
    episodes: Mapping[str, np.ndarray],
    attrs: Mapping[str, Any],
) -> Path:
    """Write episodes to a Zarr store at ``path``: first to a sibling temporary directory,
    then renamed into place, so an interrupted write never leaves a partial store and an
    existing store at ``path`` is replaced only by a complete one.

    steps: one mapping per episode, key -> (T_i, ...) arrays (4x4 poses allowed).
    episodes: key -> (N_episodes, ...) per-episode fields.
    """
    with atomic_directory(path) as tmp:
        root = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        root.attrs.update({"schema_version": SCHEMA_VERSION, **attrs})
        lengths = np.array([len(next(iter(s.values()))) if s else 0 for s in steps], np.int64)
        data = root.create_group("data")
        keys = list(steps[0]) if steps else []
        for key in keys:
            parts = [as_stored(s[key]) for s in steps]
            _write_array(data, key, np.concatenate(parts))
        meta = root.create_group("meta")
        _write_array(meta, "episode_ends", np.cumsum(lengths))
        ep = meta.create_group("episodes")
        for key, value in episodes.items():
            _write_array(ep, key, as_stored(value))
    return Path(path)


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary sibling directory of ``path``; when the block completes it replaces
    ``path``, and when it raises (or is interrupted) it is removed and ``path`` is untouched."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{uuid.uuid4().hex[:8]}")
    tmp.mkdir()
    try:
        yield tmp
        backup = None
        if path.exists():
            backup = path.with_name(f".{path.name}.old-{uuid.uuid4().hex[:8]}")
            path.rename(backup)
        tmp.rename(path)
        if backup is not None:
            shutil.rmtree(backup)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)


def _read_group(group: zarr.Group, prefix: str = "") -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for name, member in group.members():
        if isinstance(member, zarr.Group):
            out.update(_read_group(member, f"{prefix}{name}/"))
        else:
            out[f"{prefix}{name}"] = member[...]
    return out


def read_store(
    path: str | os.PathLike, required: Sequence[str] = (), task: str | None = None
) -> EpisodeStore:
    """Read a whole store; ``required`` lists data keys that must be present and ``task``,
    when given, the task the store must have been recorded for. Raises InputError naming
    the path and the missing piece."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: store not found")
    try:
        root = zarr.open_group(str(path), mode="r")
        attrs = dict(root.attrs)
        data = _read_group(root["data"])
        ends = np.asarray(root["meta/episode_ends"][...], dtype=np.int64)
        episodes = _read_group(root["meta/episodes"])
    except (KeyError, FileNotFoundError, ValueError) as exc:
        raise InputError(f"{path}: not an episode store ({exc})") from exc
    if attrs.get("schema_version") != SCHEMA_VERSION:
        raise InputError(
            f"{path}: schema_version {attrs.get('schema_version')!r}, expected {SCHEMA_VERSION}"
        )
    missing = [k for k in required if k not in data]
    if missing:
        raise InputError(f"{path}: missing data keys {missing}")
    if task is not None and attrs.get("task") != task:
        raise InputError(f"{path}: attrs.task is {attrs.get('task')!r}, expected {task!r}")
    return EpisodeStore(path, data, ends, episodes, attrs)
