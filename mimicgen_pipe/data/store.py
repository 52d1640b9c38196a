"""Zarr v3 episode stores (docs/data-contract.md), written atomically.

Layout: ``data/<key>`` (N_steps, ...) concatenated over episodes; ``meta/episode_ends``
(N_episodes,) cumulative exclusive ends; ``meta/episodes/<key>`` (N_episodes, ...);
group attributes carry the schema version, task, variant, back end and params used.
Poses are stored as (..., 7) [x, y, z, qw, qx, qy, qz], metres, in the world frame.
Each array is one chunk, so a store is a few dozen files for DVC to hash, except camera
images (``data/obs/<camera>_image``, the observe stage's), chunked along the steps (about
ROW_CHUNK_BYTES each), which are written block by block as they come and read chunk by
chunk. Every chunk is written (also one that holds only zeros) and carries a crc32c
checksum, so a missing or damaged chunk is an error when read, never a silent array of
zeros.
"""

from __future__ import annotations

import contextlib
import fnmatch
import itertools
import math
import os
import sys
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zarr
from zarr.codecs import BytesCodec, Crc32cCodec, ZstdCodec
from zarr.codecs.bytes import Endian
from zarr.storage import LocalStore

from mimicgen_pipe.core import poses
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.jsonfile import read_json
from mimicgen_pipe.data import pipelines
from mimicgen_pipe.data.outputs import atomic_directory, check_committed

SCHEMA_VERSION = 2  # 2: crc32c on every chunk, every chunk written, attrs.kind
STORE_KINDS = ("source", "parsed", "generated", "failed")
# zstd as zarr's default, then a checksum of the compressed bytes
_CODECS = (ZstdCodec(level=0, checksum=False), Crc32cCodec())


# What each array holds, as numpy dtype kinds (f float, i/u integer, b bool), checked on
# opening from the arrays' metadata before anything is read: a zarr.json relabelled with
# another dtype would otherwise read its bytes as other numbers. Keys not listed (a task's
# own extras) are not checked here.
DTYPE_KINDS = {
    "data/actions": "f",
    "data/eef_pose*": "f",
    "data/target_pose*": "f",
    "data/object_poses/*": "f",
    "data/gripper*": "f",
    "data/env_state": "f",
    "data/obs/*_image": "u",
    "data/obs/*": "f",
    "data/subtask_signals/*": "b",
    "meta/episode_ends": "i",
    "meta/episodes/seed": "iu",
    "meta/episodes/success": "b",
    "meta/episodes/ik_failure": "b",
    "meta/episodes/source_demo": "iu",
    "meta/episodes/failure_reason": "i",
    "meta/episodes/subtask_term_index": "i",
    "meta/episodes/initial_object_poses": "f",
    "meta/episodes/initial_state": "f",
}
_KIND_NAMES = {"f": "floating-point", "i": "integer", "iu": "integer", "u": "uint8", "b": "bool"}


def image_key(camera: str) -> str:
    """The data key of ``camera``'s images: (N_steps, H, W, 3) uint8 RGB."""
    return f"obs/{camera}_image"


def store_cameras(attrs: Mapping[str, Any]) -> dict[str, tuple[int, int]]:
    """Camera name -> (height, width) [px] of a store's images, in camera order (its attrs
    ``cameras``); empty for a store without images."""
    return {c: (int(v["height"]), int(v["width"])) for c, v in (attrs.get("cameras") or {}).items()}


class _Episodes:
    """Episode bookkeeping from ``episode_ends`` (N_episodes,) cumulative exclusive ends."""

    episode_ends: np.ndarray

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


@dataclass(frozen=True)
class EpisodeStore(_Episodes):
    """An episode store read into memory: ``data`` key -> (N_steps, ...) array,
    ``episodes`` key -> (N_episodes, ...) array, ``attrs`` the group attributes."""

    path: Path
    data: Mapping[str, np.ndarray]
    episode_ends: np.ndarray
    episodes: Mapping[str, np.ndarray]
    attrs: Mapping[str, Any]

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
    lengths = np.array([len(next(iter(s.values()))) if s else 0 for s in steps], np.int64)
    with store_writer(path, kind, np.cumsum(lengths), attrs) as writer:
        for key in steps[0] if steps else ():
            writer.array(key, np.concatenate([as_stored(s[key]) for s in steps]))
        for key, value in episodes.items():
            writer.episode_field(key, value)
    return Path(path)


# A step array chunked along its steps holds about this many bytes per chunk: an episode's
# rows are read by decoding one or two chunks, and a store of 1000 demos of 84x84 images is
# a few thousand files.
ROW_CHUNK_BYTES = 4 << 20


def row_chunk_steps(row_shape: Sequence[int], dtype: np.dtype | type) -> int:
    """Steps per chunk of a step array of rows ``row_shape`` chunked along its steps."""
    return max(1, ROW_CHUNK_BYTES // (np.dtype(dtype).itemsize * int(np.prod(row_shape))))


class RowWriter:
    """Writes the (n_rows, *row_shape) array ``name`` of ``group`` in chunks of
    :func:`row_chunk_steps` rows, from blocks of rows given in order (:meth:`append`): it holds
    at most one chunk, so a large array never needs to be in memory whole."""

    def __init__(
        self, group: zarr.Group, name: str, n_rows: int, row_shape: Sequence[int], dtype
    ) -> None:
        self.name, self.n_rows = name, n_rows
        rows = row_chunk_steps(row_shape, dtype)
        self._array = group.create_array(
            name,
            shape=(n_rows, *row_shape),
            dtype=dtype,
            chunks=(rows, *(max(1, s) for s in row_shape)),
            compressors=_CODECS,
            config={"write_empty_chunks": True},
        )
        self._buffer = np.empty((rows, *row_shape), dtype)
        self._held = 0  # rows in the buffer
        self._written = 0  # rows written to the array

    def append(self, block: np.ndarray) -> None:
        """The next rows, (m, *row_shape)."""
        block = np.asarray(block)
        if block.shape[1:] != self._buffer.shape[1:]:
            raise ValueError(
                f"{self.name}: rows {block.shape[1:]}, expected {self._buffer.shape[1:]}"
            )
        if self._written + self._held + len(block) > self.n_rows:
            raise ValueError(f"{self.name}: more than its {self.n_rows} rows")
        done = 0
        while done < len(block):
            m = min(len(block) - done, len(self._buffer) - self._held)
            self._buffer[self._held : self._held + m] = block[done : done + m]
            self._held, done = self._held + m, done + m
            if self._held == len(self._buffer):
                self._flush()

    def _flush(self) -> None:
        end = self._written + self._held
        self._array[self._written : end] = self._buffer[: self._held]
        self._written, self._held = end, 0

    def close(self) -> None:
        """Write the last chunk; every row must have been given."""
        if self._held:
            self._flush()
        if self._written != self.n_rows:
            raise ValueError(f"{self.name}: {self._written} of {self.n_rows} rows given")


@dataclass(frozen=True)
class StoreWriter:
    """The groups of a store being written (:func:`store_writer`)."""

    data: zarr.Group
    episodes: zarr.Group
    n_steps: int

    def array(self, key: str, value: np.ndarray) -> None:
        """``data/<key>``, (N_steps, ...), one chunk (4x4 poses stored as pq rows)."""
        _write_array(self.data, key, as_stored(value))

    def episode_field(self, key: str, value: np.ndarray) -> None:
        """``meta/episodes/<key>``, (N_episodes, ...), one chunk."""
        _write_array(self.episodes, key, as_stored(value))

    def rows(self, key: str, row_shape: Sequence[int], dtype) -> RowWriter:
        """A writer of ``data/<key>`` chunked along its steps, block by block."""
        return RowWriter(self.data, key, self.n_steps, row_shape, dtype)


@contextlib.contextmanager
def store_writer(
    path: str | os.PathLike, kind: str, episode_ends: np.ndarray, attrs: Mapping[str, Any]
) -> Iterator[StoreWriter]:
    """A store at ``path`` written array by array (as :func:`write_store` writes, and
    atomically: renamed into place when the block completes, nothing when it raises), with
    ``episode_ends`` (N_episodes,) cumulative exclusive ends."""
    if kind not in STORE_KINDS:
        raise ValueError(f"store kind {kind!r}: expected one of {STORE_KINDS}")
    ends = np.asarray(episode_ends, np.int64)
    with atomic_directory(path) as tmp:
        root = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        root.attrs.update({"schema_version": SCHEMA_VERSION, **attrs, "kind": kind})
        data = root.create_group("data")
        meta = root.create_group("meta")
        _write_array(meta, "episode_ends", ends)
        yield StoreWriter(data, meta.create_group("episodes"), int(ends[-1]) if len(ends) else 0)


def _members(path: Path, group: zarr.Group, prefix: str) -> dict[str, zarr.Array]:
    """Every array under ``group``, unread, keyed by its path in the store, its dtype
    checked (:data:`DTYPE_KINDS`); an InputError naming the zarr.json zarr cannot read."""
    try:
        out = _listed(group, prefix)
    except (KeyError, TypeError, ValueError) as exc:
        bad = _bad_metadata(path)
        raise bad or InputError(
            f"{path}: damaged store metadata ({type(exc).__name__}: {str(exc)[:80]}); re-run "
            "the stage that wrote it"
        ) from exc
    for key, member in out.items():
        _check_dtype(path, key, member.dtype)
    return out


def _listed(group: zarr.Group, prefix: str) -> dict[str, zarr.Array]:
    out: dict[str, zarr.Array] = {}
    # by name: zarr lists a group's members concurrently, in another order from one run to
    # the next, and readers write what they read in this order (an export's datasets)
    for name, member in sorted(group.members(), key=lambda m: m[0]):
        key = f"{prefix}{name}"
        if isinstance(member, zarr.Group):
            out.update(_listed(member, f"{key}/"))
        else:
            out[key] = member
    return out


def _check_dtype(path: Path, key: str, dtype: np.dtype) -> None:
    pattern = next((p for p in DTYPE_KINDS if fnmatch.fnmatchcase(key, p)), None)
    if pattern is None:
        return
    kinds = DTYPE_KINDS[pattern]
    if np.dtype(dtype).kind not in kinds or (kinds == "u" and np.dtype(dtype) != np.uint8):
        raise InputError(
            f"{path}: {key}: dtype {np.dtype(dtype)}, expected {_KIND_NAMES[kinds]} "
            f"({path / key / 'zarr.json'} was changed, or another program wrote the store; "
            "re-run the stage that wrote it)"
        )


def _metadata_files(path: Path) -> Iterator[tuple[Path, Any]]:
    """(zarr.json, its parsed document) of the store at ``path`` and of every group and array
    under it, each read bounded (:func:`read_json`: size, nesting); a group's member folders
    are entered, an array's chunks never (a store may declare millions)."""
    todo = [path]
    while todo:
        folder = todo.pop()
        meta = folder / "zarr.json"
        try:
            doc = read_json(meta, "zarr.json (store metadata)")
        except InputError as exc:
            why = str(exc).removeprefix(f"{meta}: ")
            raise InputError(
                f"{meta}: damaged store metadata ({why}); re-run the stage that wrote it"
            ) from None
        yield meta, doc
        if isinstance(doc, dict) and doc.get("node_type") == "group":
            members = sorted(p for p in folder.iterdir() if (p / "zarr.json").is_file())
            todo.extend(reversed(members))


def _check_metadata(path: Path) -> None:
    """Every zarr.json of the store read bounded before zarr parses it (zarr's own JSON
    parser recurses, and reads a file of any size): one InputError naming the file."""
    for _meta, _doc in _metadata_files(path):
        pass


def _bad_metadata(path: Path) -> InputError | None:
    """An InputError naming the first zarr.json under ``path`` that zarr cannot read, None
    when zarr reads them all."""
    for meta, doc in _metadata_files(path):
        try:
            if not isinstance(doc, dict):
                raise ValueError("not a JSON object")
            if doc.get("node_type") == "array":
                zarr.open_array(str(meta.parent), mode="r")
            else:
                zarr.open_group(str(meta.parent), mode="r")
        except Exception as bad:  # whatever zarr raises for it: this is the file
            what = f"{type(bad).__name__}: {str(bad)[:80]}"
            return InputError(
                f"{meta}: damaged store metadata ({what}); re-run the stage that wrote it"
            )
    return None


# What one array may declare, checked from its metadata before any of its chunks is listed or
# read: a zarr.json is a small text file, and zarr would otherwise list every key of a grid
# of billions of chunks, or decode a chunk to whatever size its header says. A store of
# 1000 demos of 84x84 images has a few thousand chunks; write_store writes a step array
# (not images) as one chunk.
MAX_CHUNKS = 1 << 20
MAX_CHUNK_BYTES = 4 << 30  # decoded


def _check_declared(path: Path, arrays: Mapping[str, zarr.Array]) -> np.ndarray:
    """``meta/episode_ends``, read once its own size is bounded; then every array's declared
    shape checked against it (data arrays one row per step, per-episode arrays one per
    episode) and its chunks bounded (:func:`_check_size`), before any other chunk is listed
    or read. One InputError naming the store, the array and what was expected."""
    key = "meta/episode_ends"
    if key not in arrays:
        raise InputError(f"{path}: {key} missing (not an episode store)")
    if arrays[key].ndim != 1:
        raise InputError(f"{path}: {key}: shape {arrays[key].shape}, expected (N_episodes,)")
    _check_size(path, key, arrays[key])
    _check_chunks(path, key, arrays[key])
    ends = np.asarray(_read_array(path, key, arrays[key]), dtype=np.int64)
    if len(ends) and (ends[0] < 0 or np.any(np.diff(ends) < 0)):
        raise InputError(f"{path}: {key}: expected non-decreasing ends, got {ends}")
    n_steps = int(ends[-1]) if len(ends) else 0
    for name, member in arrays.items():
        rows = member.shape[0] if member.ndim else 0
        if name.startswith("data/") and rows != n_steps:
            raise InputError(f"{path}: {name}: {rows} steps, expected {n_steps} ({key})")
        if name.startswith("meta/episodes/") and rows != len(ends):
            raise InputError(f"{path}: {name}: {rows} rows, expected one per episode ({len(ends)})")
        _check_size(path, name, member)
    return ends


def _check_size(path: Path, key: str, member: zarr.Array) -> None:
    """InputError unless ``member`` declares a regular chunk grid of at most
    :data:`MAX_CHUNKS` chunks, each decoding to at most :data:`MAX_CHUNK_BYTES`."""
    shape = tuple(int(s) for s in member.shape)
    chunks = tuple(int(c) for c in getattr(member.metadata.chunk_grid, "chunk_shape", ()))
    if len(chunks) != len(shape) or any(c < 1 for c in chunks):
        raise InputError(
            f"{path}: {key}: chunks {chunks} for shape {shape}, expected one positive chunk "
            "size per axis (the store is damaged; re-run the stage that wrote it)"
        )
    n = math.prod(-(-s // c) for s, c in zip(shape, chunks, strict=True))
    size = math.prod(chunks) * member.dtype.itemsize
    if n > MAX_CHUNKS or size > MAX_CHUNK_BYTES:
        raise InputError(
            f"{path}: {key}: shape {shape} in chunks of {chunks} declares {n} chunks of "
            f"{size} bytes, expected at most {MAX_CHUNKS} chunks of at most "
            f"{MAX_CHUNK_BYTES} bytes (the store is damaged or not written by mimicgen-pipe)"
        )


def _check_chunks(path: Path, key: str, member: zarr.Array) -> None:
    if member.nchunks_initialized < member.nchunks:
        raise InputError(
            f"{path}: {key}: {member.nchunks - member.nchunks_initialized} of "
            f"{member.nchunks} chunk(s) missing (store incomplete or damaged; re-run the "
            "stage that wrote it)"
        )


def _damaged(path: Path, key: str, exc: Exception) -> InputError:
    return InputError(
        f"{path}: {key}: a chunk cannot be decoded ({type(exc).__name__}: "
        f"{str(exc)[:80]}); the store is damaged, re-run the stage that wrote it"
    )


_ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"


def _frame_size(head: bytes) -> int | None:
    """The decoded size that the zstd frame starting with ``head`` (at least its first 18
    bytes) declares; None when it is no zstd frame or declares no size (RFC 8878, 3.1.1)."""
    if len(head) < 5 or head[:4] != _ZSTD_MAGIC:
        return None
    descriptor = head[4]
    single_segment = (descriptor >> 5) & 1
    at = 5 + (1 - single_segment) + (0, 1, 2, 4)[descriptor & 3]
    width = (single_segment, 2, 4, 8)[descriptor >> 6]
    if width == 0 or len(head) < at + width:
        return None
    size = int.from_bytes(head[at : at + width], "little")
    return size + 256 if width == 2 else size


def _check_frames(
    path: Path, key: str, member: zarr.Array, coords: Iterable[tuple[int, ...]]
) -> None:
    """InputError unless each chunk of ``coords`` declares, in its zstd frame's header, the
    size its chunk shape decodes to: zarr's zstd codec allocates what the header says before
    it decodes, so a small file declaring gigabytes is refused before it is decoded. Chunks
    of another layout than write_store's are left to zarr."""
    md = member.metadata
    codecs = [type(c) for c in getattr(md, "codecs", ())]
    if codecs != [BytesCodec, ZstdCodec, Crc32cCodec] or not isinstance(member.store, LocalStore):
        return
    expected = math.prod(md.chunk_grid.chunk_shape) * member.dtype.itemsize
    folder = Path(member.store.root) / member.path
    for c in coords:
        try:
            with (folder / md.encode_chunk_key(c)).open("rb") as f:
                declared = _frame_size(f.read(18))
        except OSError:
            continue  # a missing chunk: _check_chunks names it
        if declared != expected:
            said = "no decoded size" if declared is None else f"{declared} decoded bytes"
            raise InputError(
                f"{path}: {key}: chunk {'.'.join(map(str, c))} declares {said}, expected "
                f"{expected} (its chunk shape); the store is damaged, re-run the stage that "
                "wrote it"
            )


def _read_array(path: Path, key: str, member: zarr.Array) -> np.ndarray:
    """One whole array, every chunk present, of the size its shape declares (its header
    read before it is decoded) and matching its checksum."""
    _check_chunks(path, key, member)
    _check_frames(path, key, member, itertools.product(*map(range, member.cdata_shape)))
    try:
        return member[...]
    except Exception as exc:  # zarr raises ValueError/RuntimeError by codec
        raise _damaged(path, key, exc) from exc


def _check_required(
    path: Path, attrs: Mapping[str, Any], ends: np.ndarray, missing: Sequence[str]
) -> None:
    """InputError for data keys a reader needs that the store lacks; a store with no
    episodes has none, and is named as such."""
    if not missing:
        return
    if len(ends) == 0:
        raise no_episodes(path, attrs)
    raise InputError(f"{path}: missing data keys {list(missing)}")


def no_episodes(path: Path, attrs: Mapping[str, Any]) -> InputError:
    """The error for a store with no episodes where a reader needs some, saying what to do."""
    why = (
        "generate kept none of its attempts: raise generate.max_attempts, or check the "
        "source demos and the failed store beside it"
        if attrs.get("kind") == "generated"
        else "re-run the stage that wrote it with more demos"
    )
    return InputError(f"{path}: 0 episodes ({why})")


def _strip(prefix: str, arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {k[len(prefix) :]: v for k, v in arrays.items()}


def _is_pose_key(key: str) -> bool:
    """Keys stored as (..., 7) pose rows."""
    return key in ("eef_pose", "target_pose", "initial_object_poses") or key.startswith(
        ("object_poses/", "eef_pose/", "target_pose/")  # the last two: an arm's of several
    )


def _check_bookkeeping(
    path: Path,
    data: Mapping[str, np.ndarray],
    ends: np.ndarray,
    episodes: Mapping[str, Any],
    attrs: Mapping[str, Any],
) -> None:
    """Episode ends cumulative and covering every data array; per-episode arrays one row per
    episode; pose arrays 7 wide; subtask ends (parsed stores) inside their episodes, and in
    order within each arm's (attrs.subtasks' ``arm``, for a task of several)."""
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
        # the arm of each column: of the subtasks with a term signal, in order
        arms = np.array(
            [s.get("arm", "") for s in attrs.get("subtasks") or () if s.get("term_signal")]
        )
        for i, (row, length) in enumerate(zip(np.atleast_2d(term), lengths, strict=False)):
            same_arm = (arms[1:] == arms[:-1]) if len(arms) == len(row) else True
            if np.any(row < 1) or np.any(row > length) or np.any((np.diff(row) < 0) & same_arm):
                raise InputError(
                    f"{path}: meta/episodes/subtask_term_index: episode {i}: subtask ends "
                    f"{row.tolist()} are not increasing inside the episode's {length} steps"
                )


def _not_finite(path: Path, key: str, ends: np.ndarray, row: int) -> InputError:
    """data/<key> has a NaN or infinite value at step ``row`` of the concatenated steps."""
    ep = int(np.searchsorted(ends, row, side="right"))
    start = int(ends[ep - 1]) if ep else 0
    return InputError(
        f"{path}: data/{key}: NaN or infinite value at episode {ep}, step {row - start} (row {row})"
    )


def _check_finite(
    path: Path, data: Mapping[str, np.ndarray], ends: np.ndarray, episodes: Mapping[str, Any]
) -> None:
    """Every float array finite; the first bad value is named by array, episode and step."""
    for key, value in data.items():
        if value.dtype.kind != "f" or np.isfinite(value).all():
            continue
        step = int(np.argmax(~np.isfinite(value).reshape(len(value), -1).all(axis=1)))
        raise _not_finite(path, key, ends, step)
    for key, value in episodes.items():
        if value.dtype.kind != "f" or np.isfinite(value).all():
            continue
        ep = int(np.argmax(~np.isfinite(value).reshape(len(value), -1).all(axis=1)))
        raise InputError(f"{path}: meta/episodes/{key}: NaN or infinite value at episode {ep}")


# the stage that writes each kind of store, for a missing input outside any pipeline
_WRITTEN_BY = {
    "source": ("source",),
    "parsed": ("parse", "pose_noise"),
    "generated": ("generate",),
    "failed": ("generate",),
}


def missing_store_hint(path: Path, kind: str | Sequence[str] | None) -> str:
    """What makes a missing store: the pipeline stage that tracks ``path``
    (:func:`pipelines.made_by`), else the stages that write a store of ``kind``."""
    if hint := pipelines.made_by(path):
        return hint
    kinds = [kind] if isinstance(kind, str) else list(kind or ())
    stages = sorted({s for k in kinds for s in _WRITTEN_BY.get(k, ())})
    return f"; written by {' or '.join(f'`mimicgen-pipe {s}`' for s in stages)}" if stages else ""


def _open_root(
    path: Path, task: str | None, kind: str | Sequence[str] | None
) -> tuple[tuple[zarr.Group, zarr.Group], dict[str, Any]]:
    """The data and meta groups of the store at ``path`` and its attributes, after checking
    its schema version, its kind (one of ``kind`` unless None) and its task (unless None)."""
    if not path.exists():
        raise InputError(f"{path}: store not found{missing_store_hint(path, kind)}")
    if (path / "zarr.json").is_file():  # else zarr says what is missing, below
        _check_metadata(path)
    try:
        root = zarr.open_group(str(path), mode="r")
        attrs = dict(root.attrs)
        groups = (root["data"], root["meta"])
    except FileNotFoundError as exc:
        raise InputError(f"{path}: not an episode store ({exc})") from exc
    except (KeyError, TypeError, ValueError) as exc:
        bad = _bad_metadata(path)
        raise bad or InputError(f"{path}: not an episode store ({exc})") from exc
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
    return groups, attrs


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
    check_committed(path)  # never read a set that a killed run left half committed
    groups, attrs = _open_root(path, task, kind)
    members = _members(path, groups[0], "data/") | _members(path, groups[1], "meta/")
    ends = _check_declared(path, members)  # before any read: shapes, chunk counts, sizes
    arrays = {k: _read_array(path, k, m) for k, m in members.items() if k != "meta/episode_ends"}
    data = _strip("data/", {k: v for k, v in arrays.items() if k.startswith("data/")})
    episodes = _strip(
        "meta/episodes/", {k: v for k, v in arrays.items() if k.startswith("meta/episodes/")}
    )
    _check_required(path, attrs, ends, [k for k in required if k not in data])
    missing = [k for k in required_episodes if k not in episodes]
    if missing:
        raise InputError(f"{path}: missing meta/episodes keys {missing}")
    _check_bookkeeping(path, data, ends, episodes, attrs)
    _check_finite(path, data, ends, episodes)
    return EpisodeStore(path, data, ends, episodes, attrs)


# ---- partial reads: the arrays and episodes a stage uses, nothing else ----

# A partial read decodes at most this many bytes of an array at a time: its working memory
# beyond the rows it returns.
_BLOCK_BYTES = 1 << 20


@dataclass(frozen=True)
class StoreView(_Episodes):
    """An episode store opened for partial reads: header, episode bookkeeping and array
    shapes are checked as :func:`read_store` checks them, but an array is read only when
    asked for, and then only the rows of the episodes asked for. ``arrays``: every array,
    unread, by its path in the store (``data/<key>``, ``meta/episodes/<key>``)."""

    path: Path
    attrs: Mapping[str, Any]
    episode_ends: np.ndarray
    arrays: Mapping[str, zarr.Array]

    @property
    def data_keys(self) -> list[str]:
        return sorted(k[5:] for k in self.arrays if k.startswith("data/"))

    @property
    def episode_keys(self) -> list[str]:
        return sorted(k[14:] for k in self.arrays if k.startswith("meta/episodes/"))

    def shape(self, key: str) -> tuple[int, ...]:
        """The shape of ``data/<key>``, (N_steps, ...), without reading it."""
        return tuple(self.arrays[f"data/{key}"].shape)

    def episode_field(self, key: str) -> np.ndarray:
        """``meta/episodes/<key>`` (N_episodes, ...), checksum-verified and finite."""
        value = _read_array(self.path, f"meta/episodes/{key}", self.arrays[f"meta/episodes/{key}"])
        _check_finite(self.path, {}, self.episode_ends, {key: value})
        return value

    def read_rows(
        self, key: str, episodes: Sequence[int], out: np.ndarray | None = None
    ) -> np.ndarray:
        """The steps of ``episodes`` (ascending store indices) in ``data/<key>``,
        concatenated in episode order: written into ``out`` when given (a (rows, ...) array
        whose rows take the stored rows, cast to its dtype), else a new array of the stored
        dtype. The array's chunk must match its checksum; a NaN or infinite value among the
        rows read, or one the cast to ``out``'s dtype makes, is an InputError naming the
        episode and step."""
        member = self.arrays[f"data/{key}"]
        starts, ends = self.episode_starts, self.episode_ends
        chosen = np.asarray(episodes, np.int64)
        if np.any(np.diff(chosen) <= 0):
            raise ValueError("episodes: expected ascending store indices")
        n = int((ends[chosen] - starts[chosen]).sum())
        if out is None:
            out = np.empty((n, *member.shape[1:]), member.dtype)
        if len(out) != n:
            raise ValueError(f"out: {len(out)} rows, the episodes have {n}")
        ranges: list[list[int]] = []  # consecutive episodes read as one run of rows
        for e in chosen:
            if ranges and ranges[-1][1] == starts[e]:
                ranges[-1][1] = int(ends[e])
            else:
                ranges.append([int(starts[e]), int(ends[e])])
        done = 0
        with np.errstate(over="ignore"):  # a cast's overflow is reported below, by row
            for row, block in _iter_rows(self.path, f"data/{key}", member, ranges):
                m = len(block)
                if block.dtype.kind == "f" and not np.isfinite(block).all():
                    bad = int(np.argmax(~np.isfinite(block).reshape(m, -1).all(axis=1)))
                    raise _not_finite(self.path, key, ends, row + bad)
                dest = out[done : done + m]
                dest[...] = block.reshape((m, *out.shape[1:]))
                if dest.dtype.kind == "f" and not np.isfinite(dest).all():
                    bad = int(np.argmax(~np.isfinite(dest).reshape(m, -1).all(axis=1)))
                    raise InputError(
                        f"{self.path}: data/{key}: a value at row {row + bad} does not fit "
                        f"{dest.dtype} (it becomes infinite)"
                    )
                done += m
        return out


def open_store(
    path: str | os.PathLike,
    required: Sequence[str] = (),
    task: str | None = None,
    kind: str | Sequence[str] | None = None,
    required_episodes: Sequence[str] = (),
) -> StoreView:
    """Open a store for partial reads, checking before any work what :func:`read_store`
    checks without reading the step arrays: schema version, kind, task, required keys,
    episode bookkeeping, pose shapes (subtask ends included) and that no chunk is missing.
    Checksums and finite values are checked for what is then read. Memory: the episode
    ends, O(N_episodes)."""
    path = Path(path)
    check_committed(path)  # never read a set that a killed run left half committed
    groups, attrs = _open_root(path, task, kind)
    arrays = _members(path, groups[0], "data/") | _members(path, groups[1], "meta/")
    ends = _check_declared(path, arrays)  # before any listing: shapes, chunk counts, sizes
    for key, member in arrays.items():  # a listing, not a read: a damaged store stops here
        _check_chunks(path, key, member)
    data = _strip("data/", {k: v for k, v in arrays.items() if k.startswith("data/")})
    episodes: dict[str, Any] = _strip(
        "meta/episodes/", {k: v for k, v in arrays.items() if k.startswith("meta/episodes/")}
    )
    _check_required(path, attrs, ends, [k for k in required if k not in data])
    missing = [k for k in required_episodes if k not in episodes]
    if missing:
        raise InputError(f"{path}: missing meta/episodes keys {missing}")
    term = "meta/episodes/subtask_term_index"
    if term in arrays:  # its values are checked, so it is read (one row per episode)
        episodes["subtask_term_index"] = _read_array(path, term, arrays[term])
    _check_bookkeeping(path, data, ends, episodes, attrs)  # shapes only, besides subtask ends
    return StoreView(path, attrs, ends, arrays)


def _chunk_file(member: zarr.Array) -> Path | None:
    """The file of an array written as write_store writes it (one chunk of little-endian
    numbers, zstd, crc32c, in a local store), else None."""
    md = member.metadata
    codecs = getattr(md, "codecs", ())
    if (
        sys.byteorder != "little"
        or member.dtype.kind not in "biuf"
        or 0 in member.shape
        or tuple(getattr(md.chunk_grid, "chunk_shape", ())) != tuple(member.shape)
        or [type(c) for c in codecs] != [BytesCodec, ZstdCodec, Crc32cCodec]
        or codecs[0].endian not in (None, Endian.little)
        or not isinstance(member.store, LocalStore)
    ):
        return None
    return Path(member.store.root) / member.path / md.encode_chunk_key((0,) * member.ndim)


def _iter_rows(
    path: Path, key: str, member: zarr.Array, ranges: Sequence[Sequence[int]]
) -> Iterator[tuple[int, np.ndarray]]:
    """(first row, rows) blocks of the row ranges [start, end) of ``member``, in order.

    An array in write_store's layout is decoded as a stream, and only up to the last row
    wanted: memory stays at one block however many rows the array has. Its checksum is
    verified first, over the whole chunk file, also when only a part of it is decoded."""
    _check_chunks(path, key, member)
    chunk = _chunk_file(member)
    steps = tuple(getattr(member.metadata.chunk_grid, "chunk_shape", ()))
    if chunk is None and member.ndim and steps[1:] == tuple(member.shape[1:]):
        # chunked along the steps (camera images): decode only the chunks holding the rows
        yield from _iter_chunked_rows(path, key, member, steps[0], ranges)
        return
    if chunk is None:  # another layout: decode the whole array
        whole = _read_array(path, key, member)
        for start, end in ranges:
            yield start, whole[start:end]
        return
    import crc32c
    import pyarrow as pa

    try:
        size = chunk.stat().st_size
        if size < 4:
            raise ValueError(f"{size} bytes, shorter than its checksum")
        with chunk.open("rb") as f:
            crc, left = 0, size - 4
            while left:
                part = f.read(min(left, _BLOCK_BYTES))
                if not part:
                    raise ValueError("file shorter than its size")
                crc, left = crc32c.crc32c(part, value=crc), left - len(part)
            if np.uint32(crc).tobytes() != f.read(4):
                raise ValueError("stored and computed checksum do not match")
    except (OSError, ValueError) as exc:
        raise _damaged(path, key, exc) from exc
    row_shape = tuple(member.shape[1:])
    dtype = member.dtype.newbyteorder("<")
    row_bytes = dtype.itemsize * int(np.prod(row_shape))
    per_block = max(1, _BLOCK_BYTES // row_bytes)
    block = np.empty((per_block, *row_shape), dtype)  # decoded rows land here, block by block
    view = memoryview(block.reshape(-1).view(np.uint8))
    try:
        with pa.OSFile(str(chunk)) as raw:
            stream = pa.CompressedInputStream(raw.get_stream(0, size - 4), "zstd")
            pos = 0  # rows decoded so far
            for start, end in ranges:
                while pos < end:
                    n = min(end - pos, per_block) if pos >= start else min(start - pos, per_block)
                    got = 0
                    while got < n * row_bytes:
                        step = stream.readinto(view[got : n * row_bytes])
                        if not step:
                            raise ValueError(f"the chunk ends at row {pos + got // row_bytes}")
                        got += step
                    if pos >= start:
                        yield pos, block[:n]
                    pos += n
            stream.close()
    except (pa.ArrowException, ValueError) as exc:
        raise _damaged(path, key, exc) from exc
    finally:
        # the stream's decoding buffers come from Arrow's pool, which keeps freed memory
        pa.default_memory_pool().release_unused()


def _iter_chunked_rows(
    path: Path, key: str, member: zarr.Array, rows: int, ranges: Sequence[Sequence[int]]
) -> Iterator[tuple[int, np.ndarray]]:
    """(first row, rows) blocks of the row ranges of an array chunked along its steps in
    chunks of ``rows`` steps: one block per chunk a range overlaps, each chunk's checksum
    verified as it is decoded."""
    for start, end in ranges:
        pos = start
        while pos < end:
            stop = min(end, (pos // rows + 1) * rows)
            _check_frames(path, key, member, [(pos // rows,) + (0,) * (member.ndim - 1)])
            try:
                block = member[pos:stop]
            except Exception as exc:  # zarr raises ValueError/RuntimeError by codec
                raise _damaged(path, key, exc) from exc
            yield pos, block
            pos = stop
