"""Which pipeline stage owns a path: read from the committed ``dvc.lock`` files, so that a
stage run by hand never replaces a pipeline's tracked result, and a missing input names the
stage that makes it.

A path is *tracked* when it is, or lies inside, an output (``outs``, ``metrics``, ``plots``)
that a lock records for a stage of ``dvc.yaml`` at the repository root or of
``<folder>/dvc.yaml`` one level below it. Paths in a lock are relative to the stage's working
directory (``wdir`` in its dvc.yaml, else the dvc.yaml's folder). Nothing here imports DVC:
the locks are plain YAML."""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path

import yaml

# DVC sets it for every command a stage runs (dvc repro, dvc exp run)
DVC_STAGE_ENV = "DVC_STAGE"


@dataclass(frozen=True)
class Owner:
    """The stage of a pipeline that writes a tracked path."""

    dvc_file: str  # the pipeline's dvc.yaml, relative to the repository root
    stage: str  # its name in the lock, e.g. "export@D0"

    @property
    def repro(self) -> str:
        """The command that remakes the path in its pipeline."""
        target = self.stage if self.dvc_file == "dvc.yaml" else f"{self.dvc_file}:{self.stage}"
        return f"dvc repro {target}"


def repository_root(path: str | os.PathLike) -> Path | None:
    """The nearest folder at or above ``path`` (made absolute) that holds a ``.dvc``
    folder: the DVC repository the path belongs to, or None."""
    p = Path(os.path.abspath(path))
    for d in (p, *p.parents):
        if (d / ".dvc").is_dir():
            return d
    return None


def _stages(path: Path) -> dict[str, dict]:
    """The ``stages`` mapping of a dvc.yaml or dvc.lock, name -> body (bodies that are not
    mappings left out); empty when the file is absent or not such YAML."""
    try:
        stages = (yaml.safe_load(path.read_text(encoding="utf-8")) or {}).get("stages")
    except (OSError, yaml.YAMLError, AttributeError):
        return {}
    if not isinstance(stages, dict):
        return {}
    return {str(name): body for name, body in stages.items() if isinstance(body, dict)}


def _lock_outputs(root: Path, dvc_file: Path) -> dict[Path, Owner]:
    """Every output the lock beside ``dvc_file`` records, as an absolute path, with its
    stage (its working directory from ``dvc_file``)."""
    dirs = {
        name: (dvc_file.parent / str(body.get("wdir", "."))).resolve()
        for name, body in _stages(dvc_file).items()
    }
    name = dvc_file.relative_to(root).as_posix()
    found: dict[Path, Owner] = {}
    for stage, body in _stages(dvc_file.with_name("dvc.lock")).items():
        wdir = dirs.get(stage.split("@")[0], dvc_file.parent.resolve())
        for out in body.get("outs") or ():
            if isinstance(out, dict) and "path" in out:
                found[(wdir / str(out["path"])).resolve()] = Owner(name, stage)
    return found


@functools.cache
def _tracked(root: Path, stamp: tuple[float, ...]) -> dict[Path, Owner]:
    """Every tracked output of the repository at ``root`` (``stamp``: the locks' mtimes, so
    that an edited lock is read again)."""
    del stamp
    found: dict[Path, Owner] = {}
    for dvc_file in _pipeline_files(root):
        found |= _lock_outputs(root, dvc_file)
    return found


def _pipeline_files(root: Path) -> list[Path]:
    return sorted(p for p in (root / "dvc.yaml", *root.glob("*/dvc.yaml")) if p.is_file())


def owner(path: str | os.PathLike) -> Owner | None:
    """The stage whose tracked output ``path`` is, lies inside or holds (a folder that
    holds tracked files), or None (also outside any DVC repository). Links are followed: a
    path through a link into a repository's tracked results is one of them."""
    real = Path(os.path.realpath(path))
    # the repository above the path as written, and above where its links lead
    for root in dict.fromkeys(r for r in (repository_root(path), repository_root(real)) if r):
        found = _owner_in(root, real)
        if found is not None:
            return found
    return None


def _owner_in(root: Path, p: Path) -> Owner | None:
    """:func:`owner` of the resolved path ``p`` among the tracked outputs of ``root``."""
    locks = [f.with_name("dvc.lock") for f in _pipeline_files(root)]
    stamp = tuple(f.stat().st_mtime if f.is_file() else 0.0 for f in locks)
    tracked = _tracked(root, stamp)
    for candidate in (p, *p.parents):
        if candidate in tracked:
            return tracked[candidate]
    if p == root.resolve():
        return None  # the repository itself is no output
    inside = sorted(t for t in tracked if p in t.parents)
    return tracked[inside[0]] if inside else None


def run_by_dvc() -> bool:
    """Whether this process runs a stage's command for DVC (dvc repro, dvc exp run)."""
    return bool(os.environ.get(DVC_STAGE_ENV))


def made_by(path: str | os.PathLike) -> str:
    """``"; made by stage S of P: run `dvc repro ...`"`` for a tracked path, else ``""``:
    the hint a missing-input error ends with."""
    o = owner(path)
    return "" if o is None else f"; made by stage {o.stage} of {o.dvc_file}: run `{o.repro}`"
