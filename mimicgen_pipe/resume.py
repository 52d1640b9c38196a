"""Work directories: the finished blocks of a run, kept so that a killed run resumes.

A run that writes ``<dir>/<name>`` keeps its finished blocks in ``<dir>/.<name>.work/``:
one file per block (``block-<index>.pkl``: the SHA-256 of the payload, then the pickled
result), each written under a temporary name and renamed when complete, and a ``key`` file
naming the run. The key is a function of everything that shapes a block's result (the
run id of the data-shaping params and inputs, the block size, and the code of this package
and of the simulator back ends), so that a run started again with the same key reuses the
blocks and computes only the rest, and a run with another key discards them: blocks of two
different runs are never mixed. The directory is removed once the run's outputs are in place.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

_BLOCK = re.compile(r"block-(\d+)\.pkl")
_DIGEST_BYTES = 32


def work_dir_of(output: str | os.PathLike) -> Path:
    """The work directory of the run writing ``output``."""
    output = Path(output)
    return output.with_name(f".{output.name}.work")


def code_digest(*packages: str) -> str:
    """sha256 over the source files of the given top-level packages (found on sys.path):
    a block computed by other code is not reused."""
    import importlib.util

    h = hashlib.sha256()
    for name in packages:
        spec = importlib.util.find_spec(name)
        if spec is None or not spec.submodule_search_locations:
            raise ValueError(f"{name}: not a package")
        root = Path(next(iter(spec.submodule_search_locations)))
        for f in sorted(root.rglob("*.py")):
            h.update(f.relative_to(root.parent).as_posix().encode() + b"\0")
            h.update(f.read_bytes())
    return h.hexdigest()


@dataclass(frozen=True)
class WorkDir:
    """The finished blocks of the run whose key is ``key``, in ``path``; ``resumed``: those
    that earlier runs had saved when it was opened (checked)."""

    path: Path
    key: str
    resumed: frozenset[int] = frozenset()

    @classmethod
    def open(cls, output: str | os.PathLike, key: str) -> WorkDir:
        """The work directory beside ``output`` for the run ``key``: what it holds is kept
        when it belongs to this run, else removed. Call it holding the lock on ``output``."""
        path = work_dir_of(output)
        key_file = path / "key"
        if path.exists() and not (key_file.is_file() and key_file.read_text() == key):
            shutil.rmtree(path)
        if not path.exists():
            tmp = path.with_name(path.name + ".new")
            shutil.rmtree(tmp, ignore_errors=True)
            tmp.mkdir(parents=True)
            (tmp / "key").write_text(key)
            os.replace(tmp, path)
        work = cls(path, key)
        return cls(path, key, frozenset(work.finished()))

    def _file(self, index: int) -> Path:
        return self.path / f"block-{index:06d}.pkl"

    def finished(self) -> set[int]:
        """Indices of the blocks saved complete (a damaged file is removed and its block
        counts as not run)."""
        done = set()
        for f in self.path.iterdir():
            m = _BLOCK.fullmatch(f.name)
            if m is None:
                if f.name != "key":  # a temporary of a block being saved when killed
                    f.unlink()
                continue
            if self._read(f) is None:
                f.unlink()
            else:
                done.add(int(m.group(1)))
        return done

    def save(self, index: int, result: Any) -> None:
        """Save a finished block; it is there complete or not at all."""
        payload = pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL)
        target = self._file(index)
        tmp = target.with_name(target.name + f".tmp-{os.getpid()}")
        with tmp.open("wb") as f:
            f.write(hashlib.sha256(payload).digest())
            f.write(payload)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, target)

    def load(self, index: int) -> Any:
        """A saved block's result (listed by :meth:`finished`)."""
        raw = self._read(self._file(index))
        if raw is None:
            raise RuntimeError(f"{self._file(index)}: damaged since the run started")
        return pickle.loads(raw)

    @staticmethod
    def _read(f: Path) -> bytes | None:
        data = f.read_bytes()
        payload = data[_DIGEST_BYTES:]
        if len(data) < _DIGEST_BYTES or hashlib.sha256(payload).digest() != data[:_DIGEST_BYTES]:
            return None
        return payload

    def remove(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)
