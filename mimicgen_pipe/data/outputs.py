"""Writing stage outputs safely.

- **What may be replaced.** A stage writes only to a path that is absent or already holds an
  output of the kind it writes (:class:`OutputKind`: an episode store of the expected kind, a
  metrics JSON object, a CSV table, a PNG image, a directory laid out as the stage lays it
  out); never to one of its inputs, and no two outputs of one stage to the same place.
  :func:`claim` checks all of that, with symbolic links resolved, before any work, and the
  commit checks it again. A symbolic link at an output path is replaced by the new output
  (the link's target is left alone).
- **All old or all new.** Every output is written under a temporary sibling name
  (``.<name>.tmp-*``). Outputs that belong together (a generate run's kept store, failed
  store and metrics) are committed as one unit through a journal: once every temporary is
  complete, a journal naming every (temporary, output) pair is written beside each output
  (``.<name>.commit``), then each old output is moved aside and its temporary renamed into
  place, then the journals are removed. A run killed before every journal is in place leaves
  the old set (its temporaries are removed by the next run); one killed after is rolled
  forward to the new set by the next run of the stage (:func:`recover`). Readers never act
  on a journal: a set whose commit is half done is refused (:func:`check_committed`).
  Outputs of one run also carry one run id that readers compare (:func:`check_same_run`).
- **Nothing beside an output reaches outside its folder.** A journal is acted on only by
  the stage holding the lock of every output it names, and only when each name in it is
  one the writer gives (a temporary or an old output in that output's own folder); journals
  and lock files are opened without following links, and must be regular files. Anything
  else is refused with one line, and nothing is moved or removed.
- **One writer.** A stage claims its outputs first: an exclusive ``flock`` on a
  ``.<name>.lock`` file beside each, held until the stage ends (the kernel drops it when the
  process dies, however it dies), so a second run writing the same outputs stops at once
  instead of racing the first. Holding the locks, the stage completes a pending commit and
  removes the temporaries a killed run left beside its outputs.
- **Full or read-only disks** stop a stage with one line naming the path and the free space;
  its temporaries are removed and the previous outputs stay as they were.
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import fcntl
import hashlib
import json
import os
import re
import shutil
import signal
import stat
import uuid
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mimicgen_pipe.core import interrupts
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.jsonfile import parse_json, read_json
from mimicgen_pipe.data import pipelines

_TEMP_KINDS = ("tmp", "old")  # .<name>.tmp-* being written, .<name>.old-* being replaced
_staging = 0  # >0 while an output set writes its temporaries
_written = False  # an output of this process has been renamed into place
_replace_tracked = False  # the entry point's --replace-tracked, for the stage it runs
# Testing hook: SIGKILL this process before the N-th filesystem operation of a journaled
# commit (1-based), so that tests can stop a real run between any two of them.
KILL_AT_ENV = "MIMICGEN_PIPE_KILL_AT_COMMIT_OP"
_commit_ops = 0
Entry = tuple[Path, Path, Path]  # (temporary, output, old output moved aside) of a commit


class OutputBusy(InputError):
    """Another process holds the lock on an output: one line, exit status 2, like bad input."""


# --- what an output path may hold ----------------------------------------------------------


@dataclass(frozen=True)
class OutputKind:
    """What a stage writes at an output path. ``why_not(path)`` tells why what lies at an
    existing path is not such an output (None when it is: the stage may replace it)."""

    name: str
    why_not: Callable[[Path], str | None]


_MAX_SNIFF = 64 * 2**20  # metrics and tables larger than this are not ours


def _json_object(path: Path) -> str | None:
    if not path.is_file():
        return "is not a file"
    if path.stat().st_size > _MAX_SNIFF:
        return "is too large for a metrics file"
    try:
        value = read_json(path, "metrics file", _MAX_SNIFF)
    except InputError:
        return "is not JSON"
    return None if isinstance(value, dict) else "is JSON but not an object"


def _text_table(path: Path) -> str | None:
    if not path.is_file():
        return "is not a file"
    if path.stat().st_size > _MAX_SNIFF:
        return "is too large for a table"
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        return "is not text"
    return "is not text" if "\0" in text else None


def _png(path: Path) -> str | None:
    if not path.is_file():
        return "is not a file"
    with path.open("rb") as f:
        return None if f.read(8) == b"\x89PNG\r\n\x1a\n" else "is not a PNG image"


def store_kind(*kinds: str) -> OutputKind:
    """An episode store (Zarr group) whose ``kind`` attribute is one of ``kinds`` (any kind
    when none are given)."""

    def why_not(path: Path) -> str | None:
        meta = path / "zarr.json"
        if not path.is_dir() or not meta.is_file():
            return "is not a Zarr store"
        try:
            attrs = read_json(meta, "zarr.json").get("attributes", {})
        except (InputError, AttributeError):
            return "is not a Zarr store"
        kind = attrs.get("kind") if isinstance(attrs, dict) else None
        if kind is None or (kinds and kind not in kinds):
            return f"is a store of kind {kind!r}, not {' or '.join(map(repr, kinds))}"
        return None

    what = " or ".join(kinds) if kinds else "episode"
    return OutputKind(f"{what} store", why_not)


def directory_kind(name: str, pattern: str) -> OutputKind:
    """A directory every file of which (path relative to it, '/'-separated) fully matches the
    regular expression ``pattern``: a directory a stage made, recognised by what it holds."""
    regex = re.compile(pattern)

    def why_not(path: Path) -> str | None:
        if not path.is_dir():
            return "is not a directory"
        for root, dirs, files in os.walk(path):
            for f in files + [d for d in dirs if Path(root, d).is_symlink()]:
                rel = Path(root, f).relative_to(path).as_posix()
                if not regex.fullmatch(rel):
                    return f"holds {rel!r}, which this stage does not write"
        return None

    return OutputKind(name, why_not)


METRICS = OutputKind("metrics JSON", _json_object)
TABLE = OutputKind("CSV table", _text_table)
TEXT = OutputKind("text file", _text_table)
PNG = OutputKind("PNG image", _png)
_BY_SUFFIX = {".zarr": store_kind(), ".json": METRICS, ".csv": TABLE, ".png": PNG}

Output = str | os.PathLike | tuple[str | os.PathLike, OutputKind]


def kind_of(path: str | os.PathLike) -> OutputKind:
    """The kind of output a path names by its suffix (.zarr, .json, .csv, .png); other
    outputs are claimed with their kind."""
    kind = _BY_SUFFIX.get(Path(path).suffix)
    if kind is None:
        raise ValueError(f"{path}: no output kind for this name; claim it with its kind")
    return kind


def _why_not_replaceable(path: Path, kind: OutputKind) -> str | None:
    """Why ``path`` may not be replaced by an output of ``kind`` (None when it is absent or
    holds one). A link is judged by what it points to; a link to nothing holds nothing."""
    if not path.exists():
        return None
    why = kind.why_not(path)
    return None if why is None else f"{why}; expected a {kind.name} or nothing"


def _resolved(path: Path) -> Path:
    return Path(os.path.realpath(path))


def _nested(a: Path, b: Path) -> bool:
    return a == b or a in b.parents or b in a.parents


def check_outputs(
    outputs: Mapping[Path, OutputKind], inputs: Iterable[str | os.PathLike] = ()
) -> None:
    """InputError, before any work, when an output path holds something that is not an
    output of its kind, is (or holds, or lies in) an input, or is one of the other outputs
    (symbolic links resolved)."""
    outs = [(p, _resolved(p)) for p in outputs]
    for inp in map(Path, inputs):
        ri = _resolved(inp)
        for p, rp in outs:
            if _nested(rp, ri):
                raise InputError(
                    f"{p}: the same place as the input {inp}; writing it would destroy the "
                    "input: give another output path"
                )
    for i, (p, rp) in enumerate(outs):
        for q, rq in outs[:i]:
            if _nested(rp, rq):
                raise InputError(f"{p}: the same place as the output {q}; give distinct paths")
    for p in outputs:
        why = _why_not_replaceable(p, outputs[p])
        if why:
            raise InputError(f"{p}: {why}; give another output path or move it away")


def tracked_allowed() -> bool:
    """Whether outputs may go where a pipeline tracks them: under DVC (dvc repro, dvc exp
    run), or when the stage was told to (--replace-tracked)."""
    return _replace_tracked or pipelines.run_by_dvc()


def check_untracked(outputs: Iterable[Path]) -> None:
    """InputError, before any work, when an output path is (or lies in) a result a pipeline
    tracks (:mod:`mimicgen_pipe.data.pipelines`): a stage run by hand would mix its output into
    the pipeline's committed results."""
    for p in outputs:
        o = pipelines.owner(p)
        if o is not None:
            raise InputError(
                f"{p}: tracked by {o.dvc_file} (stage {o.stage}); a run by hand would replace "
                f"the pipeline's result: remake it with `{o.repro}`, give this stage output "
                "paths outside the pipeline's (e.g. under scratch/), or add --replace-tracked "
                "to replace it on purpose"
            )


# --- temporaries, replacing, committing ------------------------------------------------------


def temporary_name(path: Path, kind: str = "tmp") -> Path:
    """A fresh sibling name that :func:`remove_stale` recognises as a leftover of ``path``."""
    return path.with_name(f".{path.name}.{kind}-{os.getpid()}-{uuid.uuid4().hex[:8]}")


def journal_of(path: Path) -> Path:
    """Where the journal of a pending commit of ``path`` lies."""
    return path.with_name(f".{path.name}.commit")


def _remove(path: Path) -> None:
    """Remove a file or a directory tree; what cannot be removed now (a writer thread still
    adding files) is left for the next run's :func:`remove_stale`."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def _op() -> None:
    """Count one filesystem operation of a commit (see KILL_AT_ENV)."""
    global _commit_ops
    _commit_ops += 1
    at = os.environ.get(KILL_AT_ENV)
    if at and _commit_ops == int(at):
        os.kill(os.getpid(), signal.SIGKILL)


def _write_journal(final: Path, entries: Sequence[Entry]) -> None:
    """Write the journal beside ``final`` whole or not at all."""
    journal = journal_of(final)
    # named as a temporary of the output, so that a kill mid-write leaves a stale temporary
    tmp = final.with_name(temporary_name(final).name + "-commit")
    text = json.dumps({"commit": [[str(t), str(f), str(b)] for t, f, b in entries]})
    with tmp.open("w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    _op()
    os.replace(tmp, journal)


_JOURNAL_BYTES = 2**20  # journals name a few paths; a larger file is not one


def _writer_made(path: Path, final: Path, kind: str) -> bool:
    """Whether ``path`` is a name :func:`temporary_name` gives ``final`` (``kind``): in
    the output's own folder, never elsewhere."""
    pattern = rf"\.{re.escape(final.name)}\.{kind}-[0-9]+-[0-9a-f]{{8}}"
    return path.parent == final.parent and re.fullmatch(pattern, path.name) is not None


def _place(path: Path) -> Path:
    """``path`` with its folder's links resolved (not its own: an output may be a link)."""
    return Path(os.path.realpath(path.parent)) / path.name


def _open_no_link(path: Path, flags: int, what: str) -> int:
    """A descriptor of the regular file at ``path``, opened never through a symbolic link
    (nor waiting on a FIFO): InputError, ending with ``what`` to do, for anything else;
    OSError for a file that cannot be opened."""
    fd = None
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, 0o644)
    except OSError as exc:
        if exc.errno not in (errno.ELOOP, errno.EISDIR, errno.ENXIO):
            raise
    if fd is not None and stat.S_ISREG(os.fstat(fd).st_mode):
        return fd
    if fd is not None:
        os.close(fd)
    raise InputError(f"{path}: not a regular file (a symbolic link, folder or device); {what}")


def _read_journal(journal: Path, path: Path) -> list[Entry]:
    """The entries of the journal beside output ``path``, read without following a link,
    each checked to be what a writer of ``path``'s set makes: a temporary and an old name of
    an output in that output's own folder, one entry being ``path`` itself. InputError
    otherwise: nothing a journal names elsewhere is ever acted on."""
    remove = "remove it if no run of the stage that writes it was stopped while committing"
    try:
        with os.fdopen(_open_no_link(journal, os.O_RDONLY, remove), "rb") as f:
            data = f.read(_JOURNAL_BYTES + 1)
    except OSError as exc:
        raise InputError(f"{journal}: cannot read the commit journal ({exc.strerror})") from exc
    try:
        if len(data) > _JOURNAL_BYTES:
            raise ValueError("too large")
        commit = parse_json(data, str(journal))["commit"]
        entries = [(Path(t), Path(f), Path(b)) for t, f, b in commit]
        if not all(p.is_absolute() for entry in entries for p in entry):
            raise ValueError("a path in it is not absolute")
    except (InputError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{journal}: not a commit journal ({exc}); {remove}") from exc
    ours = all(_writer_made(t, f, "tmp") and _writer_made(b, f, "old") for t, f, b in entries)
    if not ours or not any(_place(f) == _place(path.absolute()) for _, f, _ in entries):
        raise InputError(
            f"{journal}: not a commit journal of {path.name} (it names paths a writer of "
            f"{path.name} never makes); nothing done: {remove}"
        )
    return entries


def _unfinished(entries: Sequence[Entry]) -> bool:
    """Whether a journaled commit must be rolled forward: every journal in place (the commit
    had begun) and a temporary not yet moved in. With a journal missing, the run was killed
    writing them (nothing moved yet) or removing them (everything moved): nothing to redo."""
    finals = [f for _, f, _ in entries]
    return all(os.path.lexists(journal_of(f)) for f in finals) and any(
        os.path.lexists(t) for t, _, _ in entries
    )


def _roll_forward(entries: Sequence[Entry]) -> None:
    """Put every temporary of a journaled commit in place (those already moved are skipped),
    then remove the old outputs moved aside. Safe to repeat after a kill at any point."""
    for tmp, _, _ in entries:  # the writer made files and folders only: a link is not ours
        if os.path.islink(tmp):
            raise InputError(f"{tmp}: a symbolic link where a temporary output should be")
    for tmp, final, backup in entries:
        if not os.path.lexists(tmp):
            continue  # moved in already
        if os.path.lexists(final) and (final.is_dir() or final.is_symlink()):
            _op()  # a directory cannot replace another in one rename: the old goes aside
            final.rename(backup)
        _op()
        os.replace(tmp, final)
    for _, _, backup in entries:
        if os.path.lexists(backup):
            _op()
            _remove(backup)


def _commit(pairs: Sequence[tuple[Path, Path]]) -> None:
    """Move each temporary onto its output, all or none after a kill at any instant: a single
    rename where that is atomic already, else through journals (module docstring)."""
    (tmp, final), *rest = pairs
    if not rest and not (os.path.lexists(final) and (final.is_dir() or final.is_symlink())):
        os.replace(tmp, final)
        return
    entries = [(t.absolute(), f.absolute(), temporary_name(f, "old").absolute()) for t, f in pairs]
    for _, final in pairs:
        _write_journal(final, entries)
    _roll_forward(entries)
    for _, final in pairs:
        _op()
        journal_of(final).unlink()


def recover(path: str | os.PathLike) -> bool:
    """Complete a commit of ``path``'s output set that a killed run left journaled (True
    when there was one). Only the stage that owns the outputs does this (:func:`claim`):
    InputError unless this process holds the lock of every output the journal names; the
    journal itself is checked by :func:`_read_journal`, and nothing is moved before."""
    path = Path(path)
    journal = journal_of(path)
    if not os.path.lexists(journal):
        return False
    entries = _read_journal(journal, path)
    held = {_place(lock.absolute()) for lock in _HELD}
    for _, final, _ in entries:
        if _place(lock_file(final)) not in held:
            raise InputError(
                f"{journal}: a stopped commit of {path} names {final}, which this run does "
                "not write; re-run the stage with the outputs it was given then, or remove "
                "the journal if no such run was stopped"
            )
    with interrupts.deferred():
        if _unfinished(entries):
            _roll_forward(entries)
        for _, final, _ in entries:
            with contextlib.suppress(FileNotFoundError):
                journal_of(final).unlink()
    return True


def check_committed(path: str | os.PathLike) -> None:
    """For readers, before reading output ``path``: InputError when a commit of its output
    set was stopped half done (readers never act on a journal; the stage that writes the
    set completes it when it runs again) or when the journal beside it is not one a writer
    of it made. A journal left from a commit that had completed is no obstacle."""
    path = Path(path)
    journal = journal_of(path)
    if os.path.lexists(journal) and _unfinished(_read_journal(journal, path)):
        raise InputError(
            f"{path}: the run that wrote it was stopped while putting its outputs in place "
            f"(journal {journal}); run that stage again, which completes the commit first"
            f"{pipelines.made_by(path)}"
        )


def check_committed_in(folder: str | os.PathLike) -> None:
    """:func:`check_committed` for every output in ``folder`` that has a journal (for
    readers of a whole folder of outputs, such as the report)."""
    for journal in sorted(Path(folder).glob(".*.commit")):
        check_committed(journal.with_name(journal.name[1 : -len(".commit")]))


def _disk_error(exc: OSError, path: Path, tmps: Sequence[Path]) -> InputError | None:
    """One line for a full or read-only disk met while writing ``path`` (None for other
    errors): the path, the free space and what had been written when it happened."""
    if exc.errno not in (errno.ENOSPC, errno.EDQUOT, errno.EROFS):
        return None
    where = path.parent if path.parent.exists() else Path(".")
    if exc.errno == errno.EROFS:
        return InputError(f"{path}: cannot write in {where} ({exc.strerror})")
    written = sum(_size(t) for t in tmps)
    free = shutil.disk_usage(where).free
    return InputError(
        f"{path}: no space left on the device of {where}: {_mb(free)} free, and the output "
        f"needs more than the {_mb(written)} written when the disk filled; free space there "
        "or write elsewhere (the previous output is unchanged)"
    )


def _size(path: Path) -> int:
    if path.is_file():
        return path.stat().st_size
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.is_dir() else 0


def _mb(n: int) -> str:
    return f"{n / 2**20:.1f} MB"


def free_space_error(path: str | os.PathLike, needed: int) -> InputError | None:
    """InputError when the device that will hold ``path`` has less than ``needed`` bytes
    free (checked before writing where a full disk cannot be handled, e.g. inside HDF5)."""
    where = Path(path)
    while not where.exists() and where != where.parent:
        where = where.parent
    free = shutil.disk_usage(where).free
    if free >= needed:
        return None
    return InputError(
        f"{path}: not enough free space on the device of {where}: {_mb(free)} free, about "
        f"{_mb(needed)} needed"
    )


def wrote_outputs() -> bool:
    """Whether this process has put an output in place (for the interrupt message)."""
    return _written


def _check_claimed_or_replaceable(pairs: Sequence[tuple[Path, Path]]) -> None:
    """At commit: every output still absent or of its kind (its claimed kind, else the kind
    its name says)."""
    for _, final in pairs:
        kind = _CLAIMED.get(_resolved(final)) or _BY_SUFFIX.get(final.suffix)
        if kind is None:
            if os.path.lexists(final):
                raise InputError(f"{final}: exists and is not a claimed output; not replaced")
            continue
        why = _why_not_replaceable(final, kind)
        if why:
            raise InputError(f"{final}: {why}; not replaced")


@contextlib.contextmanager
def output_set(*paths: str | os.PathLike) -> Iterator[list[Path]]:
    """Yield one temporary path per output (not created: the caller writes a file or a
    directory there). When the block completes, every temporary must exist; they are
    committed together (module docstring) with SIGINT/SIGTERM held back. When the block
    raises, the temporaries are removed and no output changes; a full or read-only disk
    becomes one InputError."""
    global _staging, _written
    finals = [Path(p) for p in paths]
    tmps = [temporary_name(p) for p in finals]
    try:
        for p in finals:
            p.parent.mkdir(parents=True, exist_ok=True)
        _staging += 1
        try:
            yield tmps
        finally:
            _staging -= 1
        missing = [str(f) for t, f in zip(tmps, finals, strict=True) if not t.exists()]
        if missing:
            raise RuntimeError(f"output set: nothing was written for {missing}")
        pairs = list(zip(tmps, finals, strict=True))
        _check_claimed_or_replaceable(pairs)
        with interrupts.deferred():
            _commit(pairs)
            _written = _written or not _staging
    except OSError as exc:
        error = _disk_error(exc, finals[0], tmps)
        if error is None:
            raise
        raise error from exc
    finally:
        for tmp in tmps:
            _remove(tmp)


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary sibling directory of ``path``; when the block completes it replaces
    ``path`` (an output set of one), and when it raises (or is interrupted) it is removed and
    ``path`` is untouched."""
    with output_set(path) as (tmp,):
        tmp.mkdir()
        yield tmp


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
    """Remove the stale temporaries of ``path``; call it only while holding its lock and
    after :func:`recover` (a pending commit's temporaries are not stale)."""
    stale = stale_temporaries(path)
    for p in stale:
        _remove(p)
    return stale


# --- locks ---------------------------------------------------------------------------------

_HELD: dict[Path, int] = {}  # lock file -> open descriptor holding the flock
_CLAIMED: dict[Path, OutputKind] = {}  # resolved output path -> the kind claimed for it
_MADE: dict[Path, list[Path]] = {}  # lock file -> the folders claiming it created


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
        try:  # never through a link: the pid would overwrite the file it points to
            fd = _open_no_link(lock, os.O_RDWR | os.O_CREAT, "remove it or write elsewhere")
        except OSError as exc:
            raise InputError(f"{path}: cannot write in {lock.parent} ({exc.strerror})") from exc
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
            st, now = os.fstat(fd), os.lstat(lock)
            same = (st.st_dev, st.st_ino) == (now.st_dev, now.st_ino)
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            return fd
        os.close(fd)
    raise OutputBusy(f"{path}: could not lock {lock} (it keeps being replaced)")


def claim(*outputs: Output, inputs: Iterable[str | os.PathLike] = ()) -> None:
    """Before any work: lock every output of the stage (all or none), complete a commit a
    killed run left pending, remove what killed runs left beside them, and check
    (:func:`check_outputs`) that each output may be written: absent or of its kind (given
    as ``(path, kind)``, else :func:`kind_of` its name), not an input, not another output.
    Held until :func:`release` (the entry point calls it when the stage ends) or the process
    exits; claiming a path this process holds already is a no-op."""
    kinds = {
        Path(o[0]) if isinstance(o, tuple) else Path(o): o[1]
        if isinstance(o, tuple)
        else kind_of(o)
        for o in outputs
    }
    if len(kinds) < len(outputs):
        raise InputError("the same output path is given twice; give distinct paths")
    if not tracked_allowed():
        check_untracked(kinds)
    check_outputs(kinds, inputs)  # before locking, so that a bad path leaves nothing behind
    taken: list[Path] = []
    try:
        for p in kinds:
            lock = lock_file(p)
            if lock in _HELD:
                continue
            made = [d for d in (p.parent, *p.parent.parents) if not d.exists()]
            try:
                p.parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise InputError(f"{p}: cannot create {p.parent} ({exc.strerror})") from exc
            _MADE[lock] = made  # deepest first: removed again at release while still empty
            _HELD[lock] = _acquire(p)
            taken.append(lock)
        for p in kinds:
            recover(p)
        check_outputs(kinds, inputs)  # what a completed commit put there
    except BaseException:
        release(taken)
        raise
    for p, kind in kinds.items():
        _CLAIMED[_resolved(p)] = kind
        remove_stale(p)


def release(locks: list[Path] | None = None) -> None:
    """Let go of the given lock files (default: all this process holds), removing them first
    so that no empty lock files stay behind."""
    # the last taken first: a folder made for an earlier lock is empty when its turn comes
    for lock in reversed(list(_HELD) if locks is None else locks):
        fd = _HELD.pop(lock, None)
        if fd is None:
            continue
        with contextlib.suppress(FileNotFoundError):
            lock.unlink()
        os.close(fd)
        for folder in _MADE.pop(lock, ()):  # a refused stage leaves no empty folders
            with contextlib.suppress(OSError):
                folder.rmdir()
    if locks is None:
        _CLAIMED.clear()


atexit.register(release)


@contextlib.contextmanager
def claims(replace_tracked: bool = False) -> Iterator[None]:
    """Release every claim made within the block when it ends (the entry point wraps each
    stage in one). Outside DVC, outputs a pipeline tracks are refused unless
    ``replace_tracked`` (:func:`check_untracked`)."""
    global _written, _replace_tracked
    _written, _replace_tracked = False, replace_tracked
    try:
        yield
    finally:
        _replace_tracked = False
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
