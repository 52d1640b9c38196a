"""Work directories: the finished blocks of a run, kept so that a killed run resumes.

A run that writes ``<dir>/<name>`` keeps its finished blocks in ``<dir>/.<name>.work/``:
one file per block, ``block-<index>.npz``, and a ``key`` file naming the run. A block file
is a zip of plain ``.npy`` arrays (numbers, booleans and strings, never pickled objects):
the block's index, the run's key, and the arrays a :class:`BlockCodec` makes of the block's
result. It is written under a temporary name and renamed when complete.

The key is a function of everything that shapes a block's result (the run id of the
data-shaping params and inputs, the block size, and the code of this package and of the
simulator back ends), so that a run started again with the same key reuses the blocks and
computes only the rest, and a run with another key discards them: blocks of two different
runs are never mixed. The directory is a cache: a file in it is used only when it reads
back whole (zip CRCs), with pickled data refused, names the index of its file name and this
run's key, and the codec accepts it for that index (a generation block holds the seeds of
the block at that index). Anything else, a damaged block, one copied over another or from
another run, a file of an older format, is discarded unread or unused and its block is run
again; a link in place of the directory is removed, never followed. A block that cannot be
written (a full disk) ends the run with one line naming the file and the free space, its
temporary removed. The directory is removed once the run's outputs are in place.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from mimicgen_pipe.core.errors import InputError

_BLOCK = re.compile(r"block-(\d+)\.npz")
_TEMPORARY = re.compile(r"block-\d+\.npz\.tmp-\d+")
_RESULT = "result/"  # prefix of the codec's arrays in a block file


class BadBlock(ValueError):
    """A block file that is not the complete block its name says (the message says why)."""


class BlockCodec(Protocol):
    """A block's result as named plain arrays (no object dtype) and back."""

    def encode(self, index: int, result: Any) -> dict[str, np.ndarray]:
        """The arrays block ``index``'s result is saved as."""

    def decode(self, index: int, arrays: Mapping[str, np.ndarray]) -> Any:
        """The result rebuilt from the arrays ``encode`` made; raises BadBlock when they
        are not a result of block ``index`` (e.g. another block's seeds)."""


def work_dir_of(output: str | os.PathLike) -> Path:
    """The work directory of the run writing ``output``."""
    output = Path(output)
    return output.with_name(f".{output.name}.work")


# what a package's results are made by: its Python and its shaders (the ManiSkill cameras')
CODE_SUFFIXES = (".py", ".vert", ".frag")


def code_digest(*packages: str) -> str:
    """sha256 over the source files (CODE_SUFFIXES) of the given top-level packages (found
    on sys.path): a block computed by other code is not reused."""
    import importlib.util

    h = hashlib.sha256()
    for name in packages:
        spec = importlib.util.find_spec(name)
        if spec is None or not spec.submodule_search_locations:
            raise ValueError(f"{name}: not a package")
        root = Path(next(iter(spec.submodule_search_locations)))
        for f in sorted(f for f in root.rglob("*") if f.suffix in CODE_SUFFIXES):
            h.update(f.relative_to(root.parent).as_posix().encode() + b"\0")
            h.update(f.read_bytes())
    return h.hexdigest()


def write_error(path: Path, exc: OSError, then: str = "") -> InputError:
    """One line for a file that could not be written (a full disk, a quota, a file size
    limit): the file, the system's reason, the space left on its device, and ``then``."""
    try:
        free = f"{shutil.disk_usage(path.parent).free / 2**20:.1f} MB free there"
    except OSError:  # the folder is gone or unreadable too
        free = "free space there unknown"
    return InputError(f"{path}: could not be written ({exc.strerror or exc}); {free}{then}")


def read_arrays(f: Path) -> dict[str, np.ndarray]:
    """Every array of a zip of ``.npy`` members (as ``numpy.savez`` writes it), read with
    pickled data refused and every member's CRC checked; BadBlock when it is not one."""
    if f.is_symlink() or not f.is_file():
        raise BadBlock("not a regular file")
    arrays = {}
    try:
        with zipfile.ZipFile(f) as z:
            for info in z.infolist():
                if not info.filename.endswith(".npy"):
                    raise BadBlock(f"unexpected member {info.filename!r}")
                with z.open(info) as member:
                    arrays[info.filename[: -len(".npy")]] = np.lib.format.read_array(
                        member, allow_pickle=False
                    )
                    if member.read(1):  # reading to the end also checks the CRC
                        raise BadBlock(f"{info.filename}: bytes after the array")
    except BadBlock:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zipfile.LargeZipFile) as exc:
        raise BadBlock(f"unreadable ({exc})") from None
    return arrays


def _remove(path: Path) -> None:
    """Remove a file, a link (not what it points to) or a directory tree, if there."""
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        path.unlink()
    elif path.exists():
        shutil.rmtree(path)


@dataclass(frozen=True)
class WorkDir:
    """The finished blocks of the run whose key is ``key``, in ``path``, stored through
    ``codec``; ``resumed``: those that earlier runs had saved when it was opened (checked);
    ``discarded``: one line for each file found then that was not used (and is gone)."""

    path: Path
    key: str
    codec: BlockCodec
    resumed: frozenset[int] = frozenset()
    discarded: tuple[str, ...] = ()

    @classmethod
    def open(cls, output: str | os.PathLike, key: str, codec: BlockCodec) -> WorkDir:
        """The work directory beside ``output`` for the run ``key``: what it holds is kept
        when it belongs to this run, else removed. Call it holding the lock on ``output``."""
        path = work_dir_of(output)
        key_file = path / "key"
        ours = not path.is_symlink() and path.is_dir()  # a link is removed, not followed
        if ours and not (key_file.is_file() and key_file.read_bytes() == key.encode()):
            ours = False
        if not ours:
            _remove(path)
            tmp = path.with_name(path.name + ".new")
            _remove(tmp)
            try:
                tmp.mkdir(parents=True)
                (tmp / "key").write_text(key)
                os.replace(tmp, path)
            except OSError as exc:
                _remove(tmp)
                raise write_error(tmp / "key", exc) from None
        done, discarded = cls(path, key, codec)._scan()
        return cls(path, key, codec, frozenset(done), tuple(discarded))

    def _file(self, index: int) -> Path:
        return self.path / f"block-{index:06d}.npz"

    def finished(self) -> set[int]:
        """Indices of the blocks saved complete (any other file is removed, and its block
        counts as not run)."""
        return self._scan()[0]

    def _scan(self) -> tuple[set[int], list[str]]:
        done, discarded = set(), []
        for f in sorted(self.path.iterdir()):
            if f.name == "key":
                continue
            m = _BLOCK.fullmatch(f.name)
            if m is None:
                # a temporary is what a run killed while saving leaves: nothing to report
                if not _TEMPORARY.fullmatch(f.name):
                    discarded.append(f"{f}: not a block file; removed unread")
            else:
                try:
                    self._read(f, int(m.group(1)))
                    done.add(int(m.group(1)))
                    continue
                except BadBlock as exc:
                    discarded.append(f"{f}: {exc}; discarded, its block is run again")
            _remove(f)
        return done, discarded

    def save(self, index: int, result: Any) -> None:
        """Save a finished block; it is there complete or not at all. InputError naming the
        file and the free space when it cannot be written (the temporary is removed)."""
        arrays = {"index": np.int64(index), "key": np.str_(self.key)}
        arrays |= {_RESULT + k: v for k, v in self.codec.encode(index, result).items()}
        target = self._file(index)
        tmp = target.with_name(target.name + f".tmp-{os.getpid()}")
        try:
            with tmp.open("wb") as f:
                with zipfile.ZipFile(f, "w", zipfile.ZIP_STORED) as z:
                    for name, value in arrays.items():
                        with z.open(name + ".npy", "w", force_zip64=True) as member:
                            np.lib.format.write_array(
                                member, np.asanyarray(value), allow_pickle=False
                            )
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, target)
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            kept = "; the blocks saved before are kept, and the same command resumes from them"
            raise write_error(target, exc, kept) from None

    def load(self, index: int) -> Any:
        """A saved block's result (listed by :meth:`finished`)."""
        try:
            return self._read(self._file(index), index)
        except BadBlock as exc:
            raise RuntimeError(
                f"{self._file(index)}: damaged since the run started ({exc})"
            ) from None

    def _read(self, f: Path, index: int) -> Any:
        """The result in block file ``f`` if it is block ``index`` of this run, else
        BadBlock."""
        arrays = read_arrays(f)
        stored = arrays.get("index")
        if stored is None or stored.shape != () or stored.dtype.kind not in "iu":
            raise BadBlock("no block index")
        if int(stored) != index:
            raise BadBlock(f"holds block {int(stored)}, not {index}")
        key = arrays.get("key")
        if key is None or key.shape != () or key.dtype.kind != "U" or str(key) != self.key:
            raise BadBlock("a block of another run")
        result = {k[len(_RESULT) :]: v for k, v in arrays.items() if k.startswith(_RESULT)}
        try:
            return self.codec.decode(index, result)
        except BadBlock:
            raise
        except (KeyError, ValueError, TypeError, IndexError) as exc:
            raise BadBlock(f"not a result of this run's blocks ({exc!r})") from None

    def remove(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)
