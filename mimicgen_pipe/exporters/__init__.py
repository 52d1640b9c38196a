"""Exporters: a generated (or source) store in the formats people train from.

One module per format, named as ``export.formats`` names it (mimicgen_pipe.registry):

- :mod:`.robomimic`: robomimic / MimicGen HDF5 (``data/demo_<i>``, ``mask/``, ``datagen_info``)
- :mod:`.lerobot`: a LeRobot dataset (parquet files and ``meta/``), low-dim state and action
- :mod:`.maniskill`: a ManiSkill trajectory (``.h5`` + ``.json``) that ManiSkill's own
  ``replay_trajectory`` replays; ManiSkill back end only

Each defines

- ``FILE_NAME``: the path in the export directory that ``write`` writes (a file or a folder);
- ``WRITES``: a regular expression that every path ``write`` makes in the export directory
  ('/'-separated, relative to it) fully matches, so that the stage recognises a directory it
  made;
- ``check(store, info) -> str | None``: why ``store`` cannot be exported, before anything is
  written (:func:`missing_keys` helps), or None;
- ``write(store, path, info, **extra) -> None``: the format at ``path``.

Every format reads the same :class:`ExportInfo`, made by the export stage from the store's
attrs and params.yaml.
"""

from __future__ import annotations

import types
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mimicgen_pipe.errors import InputError
from mimicgen_pipe.outputs import OutputKind, directory_kind
from mimicgen_pipe.registry import choices, load
from mimicgen_pipe.store import EpisodeStore
from mimicgen_pipe.taskspec import TaskSpec


@dataclass(frozen=True)
class ExportInfo:
    """What the formats need beyond the arrays.

    env_args: {"env_name", "type", "env_kwargs"}: ``envs.make_env(**env_kwargs)`` rebuilds the
    env the episodes ran in (robomimic's ``env_args``). task_description: one sentence (the
    LeRobot task string). obs_keys: the policy observation, keys of ``obs/`` concatenated in
    this order as LeRobot's ``observation.state``. fps: control frequency [Hz]. valid_fraction:
    share of episodes in robomimic's ``mask/valid`` (the last ones), the rest in ``mask/train``.
    """

    env_args: dict[str, Any]
    task_description: str
    obs_keys: tuple[str, ...]
    fps: int
    valid_fraction: float = 0.1


ENV_TYPE = 2  # robomimic's EnvType.GYM_TYPE: env_kwargs rebuild a gym-style env, not robosuite


def export_info(
    attrs: Mapping[str, Any], spec: TaskSpec, obs_keys: Sequence[str], valid_fraction: float
) -> ExportInfo:
    """The ExportInfo of a store, from its attrs (back end, task, robot, control mode and
    frequency) and the task spec."""
    return ExportInfo(
        env_args={
            "env_name": f"{attrs['backend']}:{attrs['task']}",
            "type": ENV_TYPE,
            "env_kwargs": {k: attrs[k] for k in ("backend", "task", "robot")},
            "control_mode": attrs["control_mode"],
            "control_freq": int(attrs["control_freq"]),
        },
        task_description=task_description(spec),
        obs_keys=tuple(obs_keys),
        fps=int(attrs["control_freq"]),
        valid_fraction=valid_fraction,
    )


def exporter(fmt: str) -> types.ModuleType:
    """The exporter module of format ``fmt``; InputError naming the formats for another."""
    known = choices("mimicgen_pipe.exporters")
    if fmt not in known:
        raise InputError(f"export format {fmt!r}: unknown (known: {', '.join(known)})")
    return load("mimicgen_pipe.exporters", fmt)


def export_dir_kind() -> OutputKind:
    """An export directory: what the formats write (each one's ``WRITES``) and nothing else,
    so that the stage replaces only a directory it made."""
    writes = (exporter(fmt).WRITES for fmt in choices("mimicgen_pipe.exporters"))
    return directory_kind("export directory", "|".join(f"(?:{w})" for w in writes))


def check(store: EpisodeStore, fmt: str, info: ExportInfo) -> None:
    """InputError naming the store, the format and what it lacks; nothing is written."""
    why = exporter(fmt).check(store, info)
    if why:
        raise InputError(f"{store.path}: cannot export as {fmt}: {why}")


def write(store: EpisodeStore, fmt: str, out_dir: Path, info: ExportInfo, **extra: Any) -> Path:
    """Write ``store`` as ``fmt`` into ``out_dir`` (at the format's FILE_NAME); returns the
    path."""
    module = exporter(fmt)
    path = Path(out_dir) / module.FILE_NAME
    module.write(store, path, info, **extra)
    return path


def task_description(spec: TaskSpec) -> str:
    """One sentence from the task's subtasks, e.g. "stack_cube: grasp cubeA, then place on
    cubeB" (LeRobot's task string)."""
    steps = ", then ".join(s.name.replace("_", " ") for s in spec.subtasks)
    return f"{spec.name}: {steps}"


def missing_keys(store: EpisodeStore, keys: tuple[str, ...] | list[str]) -> str | None:
    """'no data/<key>, ...' for the keys the store lacks, or None."""
    missing = [k for k in keys if k not in store.data]
    return f"no {', '.join('data/' + k for k in missing)}" if missing else None
