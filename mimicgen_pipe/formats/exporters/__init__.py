"""Exporters: a generated (or source) store in the formats people train from.

One module per format, named as ``export.formats`` names it (mimicgen_pipe.core.registry):

- :mod:`.robomimic`: robomimic / MimicGen HDF5 (``data/demo_<i>``, ``mask/``, ``datagen_info``)
- :mod:`.lerobot`: a LeRobot dataset (parquet files, ``meta/`` and one video per camera)
- :mod:`.maniskill`: a ManiSkill trajectory (``.h5`` + ``.json``) that ManiSkill's own
  ``replay_trajectory`` replays; ManiSkill back end only

Each defines

- ``FILE_NAME``: the path in the export directory that ``write`` writes (a file or a folder);
- ``WRITES``: a regular expression that every path ``write`` makes in the export directory
  ('/'-separated, relative to it) fully matches, so that the stage recognises a directory it
  made;
- ``check(store, info) -> str | None``: why ``store`` cannot be exported, before anything is
  written (:func:`missing_keys` helps), or None;
- ``write(store, path, info, **extra) -> dict``: the format at ``path``; returns figures for
  the metrics file (``image_bytes``: bytes its camera images take on disk).

Each format records :func:`provenance` (what made the store, with which params and tool
version, and the conventions of the arrays it wrote) in its own metadata, under
PROVENANCE_KEY.

Every format reads the same :class:`ExportInfo`, made by the export stage from the store's
attrs and params.yaml (its job, :class:`ExportJob`, written by :func:`export`), and the same
store: :func:`read` gives every array but the camera
images, which the formats read one episode at a time (:func:`episode_images`), so that an
export's memory does not grow with the images (1000 stack_cube demos of two 84x84
cameras hold about 4.7 GB of them).
"""

from __future__ import annotations

import importlib.metadata
import time
import types
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mimicgen_pipe.core.camera_calibration import store_calibration
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.observations import QUAT_ORDER
from mimicgen_pipe.core.registry import choices, load
from mimicgen_pipe.core.taskspec import ARM, SubtaskSpec, TaskSpec
from mimicgen_pipe.data.outputs import OutputKind, directory_kind
from mimicgen_pipe.data.store import (
    EpisodeStore,
    image_key,
    no_episodes,
    open_store,
    read_store,
    store_cameras,
)
from mimicgen_pipe.method.segments import subtask_at_steps

KINDS = ("source", "generated", "failed")  # the stores export takes


@dataclass(frozen=True)
class ExportInfo:
    """What the formats need beyond the arrays.

    env_args: {"env_name", "type", "env_kwargs"}: ``mimicgen_pipe.backends.make_env(**env_kwargs)``
    rebuilds the env the episodes ran in (robomimic's ``env_args``). task_description: one sentence
    (the LeRobot task string). obs_keys: the policy observation, keys of ``obs/`` concatenated in
    this order as LeRobot's ``observation.state`` and ``observation.environment_state``. fps:
    control frequency [Hz]. valid_fraction: share of episodes in robomimic's ``mask/valid``
    (the last ones), the rest in ``mask/train``. subtasks: the task's subtasks in order (the
    per-step subtask labels index them). arms: a task of several arms' arms, in the order of
    their 7 action entries each (TaskSpec.several_arms); empty for one arm.
    """

    env_args: dict[str, Any]
    task_description: str
    obs_keys: tuple[str, ...]
    fps: int
    valid_fraction: float = 0.1
    subtasks: tuple[SubtaskSpec, ...] = ()
    arms: tuple[str, ...] = ()

    @property
    def action_names(self) -> list[str]:
        """One name per action entry: dx, dy, dz, drx, dry, drz, gripper; with several arms
        each arm's seven prefixed with its name (``left.dx``)."""
        if not self.arms:
            return list(ACTION_NAMES)
        return [f"{arm}.{n}" for arm in self.arms for n in ACTION_NAMES]

    @property
    def label_arms(self) -> tuple[str, ...]:
        """The arms with their own subtask labels: ARM alone for one arm."""
        return self.arms or (ARM,)


ACTION_NAMES = ("dx", "dy", "dz", "drx", "dry", "drz", "gripper")  # one arm's 7 action entries
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
        subtasks=tuple(spec.subtasks),
        arms=spec.several_arms,
    )


TOOL = "mimicgen-pipe"  # the package whose version the exports record
PROVENANCE_KEY = "mimicgen_pipe"  # the metadata key each format records provenance under
POSE_FRAME = "world"  # the frame of every position, quaternion and pose written
UNITS = {"length": "m", "angle": "rad", "time": "s"}
# the store attrs that say what made it: the params of the stage that wrote it (generate's
# for a generated or failed store, source's for a source store), observe's for images
_MADE_BY = ("kind", "run_id", "task", "variant", "backend", "robot", "params", "observe")


def tool_version() -> str:
    """mimicgen-pipe's version from its package metadata ("unknown" when run from a source
    tree that was never installed)."""
    try:
        return importlib.metadata.version(TOOL)
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def provenance(
    attrs: Mapping[str, Any], quaternion_order: str = QUAT_ORDER, control_mode: str | None = None
) -> dict[str, Any]:
    """What an export holds, for its metadata: the tool and its version, what made the store
    (its attrs of _MADE_BY: kind, run id, task, variant, back end, robot, params; None where
    the store has none, e.g. a source store's run id) and the conventions of the arrays the
    format wrote: quaternion order, pose frame, units, the actions' control mode (the
    store's unless the format writes others) and control frequency [Hz]."""
    made_by = {k: attrs.get(k) for k in _MADE_BY if k != "observe" or k in attrs}
    conventions = {
        "quaternion_order": quaternion_order,
        "pose_frame": POSE_FRAME,
        "units": UNITS,
        "control_mode": control_mode or attrs.get("control_mode"),
        "control_freq_hz": int(attrs["control_freq"]),
    }
    return {"tool": TOOL, "tool_version": tool_version()} | made_by | {"conventions": conventions}


def exporter(fmt: str) -> types.ModuleType:
    """The exporter module of format ``fmt``; InputError naming the formats for another."""
    known = choices("mimicgen_pipe.formats.exporters")
    if fmt not in known:
        raise InputError(f"export format {fmt!r}: unknown (known: {', '.join(known)})")
    return load("mimicgen_pipe.formats.exporters", fmt)


def export_dir_kind() -> OutputKind:
    """An export directory: what the formats write (each one's ``WRITES``) and nothing else,
    so that the stage replaces only a directory it made."""
    writes = (exporter(fmt).WRITES for fmt in choices("mimicgen_pipe.formats.exporters"))
    return directory_kind("export directory", "|".join(f"(?:{w})" for w in writes))


def check(store: EpisodeStore, fmt: str, info: ExportInfo) -> None:
    """InputError naming the store, the format and what it lacks (or the key of its camera
    calibration that is wrong); nothing is written."""
    if store.n_episodes == 0:
        raise no_episodes(store.path, store.attrs)
    store_calibration(store.attrs, str(store.path))  # its own error, naming the key
    why = exporter(fmt).check(store, info)
    if why:
        raise InputError(f"{store.path}: cannot export as {fmt}: {why}")


def write(
    store: EpisodeStore, fmt: str, out_dir: Path, info: ExportInfo, **extra: Any
) -> tuple[Path, dict[str, Any]]:
    """Write ``store`` as ``fmt`` into ``out_dir`` (at the format's FILE_NAME); returns the
    path and the format's figures for the metrics file."""
    module = exporter(fmt)
    path = Path(out_dir) / module.FILE_NAME
    return path, module.write(store, path, info, **extra)


@dataclass(frozen=True)
class ExportJob:
    """One export run, checked (mimicgen_pipe.stages.export.resolve): the store at
    ``store_path`` of task ``task`` (``store``, read but for its camera images), in every
    format of ``formats`` (each one's :func:`check` passed), with ``info``, written into the
    export directory ``out`` and its numbers into the metrics JSON ``metrics_path``.
    ``step_success``: (N_steps,) the task's success after every step (None where export.
    step_success is off or the back end does not restore states cheaply);
    ``maniskill_replays``: what replays the episodes in ManiSkill for its trajectory format,
    returning that format's ``write`` extras (None without the format)."""

    task: str
    store_path: Path
    store: EpisodeStore
    formats: tuple[str, ...]
    info: ExportInfo
    step_success: np.ndarray | None
    maniskill_replays: Callable[[], dict[str, Any]] | None
    out: Path
    metrics_path: Path


def export(job: ExportJob, out_dir: Path) -> dict[str, float | int]:
    """Every format of ``job`` written, in order, into the new directory ``out_dir`` (the
    temporary of the job's ``out``). Returns the metrics' numbers: episodes, each format's
    seconds and figures, and the share of episodes whose ManiSkill replay succeeds."""
    store = job.store
    metrics: dict[str, float | int] = {"episodes": store.n_episodes}
    out_dir.mkdir()
    for fmt in job.formats:
        t0 = time.perf_counter()
        if fmt == "maniskill":
            assert job.maniskill_replays is not None
            extra = job.maniskill_replays()
            ok = sum(bool(r.success[-1]) for r in extra["replays"])
            metrics["maniskill_replay_success"] = ok / max(1, store.n_episodes)
        else:
            extra = {"step_success": job.step_success}
        path, figures = write(store, fmt, out_dir, job.info, **extra)
        metrics[f"{fmt}_seconds"] = round(time.perf_counter() - t0, 2)
        metrics |= {f"{fmt}_{k}": v for k, v in figures.items()}
        print(f"export: {fmt} -> {job.out / path.name}")
    return metrics


def read(path: str | Path, task: str) -> EpisodeStore:
    """The store at ``path`` in memory, but for its camera images (:func:`episode_images`
    reads them), checked as read_store checks a store: InputError naming the array."""
    view = open_store(path, task=task, kind=KINDS)
    if not store_cameras(view.attrs):
        return read_store(path, task=task, kind=KINDS)
    images = {image_key(c) for c in store_cameras(view.attrs)}
    every = range(view.n_episodes)
    data = {k: view.read_rows(k, every) for k in view.data_keys if k not in images}
    episodes = {k: view.episode_field(k) for k in view.episode_keys}
    return EpisodeStore(view.path, data, view.episode_ends, episodes, view.attrs)


def missing_images(store: EpisodeStore) -> str | None:
    """Why the images of the cameras the store's attrs list cannot be read (an image array
    missing, or not (N_steps, H, W, 3) uint8 with the listed size), or None."""
    cams = store_cameras(store.attrs)
    if not cams:
        return None
    view = open_store(store.path)
    for camera, (h, w) in cams.items():
        key = image_key(camera)
        if f"data/{key}" not in view.arrays:
            return f"no data/{key} (attrs.cameras lists {camera!r})"
        array = view.arrays[f"data/{key}"]
        expected = (int(store.episode_ends[-1]) if store.n_episodes else 0, h, w, 3)
        if tuple(array.shape) != expected or array.dtype != np.uint8:
            return f"data/{key} is {array.dtype} {tuple(array.shape)}, expected uint8 {expected}"
    return None


def episode_images(store: EpisodeStore, camera: str) -> Iterator[np.ndarray]:
    """The images of ``camera``, one (T_i, H, W, 3) uint8 array per episode, in order; one
    episode in memory at a time."""
    view = open_store(store.path)
    for i in range(store.n_episodes):
        yield view.read_rows(image_key(camera), [i])


def step_outcomes(store: EpisodeStore, step_success: np.ndarray | None = None) -> dict:
    """Each step's outcome, (N_steps,) each, as robomimic's datasets record it: ``success``
    (bool), whether the task is achieved in the state after the step; ``reward`` (float64),
    the sparse success reward r(s') = 1.0 where it is, else 0.0; ``done`` (bool), on success
    or at the episode's last step (robomimic's done_mode 2).

    ``step_success``: (N_steps,) bool, the task's success after every step, as the export
    stage evaluates it on the back end (mimicgen_pipe/stages/export.py); without it only the last
    step's is known, the episode's ``success`` (meta/episodes; a store without it: every episode
    succeeded), and every earlier step counts as not achieved. ValueError for an array of
    another shape."""
    n = int(store.episode_ends[-1]) if store.n_episodes else 0
    last = store.episode_ends - 1
    if step_success is None:
        success = np.zeros(n, bool)
        success[last] = store.episodes.get("success", np.ones(store.n_episodes, bool))
    else:
        success = np.asarray(step_success)
        if success.shape != (n,) or success.dtype != bool:
            raise ValueError(f"step_success: {success.dtype} {success.shape}, expected bool ({n},)")
    done = success.copy()
    done[last] = True
    return {"success": success, "reward": success.astype(np.float64), "done": done}


def subtask_labels(
    store: EpisodeStore, subtasks: Sequence[SubtaskSpec], arm: str = ARM
) -> np.ndarray | None:
    """(N_steps,) int64: the subtask of ``arm`` each step belongs to, an index into
    ``subtasks`` (-1: a step at which the arm of a task of several has no subtask and holds).
    From the arm's subtask at each step where the generator recorded it (``subtask/<arm>``,
    several arms), else from the store's subtask ends (``meta/episodes/subtask_term_index``:
    the arm's subtask k + 1 starts at its end k), else from its term signals as the generator
    walks them (subtask k + 1 starts at the first rise of subtask k's term signal after
    subtask k started; an episode that fails stays in the subtask whose signal never rose).
    None for a store with none of them (a source store brought in from a file without its
    signals) and for an arm without subtasks."""
    mine = [i for i, s in enumerate(subtasks) if s.arm == arm]
    if not mine:
        return None
    if f"subtask/{arm}" in store.data:
        return np.asarray(store.data[f"subtask/{arm}"], np.int64)
    own, index, lengths = [subtasks[i] for i in mine], np.asarray(mine, np.int64), store.lengths
    if "subtask_term_index" in store.episodes:
        ending = [i for i, s in enumerate(subtasks) if s.term_signal is not None]
        ends = store.episodes["subtask_term_index"][:, [ending.index(i) for i in mine[:-1]]]
        parts = [
            index[np.searchsorted(e, np.arange(n), side="right")]
            for e, n in zip(ends, lengths, strict=True)
        ]
    elif all(f"subtask_signals/{s.term_signal}" in store.data for s in own[:-1]):
        parts = [
            index[subtask_at_steps(store.episode(i), own, int(n))] for i, n in enumerate(lengths)
        ]
    else:
        return None
    return np.concatenate(parts).astype(np.int64) if parts else np.zeros(0, np.int64)


def task_description(spec: TaskSpec) -> str:
    """One sentence from the task's subtasks, e.g. "stack_cube: grasp cubeA, then place on
    cubeB" (LeRobot's task string)."""
    steps = ", then ".join(s.name.replace("_", " ") for s in spec.subtasks)
    return f"{spec.name}: {steps}"


def missing_keys(store: EpisodeStore, keys: tuple[str, ...] | list[str]) -> str | None:
    """'no data/<key>, ...' for the keys the store lacks, or None."""
    missing = [k for k in keys if k not in store.data]
    return f"no {', '.join('data/' + k for k in missing)}" if missing else None
