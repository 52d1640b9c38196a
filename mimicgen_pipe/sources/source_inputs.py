"""Source demos brought in from a file (source.from_file): where a pipeline keeps them, and
which file a run read.

DVC re-runs a stage when one of its deps changes, and a params value is a string: a file
that source.from_file names is not a dep, so editing it in place would leave the source
stage "up to date". A pipeline that takes brought-in demos therefore has an inputs folder,
``<its dvc.yaml's folder>/inputs/``, that its source stage declares as a dep, and its
params' source.from_file must name a file inside it (:func:`check_place`). A pipeline whose
source stages do not track such a folder makes its own source demos. Outside any pipeline
(no dvc.yaml beside the params file) nothing tracks the file and any file may be named.

The source stage names the file it read, with its sha256, in its log line and metrics
(:func:`file_identity`), so that a reader can tell which version of the file a run used."""

from __future__ import annotations

import hashlib
import os
import re
from pathlib import Path

from mimicgen_pipe.core.errors import InputError

# pipelines' dvc.yaml readers (_stages, _pipeline_files) are used as they are: an edit of
# pipelines.py would re-run every stage (all depend on mimicgen_pipe/data)
from mimicgen_pipe.data import pipelines

INPUTS = "inputs"  # beside a pipeline's dvc.yaml: the folder its source stage tracks
# a stage whose command runs the source stage (dvc.yaml folds it into one string)
SOURCE_CMD = re.compile(r"\s*mimicgen-pipe\s+source(\s|$)")


def inputs_folder(dvc_file: Path) -> Path | None:
    """``<dvc_file's folder>/inputs`` (absolute) when a stage of ``dvc_file`` that runs
    ``mimicgen-pipe source`` declares it as a dep, else None (its source stages make their
    own demos)."""
    folder = Path(os.path.abspath(dvc_file)).parent / INPUTS
    for body in pipelines._stages(Path(dvc_file)).values():
        if not SOURCE_CMD.match(str(body.get("cmd", ""))):
            continue
        wdir = folder.parent / str(body.get("wdir", "."))
        deps = [Path(os.path.normpath(wdir / str(d))) for d in body.get("deps") or ()]
        if folder in deps:
            return folder
    return None


def check_place(params_file: str | os.PathLike, from_file: str) -> None:
    """InputError naming the params file, the key and the file when ``from_file`` (params'
    source.from_file, relative to the working directory) lies outside the inputs folder of
    the pipeline whose dvc.yaml is beside ``params_file``, or when that pipeline's source
    stages track no such folder. Nothing to check outside any pipeline."""
    dvc_file = Path(os.path.abspath(params_file)).with_name("dvc.yaml")
    if not dvc_file.is_file():
        return
    where = f"{params_file}: source.from_file: {from_file}"
    folder = inputs_folder(dvc_file)
    if folder is None:
        raise InputError(
            f"{where}: the pipeline of {_shown(dvc_file)} makes its own source demos; "
            f"brought-in demos go in {_folders_elsewhere(dvc_file)}, named by source.from_file "
            "in that pipeline's params file"
        )
    if folder not in Path(os.path.abspath(from_file)).parents:
        raise InputError(
            f"{where}: expected a file in {_shown(folder)}/, the folder that the source stage "
            f"of {_shown(dvc_file)} tracks (so that editing the file re-runs the stage)"
        )


def _folders_elsewhere(dvc_file: Path) -> str:
    """The inputs folders of the repository's pipelines that have one, each with its
    dvc.yaml, as a user would name them."""
    root = pipelines.repository_root(dvc_file)
    found = [
        f"{_shown(folder)}/ ({_shown(f)})"
        for f in (pipelines._pipeline_files(root) if root else [])
        if (folder := inputs_folder(f)) is not None
    ]
    return " or ".join(found) or f"a pipeline's {INPUTS}/ folder that its source stage tracks"


def _shown(path: Path) -> str:
    """``path`` as a user names it from the working directory."""
    return Path(os.path.relpath(path)).as_posix()


def file_sha256(path: str | os.PathLike) -> str:
    """sha256 over the bytes of the file at ``path``, read in chunks (a demo file may be
    larger than memory)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def file_identity(from_file: str | None) -> dict[str, str]:
    """The metrics fields naming the source file a run read: its path as given and its
    sha256, and its .json's where the back end's own format reads one beside it (a
    ManiSkill trajectory); none for the demonstrator's demos, whose metrics keep their
    bytes."""
    if from_file is None:
        return {}
    # here: the check stage imports this module without loading HDF5
    from mimicgen_pipe.sources.robomimic_source import is_robomimic_file

    fields = {"source_file": from_file, "source_file_sha256": file_sha256(from_file)}
    sidecar = Path(from_file).with_suffix(".json")
    if not is_robomimic_file(from_file) and sidecar.is_file():
        fields["source_file_json_sha256"] = file_sha256(sidecar)
    return fields


def describe(fields: dict[str, str]) -> str:
    """``" from <file> (sha256 <hex>)"`` for the source stage's log line (``fields``: from
    :func:`file_identity`), ``""`` without a file."""
    if not fields:
        return ""
    return f" from {fields['source_file']} (sha256 {fields['source_file_sha256']})"
