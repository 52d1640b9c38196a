"""Exporters: a generated (or source) store in the formats people train from.

One module per format, each with ``REQUIRED`` (the store's data keys it reads), ``check``
(why a store cannot be exported, before anything is written) and ``write``:

- :mod:`.robomimic`: robomimic / MimicGen HDF5 (``data/demo_<i>``, ``mask/``, ``datagen_info``)
- :mod:`.lerobot`: a LeRobot dataset (parquet files and ``meta/``), low-dim state and action
- :mod:`.maniskill`: a ManiSkill trajectory (``.h5`` + ``.json``) that ManiSkill's own
  ``replay_trajectory`` replays; ManiSkill back end only

Every format reads the same :class:`ExportInfo`, made by the export stage from the store's
attrs and params.yaml.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mimicgen_pipe.errors import InputError
from mimicgen_pipe.outputs import directory_kind
from mimicgen_pipe.store import EpisodeStore
from mimicgen_pipe.taskspec import TaskSpec

FORMATS = ("robomimic", "lerobot", "maniskill")
# what each format writes inside the export directory
FILE_NAMES = {"robomimic": "demos.hdf5", "lerobot": "lerobot", "maniskill": "trajectory.h5"}
# an export directory holds those files (ManiSkill's .json beside its .h5) and nothing else,
# so that the stage replaces only a directory it made
EXPORT_DIR = directory_kind(
    "export directory",
    "|".join(
        rf"{re.escape(Path(n).stem)}\.(h5|json)" if n.endswith(".h5") else rf"{re.escape(n)}(/.+)?"
        for n in FILE_NAMES.values()
    ),
)


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


def _module(fmt: str):
    if fmt not in FORMATS:
        raise InputError(f"export format {fmt!r}: unknown (known: {', '.join(FORMATS)})")
    return _FORMAT_MODULES[fmt]


def check(store: EpisodeStore, fmt: str, info: ExportInfo) -> None:
    """InputError naming the store, the format and what it lacks; nothing is written."""
    why = _module(fmt).check(store, info)
    if why:
        raise InputError(f"{store.path}: cannot export as {fmt}: {why}")


def write(store: EpisodeStore, fmt: str, out_dir: Path, info: ExportInfo, **extra: Any) -> Path:
    """Write ``store`` as ``fmt`` into ``out_dir`` (FILE_NAMES[fmt]); returns the path."""
    path = Path(out_dir) / FILE_NAMES[fmt]
    _module(fmt).write(store, path, info, **extra)
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


# the format modules, imported here so that every stage that exports depends on all of them
from mimicgen_pipe.exporters import lerobot, maniskill, robomimic  # noqa: E402

_FORMAT_MODULES = {"robomimic": robomimic, "lerobot": lerobot, "maniskill": maniskill}
