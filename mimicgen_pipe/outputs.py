"""Writing stage outputs safely.

- Every output is written under a temporary sibling name (``.<name>.tmp-*``) and renamed into
  place only when complete; outputs that belong together (a generate run's kept store, failed
  store and metrics) are renamed one after the other at the end, with signals held back, and
  carry one run id that readers compare (:func:`check_same_run`).
- A stage claims its outputs first (:func:`claim`): an exclusive ``flock`` on a
  ``.<name>.lock`` file beside each, held until the stage ends (the kernel drops it when the
  process dies, however it dies), so a second run writing the same outputs stops at once
  instead of racing the first. Holding the lock, the stage removes the temporaries a killed
  run left beside its outputs.
"""

from __future__ import annotations

import atexit
import contextlib
import fcntl
import hashlib
import json
import os
import shutil
import uuid
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from mimicgen_pipe import interrupts
from mimicgen_pipe.errors import InputError

_TEMP_KINDS = ("tmp", "old")  # .<name>.tmp-* being written, .<name>.old-* being replaced
_staging = 0  # >0 while an output set writes its temporaries
_written = False  # an output of this process has been renamed into place


class OutputBusy(InputError):
    """Another process holds the lock on an output: one line, exit status 2, like bad input."""


def temporary_name(path: Path, kind: str = "tmp") -> Path:
    """A fresh sibling name that :func:`remove_stale` recognises as a leftover of ``path``."""
    return path.with_name(f".{path.name}.{kind}-{os.getpid()}-{uuid.uuid4().hex[:8]}")


def _remove(path: Path) -> None:
    """Remove a file or a directory tree; what cannot be removed now (a writer thread still
    adding files) is left for the next run's :func:`remove_stale`."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def _replace(tmp: Path, path: Path) -> None:
    """Move ``tmp`` onto ``path``. A directory cannot replace another in one rename: the old
    one is renamed aside first and removed after."""
    backup = None
    if path.is_dir() and not path.is_symlink():
        backup = temporary_name(path, "old")
        path.rename(backup)
    os.replace(tmp, path)
    if backup is not None:
        _remove(backup)


def wrote_outputs() -> bool:
    """Whether this process has put an output in place (for the interrupt message)."""
    return _written


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary sibling directory of ``path``; when the block completes it replaces
    ``path``, and when it raises (or is interrupted) it is removed and ``path`` is untouched."""
    global _written
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_name(path)
    tmp.mkdir()
    try:
        yield tmp
        with interrupts.deferred():
            _replace(tmp, path)
            _written = _written or not _staging
    finally:
        _remove(tmp)


@contextlib.contextmanager
def output_set(*paths: str | os.PathLike) -> Iterator[list[Path]]:
    """Yield one temporary path per output (not created: the caller writes a file or a
    directory there). When the block completes, every temporary must exist; they are renamed
    into place in the order given, with SIGINT/SIGTERM held back, so put the output readers
    look at first last. When the block raises, the temporaries are removed and no output
    changes."""
    global _staging, _written
    finals = [Path(p) for p in paths]
    tmps = [temporary_name(p) for p in finals]
    for p in finals:
        p.parent.mkdir(parents=True, exist_ok=True)
    _staging += 1
    try:
        try:
            yield tmps
        finally:
            _staging -= 1
        missing = [str(f) for t, f in zip(tmps, finals, strict=True) if not t.exists()]
        if missing:
            raise RuntimeError(f"output set: nothing was written for {missing}")
        with interrupts.deferred():
            for tmp, final in zip(tmps, finals, strict=True):
                _replace(tmp, final)
            _written = True
    finally:
        for tmp in tmps:
            _remove(tmp)


def stale_temporaries(path: str | os.PathLike) -> list[Path]:
    """Temporaries of ``path`` that runs killed before they could clean up left beside it,
    including those of writers nested in them (``..<name>.tmp-*.tmp-*``)."""
    path = Path(path)
    if not path.parent.is_dir():
        return []
    marks = [f".{path.name}.{kind}-" for kind in _TEMP_KINDS]
    return sorted(
        p
        for p in path.parent.iterdir()
        if p.name.startswith(".") and any(m in p.name for m in marks)
    )


def remove_stale(path: str | os.PathLike) -> list[Path]:
    """Remove the stale temporaries of ``path``; call it only while holding its lock."""
    stale = stale_temporaries(path)
    for p in stale:
        _remove(p)
    return stale


# --- locks ---------------------------------------------------------------------------------

_HELD: dict[Path, int] = {}  # lock file -> open descriptor holding the flock


def lock_file(path: str | os.PathLike) -> Path:
    path = Path(path)
    return path.with_name(f".{path.name}.lock")


def _holder(fd: int) -> str:
    """The pid the holder wrote into the lock file, for the error message."""
    with contextlib.suppress(OSError):
        text = os.pread(fd, 32, 0).decode(errors="replace").strip()
        if text.isdigit():
            return f" (pid {text})"
    return ""


def _acquire(path: Path) -> int:
    """An exclusive flock on ``path``'s lock file, or OutputBusy at once. The holder removes
    the file when it lets go, so after locking, check that the file we locked is still the
    one at that name (else a third process may lock a new file there) and retry if not."""
    lock = lock_file(path)
    for _ in range(20):
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise OutputBusy(
                f"{path}: another mimicgen-pipe run{holder} is writing this output; wait for "
                f"it to finish or stop it (lock {lock})"
            ) from None
        try:
            st, now = os.fstat(fd), os.stat(lock)
            same = (st.st_dev, st.st_ino) == (now.st_dev, now.st_ino)
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            return fd
        os.close(fd)
    raise OutputBusy(f"{path}: could not lock {lock} (it keeps being replaced)")


def claim(*paths: str | os.PathLike) -> None:
    """Lock every output of the stage (all or none), then remove what killed runs left
    beside them. Held until :func:`release` (the entry point calls it when the stage ends)
    or the process exits; claiming a path this process holds already is a no-op."""
    taken: list[Path] = []
    try:
        for p in map(Path, paths):
            lock = lock_file(p)
            if lock in _HELD:
                continue
            p.parent.mkdir(parents=True, exist_ok=True)
            _HELD[lock] = _acquire(p)
            taken.append(lock)
    except BaseException:
        release(taken)
        raise
    for p in paths:
        remove_stale(p)


def release(locks: list[Path] | None = None) -> None:
    """Let go of the given lock files (default: all this process holds), removing them first
    so that no empty lock files stay behind."""
    for lock in list(_HELD) if locks is None else locks:
        fd = _HELD.pop(lock, None)
        if fd is None:
            continue
        with contextlib.suppress(FileNotFoundError):
            lock.unlink()
        os.close(fd)


atexit.register(release)


@contextlib.contextmanager
def claims() -> Iterator[None]:
    """Release every claim made within the block when it ends (the entry point wraps each
    stage in one)."""
    global _written
    _written = False
    try:
        yield
    finally:
        release()


# --- run ids -------------------------------------------------------------------------------


def content_digest(arrays: Mapping[str, np.ndarray]) -> str:
    """sha256 of arrays' names, dtypes, shapes and bytes: identifies an input store's
    contents independently of how its files were compressed or where it lies."""
    h = hashlib.sha256()
    for key in sorted(arrays):
        a = np.ascontiguousarray(arrays[key])
        h.update(json.dumps([key, a.dtype.str, list(a.shape)]).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def store_digest(store: Any) -> str:
    """:func:`content_digest` of every array of a store read into memory (an EpisodeStore,
    not imported here: the report, which imports this module, reads no store)."""
    arrays = {f"data/{k}": v for k, v in store.data.items()}
    arrays["meta/episode_ends"] = store.episode_ends
    arrays.update({f"meta/episodes/{k}": v for k, v in store.episodes.items()})
    return content_digest(arrays)


def run_id(shaping: Mapping[str, Any], *input_digests: str) -> str:
    """A short id for one run's output set, a function of what shapes the data only (the
    params that change it and the inputs' contents), so that the same inputs and params give
    the same id, and the same bytes, on any machine and with any number of workers."""
    text = json.dumps(
        {"shaping": shaping, "inputs": list(input_digests)}, sort_keys=True, separators=(",", ":")
    )
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def check_same_run(ids: Mapping[str, Any], what: str = "generate") -> None:
    """InputError when outputs that must come from one run carry different run ids (or one
    has none): e.g. a new kept store beside an old failed store after a killed run.
    ``ids``: a name of each output (path, or file and key) -> its run id."""
    if len(set(ids.values())) <= 1:
        return
    listed = ", ".join(f"{name} has run id {rid!r}" for name, rid in ids.items())
    raise InputError(
        f"outputs of different {what} runs: {listed}; re-run {what} to write them together"
    )
