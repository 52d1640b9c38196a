"""Zarr v3 episode stores (DESIGN.md data contract), written atomically.

Layout: ``data/<key>`` (N_steps, ...) concatenated over episodes; ``meta/episode_ends``
(N_episodes,) cumulative exclusive ends; ``meta/episodes/<key>`` (N_episodes, ...);
group attributes carry the schema version, task, variant, back end and params used.
Poses are stored as (..., 7) [x, y, z, qw, qx, qy, qz], metres, in the world frame.
Each array is one chunk, so a store is a few dozen files for DVC to hash. Every chunk is
written (also one that holds only zeros) and carries a crc32c checksum, so a missing or
damaged chunk is an error when read, never a silent array of zeros.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zarr
from zarr.codecs import Crc32cCodec, ZstdCodec

from mimicgen_pipe import poses
from mimicgen_pipe.errors import InputError
from mimicgen_pipe.outputs import atomic_directory

SCHEMA_VERSION = 2  # 2: crc32c on every chunk, every chunk written, attrs.kind
STORE_KINDS = ("source", "parsed", "generated", "failed")
# zstd as zarr's default, then a checksum of the compressed bytes
_CODECS = (ZstdCodec(level=0, checksum=False), Crc32cCodec())


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

    @property
    def lengths(self) -> np.ndarray:
        """(N_episodes,) int64 steps per episode."""
        return self.episode_ends - self.episode_starts

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
    arr = group.create_array(
        name,
        shape=value.shape,
        dtype=value.dtype,
        chunks=chunks,
        compressors=_CODECS,
        config={"write_empty_chunks": True},
    )
    if value.size:
        arr[...] = value


def write_store(
    path: str | os.PathLike,
    kind: str,
    steps: Sequence[Mapping[str, np.ndarray]],
    episodes: Mapping[str, np.ndarray],
    attrs: Mapping[str, Any],
) -> Path:
    """Write episodes to a Zarr store at ``path``: first to a sibling temporary directory,
    then renamed into place, so an interrupted write never leaves a partial store and an
    existing store at ``path`` is replaced only by a complete one.

    kind: what the store holds, one of STORE_KINDS (readers check it).
    steps: one mapping per episode, key -> (T_i, ...) arrays (4x4 poses allowed).
    episodes: key -> (N_episodes, ...) per-episode fields.
    """
    if kind not in STORE_KINDS:
        raise ValueError(f"store kind {kind!r}: expected one of {STORE_KINDS}")
    with atomic_directory(path) as tmp:
        root = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        root.attrs.update({"schema_version": SCHEMA_VERSION, **attrs, "kind": kind})
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


def _read_group(path: Path, group: zarr.Group, prefix: str) -> dict[str, np.ndarray]:
    """Every array under ``group``, keyed by its path in the store; a missing chunk or a
    chunk whose checksum does not match is an InputError naming the array."""
    out: dict[str, np.ndarray] = {}
    for name, member in group.members():
        key = f"{prefix}{name}"
        if isinstance(member, zarr.Group):
            out.update(_read_group(path, member, f"{key}/"))
            continue
        if member.nchunks_initialized < member.nchunks:
            raise InputError(
                f"{path}: {key}: {member.nchunks - member.nchunks_initialized} of "
                f"{member.nchunks} chunk(s) missing (store incomplete or damaged; re-run the "
                "stage that wrote it)"
            )
        try:
            out[key] = member[...]
        except Exception as exc:  # zarr raises ValueError/RuntimeError by codec
            raise InputError(
                f"{path}: {key}: a chunk cannot be decoded ({type(exc).__name__}: "
                f"{str(exc)[:80]}); the store is damaged, re-run the stage that wrote it"
            ) from exc
    return out


def _strip(prefix: str, arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {k[len(prefix) :]: v for k, v in arrays.items()}


def _is_pose_key(key: str) -> bool:
    """Keys stored as (..., 7) pose rows."""
    return key in ("eef_pose", "target_pose", "initial_object_poses") or key.startswith(
        "object_poses/"
    )


def _check_bookkeeping(
    path: Path, data: Mapping[str, np.ndarray], ends: np.ndarray, episodes: Mapping[str, Any]
) -> None:
    """Episode ends cumulative and covering every data array; per-episode arrays one row per
    episode; pose arrays 7 wide; subtask ends (parsed stores) inside their episodes."""
    if ends.ndim != 1 or (len(ends) and (ends[0] < 0 or np.any(np.diff(ends) < 0))):
        raise InputError(f"{path}: meta/episode_ends: expected non-decreasing ends, got {ends}")
    n_steps = int(ends[-1]) if len(ends) else 0
    for key, value in data.items():
        if value.shape[:1] != (n_steps,):
            raise InputError(
                f"{path}: data/{key}: {value.shape[0] if value.ndim else 0} steps, expected "
                f"{n_steps} (meta/episode_ends)"
            )
    for key, value in episodes.items():
        if value.shape[:1] != (len(ends),):
            raise InputError(
                f"{path}: meta/episodes/{key}: {value.shape[0] if value.ndim else 0} rows, "
                f"expected one per episode ({len(ends)})"
            )
    for prefix, arrays in (("data/", data), ("meta/episodes/", episodes)):
        for key, value in arrays.items():
            if _is_pose_key(key) and value.shape[-1:] != (7,):
                raise InputError(
                    f"{path}: {prefix}{key}: shape {value.shape}, expected (..., 7) poses "
                    "[x, y, z, qw, qx, qy, qz]"
                )
    term = episodes.get("subtask_term_index")
    if term is not None:
        lengths = np.diff(np.concatenate([[0], ends]))
        for i, (row, length) in enumerate(zip(np.atleast_2d(term), lengths, strict=False)):
            if np.any(row < 1) or np.any(row > length) or np.any(np.diff(row) < 0):
                raise InputError(
                    f"{path}: meta/episodes/subtask_term_index: episode {i}: subtask ends "
                    f"{row.tolist()} are not increasing inside the episode's {length} steps"
                )


def _check_finite(
    path: Path, data: Mapping[str, np.ndarray], ends: np.ndarray, episodes: Mapping[str, Any]
) -> None:
    """Every float array finite; the first bad value is named by array, episode and step."""
    for key, value in data.items():
        if value.dtype.kind != "f" or np.isfinite(value).all():
            continue
        step = int(np.argmax(~np.isfinite(value).reshape(len(value), -1).all(axis=1)))
        ep = int(np.searchsorted(ends, step, side="right"))
        start = int(ends[ep - 1]) if ep else 0
        raise InputError(
            f"{path}: data/{key}: NaN or infinite value at episode {ep}, step {step - start} "
            f"(row {step})"
        )
    for key, value in episodes.items():
        if value.dtype.kind != "f" or np.isfinite(value).all():
            continue
        ep = int(np.argmax(~np.isfinite(value).reshape(len(value), -1).all(axis=1)))
        raise InputError(f"{path}: meta/episodes/{key}: NaN or infinite value at episode {ep}")


def read_store(
    path: str | os.PathLike,
    required: Sequence[str] = (),
    task: str | None = None,
    kind: str | Sequence[str] | None = None,
    required_episodes: Sequence[str] = (),
) -> EpisodeStore:
    """Read a whole store and check it before any work: its schema version, its declared
    kind (``kind``: one of STORE_KINDS or a list of them; any when None), ``task`` when
    given, the data keys in ``required`` and per-episode keys in ``required_episodes``,
    every chunk present and matching its checksum, episode bookkeeping, pose shapes and
    finite float values. Raises InputError naming the path, the array and, for bad values,
    the episode and step."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: store not found")
    try:
        root = zarr.open_group(str(path), mode="r")
        attrs = dict(root.attrs)
        groups = [root["data"], root["meta"]]
    except (KeyError, FileNotFoundError, ValueError) as exc:
        raise InputError(f"{path}: not an episode store ({exc})") from exc
    if attrs.get("schema_version") != SCHEMA_VERSION:
        raise InputError(
            f"{path}: schema_version {attrs.get('schema_version')!r}, expected {SCHEMA_VERSION}"
            " (written by another version of mimicgen-pipe; re-run the stage that wrote it)"
        )
    kinds = (kind,) if isinstance(kind, str) else kind
    if kinds is not None and attrs.get("kind") not in kinds:
        raise InputError(
            f"{path}: a {attrs.get('kind')!r} store, expected {' or '.join(map(repr, kinds))}"
        )
    if task is not None and attrs.get("task") != task:
        raise InputError(f"{path}: attrs.task is {attrs.get('task')!r}, expected {task!r}")
    arrays = _read_group(path, groups[0], "data/") | _read_group(path, groups[1], "meta/")
    if "meta/episode_ends" not in arrays:
        raise InputError(f"{path}: meta/episode_ends missing (not an episode store)")
    data = _strip("data/", {k: v for k, v in arrays.items() if k.startswith("data/")})
    episodes = _strip(
        "meta/episodes/", {k: v for k, v in arrays.items() if k.startswith("meta/episodes/")}
    )
    ends = np.asarray(arrays["meta/episode_ends"], dtype=np.int64)
    missing = [k for k in required if k not in data]
    if missing:
        raise InputError(f"{path}: missing data keys {missing}")
    missing = [k for k in required_episodes if k not in episodes]
    if missing:
        raise InputError(f"{path}: missing meta/episodes keys {missing}")
    _check_bookkeeping(path, data, ends, episodes)
    _check_finite(path, data, ends, episodes)
    return EpisodeStore(path, data, ends, episodes, attrs)
