"""Camera images of stored episodes (the observe stage): every step's stored ``env_state`` is
set in a render-only env of the back end and pictured by its cameras
(mimicgen_pipe/core/cameras.py), in fixed blocks of episodes on the executor layer
(mimicgen_pipe.run.executors), and written beside a copy of the input store's arrays as
``data/obs/<camera>_image`` (N_steps, H, W, 3) uint8 RGB, chunked along the steps
(docs/data-contract.md).

A picture depends on the state alone, and blocks are written in order, so the store is the
same for any number of workers; a killed run resumes from its finished blocks
(mimicgen_pipe.run.resume).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mimicgen_pipe.core.camera_calibration import ATTR as CALIBRATION
from mimicgen_pipe.core.contracts import Renderer
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.interrupts import Interrupted
from mimicgen_pipe.data.outputs import content_digest, run_id
from mimicgen_pipe.data.params import Params, data_params
from mimicgen_pipe.data.store import (
    StoreView,
    StoreWriter,
    image_key,
    no_episodes,
    store_cameras,
    store_writer,
)
from mimicgen_pipe.run.executors import Executor, map_blocks
from mimicgen_pipe.run.resume import BadBlock, WorkDir, code_digest
from mimicgen_pipe.run.rollout_progress import StepCounter, StepProgress

EPISODES_PER_BLOCK = 2  # ~440 pictures per block on stack_cube: 15-30 s of work


# the back end's renderer maker (contracts.Backend.make_renderer): (task, robot, width [px],
# height [px], cameras) -> a renderer; picklable, for it is sent to every worker
RendererMaker = Callable[[str, str, int, int, Sequence[str]], Renderer]

# checks that an arm has cameras on a back end (mimicgen_pipe.backends.check_cameras): (backend,
# robot, cameras, where) -> None, or InputError naming ``where``
CameraCheck = Callable[[str, str, Sequence[str], str], None]


@dataclass(frozen=True)
class ImageJob:
    """What a worker of an observe run needs, sent once per worker: the store whose states
    it renders, the renderer's settings and the back end's ``make_renderer``. Image sizes in
    pixels."""

    store: Path
    backend: str
    task: str
    robot: str
    cameras: tuple[str, ...]
    height: int
    width: int
    make_renderer: RendererMaker
    # where each worker keeps its count of frames rendered (rollout_progress.StepCounter)
    progress: str | None = None


def check_input(view: StoreView, params: Params, where: str, check_cameras: CameraCheck) -> int:
    """The number of episodes observed (observe.episodes, null: all), after checking before
    any work that ``view`` can be observed as ``params`` say: it has env_state and no images
    yet, its arm has every camera asked for on its back end (``check_cameras``; ``where``:
    the params file, for the message) and it holds that many episodes. InputError
    otherwise."""
    o = params.observe
    if view.n_episodes == 0:
        raise no_episodes(view.path, view.attrs)
    if "env_state" not in view.data_keys:
        raise InputError(
            f"{view.path}: no data/env_state (the stored simulator states images are rendered "
            "from); observe a source, generated or failed store"
        )
    if store_cameras(view.attrs):
        raise InputError(
            f"{view.path}: has images already (cameras {list(store_cameras(view.attrs))}); "
            "observe the store it was observed from"
        )
    backend, robot = view.attrs["backend"], view.attrs["robot"]
    check_cameras(backend, robot, o.cameras, f"{where}: observe.cameras")
    if o.episodes is not None and o.episodes > view.n_episodes:
        raise InputError(
            f"{where}: observe.episodes {o.episodes}: {view.path} has {view.n_episodes} episodes"
        )
    return view.n_episodes if o.episodes is None else o.episodes


def observe_run_id(params: Params, attrs: Mapping[str, Any], states: np.ndarray) -> str:
    """The id of an observe run: the observe params (no worker count), the back end, task and
    arm, and the states rendered."""
    shaping = {k: attrs.get(k) for k in ("backend", "task", "robot")}
    return run_id(shaping | data_params(params, "observe"), content_digest({"env_state": states}))


def episode_blocks(n_episodes: int, per_block: int = EPISODES_PER_BLOCK) -> list[list[int]]:
    """The fixed blocks of episode indices the pictures are taken in."""
    return [list(range(s, min(s + per_block, n_episodes))) for s in range(0, n_episodes, per_block)]


# a block's result: camera -> (rows, H, W, 3) images, and "seconds/<camera>" -> (1,) float64
# seconds spent on that camera's pictures (its share of the scene updates included)
BlockImages = dict[str, np.ndarray]


class ImageBlockCodec:
    """A block's images as the plain arrays a work directory keeps, and back; accepted only
    for the block index whose steps they hold (``blocks``, the episodes' ``lengths``)."""

    def __init__(self, blocks: Sequence[Sequence[int]], lengths: np.ndarray, job: ImageJob):
        self.blocks, self.lengths, self.job = blocks, lengths, job

    def encode(self, index: int, result: BlockImages) -> dict[str, np.ndarray]:
        return dict(result)

    def decode(self, index: int, arrays: Mapping[str, np.ndarray]) -> BlockImages:
        if not 0 <= index < len(self.blocks):
            raise BadBlock(f"no block {index} in a run of {len(self.blocks)} blocks")
        rows = int(self.lengths[list(self.blocks[index])].sum())
        j = self.job
        for camera in j.cameras:
            a = arrays[camera]
            if a.dtype != np.uint8 or a.shape != (rows, j.height, j.width, 3):
                raise BadBlock(f"{camera}: {a.dtype} {a.shape}, expected uint8 {rows} rows")
            if arrays[f"seconds/{camera}"].shape != (1,):
                raise BadBlock(f"seconds/{camera}: shape {arrays[f'seconds/{camera}'].shape}")
        return {k: arrays[k] for k in arrays}


_WORKER: tuple[ImageJob, Renderer, StoreView, StepCounter | None] | None = None


def _init_worker(job: ImageJob) -> None:
    global _WORKER
    from mimicgen_pipe.data.store import open_store

    renderer = job.make_renderer(job.task, job.robot, job.width, job.height, job.cameras)
    counter = StepCounter.open(job.progress)
    if counter is not None:
        counter.step()  # stands for a reset: each later call is one frame rendered
    _WORKER = (job, renderer, open_store(job.store), counter)


def _render_block(episodes: list[int]) -> BlockImages:
    """Every step of ``episodes`` pictured by every camera of the worker's job."""
    assert _WORKER is not None
    job, renderer, view, counter = _WORKER
    states = view.read_rows("env_state", episodes)
    out = {c: np.empty((len(states), job.height, job.width, 3), np.uint8) for c in job.cameras}
    before = dict(renderer.seconds)
    for t, state in enumerate(states):
        for camera, image in renderer.images(state).items():
            out[camera][t] = image
        if counter is not None:  # the stage's bar moves while a block renders
            counter.step()
    seconds = {c: renderer.seconds[c] - before[c] for c in job.cameras}
    return out | {f"seconds/{c}": np.array([seconds[c]]) for c in job.cameras}


def open_work_dir(out: Path, run: str, codec: ImageBlockCodec) -> WorkDir:
    """The work directory beside ``out`` of observe run ``run``: blocks that an earlier,
    killed run of the same run, blocks (``codec.blocks``) and code finished are reused."""
    per_block = len(codec.blocks[0]) if codec.blocks else 0
    key = f"{run}/{per_block}/{code_digest('mimicgen_pipe')}"
    work = WorkDir.open(out, key, codec)
    for line in work.discarded:
        print(f"observe: {line}")
    if work.resumed:
        print(f"observe: resuming: {len(work.resumed)} finished blocks of episodes in {work.path}")
    return work


def render_blocks(
    job: ImageJob,
    blocks: Sequence[list[int]],
    executor: Executor,
    work: WorkDir | None = None,
) -> Iterator[BlockImages]:
    """The images of each block of episodes, in block order (finished blocks saved in and
    reused from ``work``)."""
    return map_blocks(_render_block, blocks, executor, _init_worker, (job,), work)


def write_observed(
    writer: StoreWriter,
    view: StoreView,
    job: ImageJob,
    images: Iterator[BlockImages],
    blocks: Sequence[list[int]],
    progress: StepProgress,
    work: WorkDir | None = None,
) -> dict[str, float]:
    """Into ``writer``: every array of ``view`` for the episodes of ``blocks``, as stored,
    then each camera's images as the blocks' ``images`` come (one block in memory at a time).
    Returns the seconds spent per camera. ``progress``: the bar of frames
    (:func:`frame_progress`), told of each block written."""
    chosen = [e for block in blocks for e in block]
    for key in view.data_keys:
        writer.array(key, view.read_rows(key, chosen))
    for key in view.episode_keys:
        writer.episode_field(key, view.episode_field(key)[: len(chosen)])
    rows = {c: writer.rows(image_key(c), (job.height, job.width, 3), np.uint8) for c in job.cameras}
    seconds = dict.fromkeys(job.cameras, 0.0)
    done = 0
    try:
        for block, result in zip(blocks, images, strict=True):
            for camera, writer_rows in rows.items():
                writer_rows.append(result[camera])
                seconds[camera] += float(result[f"seconds/{camera}"][0])
            done += len(block)
            progress.returned(len(result[job.cameras[0]]))
    except Interrupted as exc:
        exc.detail = f"after {done} of {len(chosen)} episodes"
        if work is not None:
            exc.detail += f"; finished blocks kept in {work.path} (the same command resumes)"
        raise
    for writer_rows in rows.values():
        writer_rows.close()
    return seconds


def frame_progress(label: str, frames: int, workers: int) -> StepProgress:
    """The observe stage's bar of ``frames`` frames (steps) rendered, shown at once and
    moved while the workers render (each counts its frames where :class:`ImageJob`'s
    ``progress`` says): a block of episodes can take a minute. A frame is an episode of one
    step to the bar."""
    return StepProgress(label, frames, 1, workers)


def observed_attrs(
    attrs: Mapping[str, Any], params: Params, calibration: Mapping[str, Any]
) -> dict[str, Any]:
    """The observed store's attributes: its input store's, plus each camera's size, the
    cameras' calibration (``calibration``: camera_calibration's attribute, from the back end)
    and the observe params that shaped it."""
    o = params.observe
    return dict(attrs) | {
        "cameras": {c: {"height": o.height, "width": o.width} for c in o.cameras},
        CALIBRATION: calibration,
        "observe": data_params(params, "observe")["observe"],
    }


def observe_metrics(
    store: Path,
    job: ImageJob,
    frames: int,
    n_episodes: int,
    seconds: Mapping[str, float],
    wall: float,
) -> dict[str, Any]:
    """The observe stage's numbers for the ``store`` it wrote: episodes, frames (steps) per
    camera, ms per frame per camera (of the ``seconds`` each camera took), MB of stored
    (compressed) images per 1000 demos, and the stage's ``wall`` time [s] (``seconds``)."""
    out: dict[str, Any] = {"episodes": n_episodes, "frames": frames, "seconds": round(wall, 1)}
    total = 0
    for camera in job.cameras:
        files = (store / "data" / image_key(camera)).rglob("*")
        total += sum(f.stat().st_size for f in files if f.is_file())
        out[f"ms_per_frame_{camera}"] = round(1000 * seconds[camera] / max(1, frames), 2)
    out["image_mb_per_1000_demos"] = round(total / 2**20 * 1000 / max(1, n_episodes), 1)
    return out


@dataclass(frozen=True)
class ObserveJob:
    """One observe run, checked (mimicgen_pipe.stages.observe.resolve): the first
    ``episodes`` episodes of the store at ``store_path`` (``view``, a ``kind`` store of task
    ``task``, variant ``variant``, recorded on back end ``backend`` with arm ``robot``),
    pictured in blocks of episodes ``blocks`` by ``workers`` local workers, each sent
    ``images``; written beside a copy of their arrays as the observed store ``out`` with
    attributes ``attrs`` (:func:`observed_attrs`) under run id ``run_id``
    (:func:`observe_run_id`), and the metrics JSON ``metrics_path``."""

    task: str
    variant: str
    backend: str
    robot: str
    kind: str
    store_path: Path
    view: StoreView
    episodes: int
    images: ImageJob
    blocks: list[list[int]]
    workers: int
    run_id: str
    attrs: Mapping[str, Any]
    out: Path
    metrics_path: Path

    @property
    def frames(self) -> int:
        """The steps pictured (a frame per step, of each camera)."""
        return int(self.view.episode_ends[self.episodes - 1]) if self.episodes else 0

    @property
    def label(self) -> str:
        """The name of the run's progress bar."""
        return f"observe {self.task} {self.variant}"


def observe(
    job: ObserveJob, out_dir: Path, work: WorkDir, progress: StepProgress
) -> dict[str, float]:
    """The job's observed store written at ``out_dir`` (the temporary of its ``out``): its
    blocks of episodes pictured by the workers (finished blocks saved in and reused from
    ``work``, the bar ``progress`` moved as they render), then written in order
    (:func:`write_observed`). Returns the seconds spent per camera."""
    rendering = dataclasses.replace(job.images, progress=progress.directory)
    images = render_blocks(rendering, job.blocks, Executor("local", job.workers), work)
    try:
        ends = job.view.episode_ends[: job.episodes]
        with store_writer(out_dir, job.kind, ends, job.attrs) as writer:
            return write_observed(writer, job.view, job.images, images, job.blocks, progress, work)
    finally:
        images.close()
