"""Which pipeline stage owns a path: read from the committed ``dvc.lock`` files, so that a
stage run by hand never replaces a pipeline's tracked result, and a missing input names the
stage that makes it.

A path is *tracked* when it is, or lies inside, an output (``outs``, ``metrics``, ``plots``)
that a lock records for a stage of ``dvc.yaml`` at the repository root or of a ``dvc.yaml``
one or two folders below it (``suite/dvc.yaml``, ``suite/scaling/dvc.yaml``). Paths in a lock
are relative to the stage's working directory (``wdir`` in its dvc.yaml, else the dvc.yaml's
folder). Nothing here imports DVC: the locks are plain YAML.

A stage runs in the pipeline of its params file's folder (:func:`use_pipeline`): its default
paths lie where that pipeline's dvc.yaml keeps them (:func:`layout_roots`), and a path that
several pipelines track is named as that pipeline's."""

from __future__ import annotations

import functools
import os
import re
from dataclasses import dataclass
from pathlib import Path

import yaml

# DVC sets it for every command a stage runs (dvc repro, dvc exp run)
DVC_STAGE_ENV = "DVC_STAGE"

_current: Path | None = None  # the dvc.yaml of the running stage's pipeline (use_pipeline)


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


def _body(stage: dict) -> dict:
    """A dvc.yaml stage's body: the ``do`` of a ``foreach`` stage, else the stage itself."""
    do = stage.get("do")
    return do if "foreach" in stage and isinstance(do, dict) else stage


def _lock_outputs(root: Path, dvc_file: Path) -> dict[Path, Owner]:
    """Every output the lock beside ``dvc_file`` records, as an absolute path, with its
    stage (its working directory from ``dvc_file``)."""
    dirs = {
        name: (dvc_file.parent / str(_body(body).get("wdir", "."))).resolve()
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
def _tracked(root: Path, stamp: tuple[float, ...], current: Path | None) -> dict[Path, Owner]:
    """Every tracked output of the repository at ``root`` (``stamp``: the locks' mtimes, so
    that an edited lock is read again), owned by the ``current`` pipeline where it tracks it
    too."""
    del stamp
    found: dict[Path, Owner] = {}
    # the current pipeline's last: its owners replace another pipeline's of the same path
    for dvc_file in sorted(_pipeline_files(root), key=lambda f: f == current):
        found |= _lock_outputs(root, dvc_file)
    return found


def _pipeline_files(root: Path) -> list[Path]:
    found = (root / "dvc.yaml", *root.glob("*/dvc.yaml"), *root.glob("*/*/dvc.yaml"))
    return sorted(p for p in found if p.is_file())


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
    tracked = _tracked(root, stamp, _current)
    for candidate in (p, *p.parents):
        if candidate in tracked:
            return tracked[candidate]
    if p == root.resolve():
        return None  # the repository itself is no output
    inside = sorted(t for t in tracked if p in t.parents)
    return tracked[inside[0]] if inside else None


def use_pipeline(params_file: str | os.PathLike) -> None:
    """Run in the pipeline whose dvc.yaml lies beside ``params_file`` (none: the default
    layout): :func:`layout_roots` follows its dvc.yaml, and :func:`owner` names its stage
    for a path that other pipelines track too."""
    global _current
    dvc_file = Path(os.path.abspath(params_file)).with_name("dvc.yaml")
    _current = dvc_file if dvc_file.is_file() else None


def layout_roots() -> dict[str, Path]:
    """First folder of a default path (data, metrics, plots, ...) -> the folder, relative to
    the repository root, that holds it in the current pipeline: its dvc.yaml's folder where
    one of its stages writes an output below <that folder>/<first folder> (e.g. quickstart/
    for quickstart/data/...). Empty outside a pipeline: paths as
    :mod:`mimicgen_pipe.data.layout` builds them."""
    if _current is None:
        return {}
    return _roots(_current, _current.stat().st_mtime)


@functools.cache
def _roots(dvc_file: Path, mtime: float) -> dict[str, Path]:
    """:func:`layout_roots` of ``dvc_file`` (``mtime``: read again once edited)."""
    del mtime
    folder, root = dvc_file.parent, repository_root(dvc_file)
    if root is None or folder == root:
        return {}
    tops = {o.relative_to(folder).parts[0] for o in _declared(dvc_file) if folder in o.parents}
    return dict.fromkeys(sorted(tops), folder.relative_to(root))


def declares(path: str | os.PathLike) -> bool:
    """Whether a stage of the current pipeline declares ``path`` (relative to the repository
    root) as an output, a ${...} of its dvc.yaml matching any name; True outside a pipeline,
    whose layout has every default path."""
    if _current is None or (root := repository_root(_current)) is None:
        return True
    target = (root / path).as_posix()
    for out in _declared(_current):
        parts = re.split(r"\$\{[^}]*\}", out.as_posix())
        if re.fullmatch("[^/]+".join(map(re.escape, parts)), target):
            return True
    return False


def _declared(dvc_file: Path) -> list[Path]:
    """Every output (outs, metrics, plots) that a stage of ``dvc_file`` declares, as an
    absolute normalised path (templates such as ${task} left in)."""
    found = []
    for stage in _stages(dvc_file).values():
        body = _body(stage)
        wdir = dvc_file.parent / str(body.get("wdir", "."))
        for key in ("outs", "metrics", "plots"):
            for out in body.get(key) or ():
                for path in out if isinstance(out, dict) else [out]:
                    found.append(Path(os.path.normpath(wdir / str(path))))
    return found


def run_by_dvc() -> bool:
    """Whether this process runs a stage's command for DVC (dvc repro, dvc exp run)."""
    return bool(os.environ.get(DVC_STAGE_ENV))


def made_by(path: str | os.PathLike) -> str:
    """``"; made by stage S of P: run `dvc repro ...`"`` for a tracked path, else ``""``:
    the hint a missing-input error ends with."""
    o = owner(path)
    return "" if o is None else f"; made by stage {o.stage} of {o.dvc_file}: run `{o.repro}`"
