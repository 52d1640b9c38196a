"""Videos of stored episodes (the render stage): captions, MP4 and GIF writing. Frames are
(H, W, 3) uint8 RGB, rendered by a back end's renderer (mimicgen_pipe.core.contracts.Renderer)."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from mimicgen_pipe.core.contracts import Renderer
from mimicgen_pipe.core.taskspec import SubtaskSpec
from mimicgen_pipe.data.store import EpisodeStore
from mimicgen_pipe.method.segments import subtask_at_steps

FONT = cv2.FONT_HERSHEY_SIMPLEX
KEPT_RGB, FAILED_RGB, TEXT_RGB, BAND_RGB = (
    (90, 230, 90),
    (255, 90, 90),
    (255, 255, 255),
    (25, 25, 25),
)


def episode_frames(
    render: Callable[[np.ndarray], np.ndarray],
    store: EpisodeStore,
    i: int,
    subtasks: Sequence[SubtaskSpec],
    title: str,
    ok: bool,
    label: str,
) -> list[np.ndarray]:
    """Episode ``i`` of a generated (``ok``) or failed store, one frame per step rendered by
    ``render`` from the step's stored env_state, captioned: ``title`` and the step, the
    subtask the step is in (:func:`subtask_at_steps`) with that subtask's source demo (with
    several arms each arm's, with the source demo in brackets), and the outcome (kept, or the
    subtask the attempt failed in). ``label`` names the progress
    bar of the frames."""
    ep = store.episode(i)
    steps = len(ep["env_state"])
    arms = tuple(dict.fromkeys(s.arm for s in subtasks))
    if len(arms) == 1:
        phases = {arms[0]: subtask_at_steps(ep, subtasks, steps)}
    else:  # the generator recorded each arm's subtask (-1: the arm holds)
        phases = {a: ep[f"subtask/{a}"] for a in arms}
    source = store.episodes["source_demo"][i]
    status = "kept (success)" if ok else "failed in subtask " + (
        subtasks[int(store.episodes["failure_reason"][i])].name)  # fmt: skip

    def doing(arm: str, k: int) -> str:
        if len(arms) == 1:
            return (
                f"subtask {k + 1}/{len(subtasks)} {subtasks[k].name}  source demo {int(source[k])}"
            )
        return f"{arm}: {subtasks[k].name} ({int(source[k])})" if k >= 0 else f"{arm}: holds"

    frames = []
    for t in tqdm(range(steps), desc=label, unit="frame", leave=False):
        now = "  ".join(doing(a, int(phases[a][t])) for a in arms)
        lines = [f"{title}  step {t}/{steps}", now, status]
        frames.append(caption(render(ep["env_state"][t]), lines, ok))
    return frames


def caption(frame: np.ndarray, lines: Sequence[str], ok: bool | None = None) -> np.ndarray:
    """``frame`` with a dark band below holding ``lines`` (the last one green when ``ok``,
    red when not ok). The band's height depends on the frame width only and makes the height
    a multiple of 16 (what H.264 in yuv420p wants), so every frame of a video has one size."""
    h, w = frame.shape[:2]
    scale = w / 640  # 0.5 at 320 px wide
    pad = max(4, int(8 * scale))
    line_h = cv2.getTextSize("Ag", FONT, scale, 1)[0][1] + pad
    band = line_h * len(lines) + 6
    band += (-(h + band)) % 16
    out = np.empty((h + band, w, 3), np.uint8)
    out[:h], out[h:] = frame, BAND_RGB
    for i, line in enumerate(lines):
        colour = TEXT_RGB
        if ok is not None and i == len(lines) - 1:
            colour = KEPT_RGB if ok else FAILED_RGB
        size = scale * min(1.0, (w - 8) / max(1, cv2.getTextSize(line, FONT, scale, 1)[0][0]))
        y = h + 3 + line_h * (i + 1) - pad // 2
        cv2.putText(out, line, (4, y), FONT, size, colour, 1, cv2.LINE_AA)
    return out


def write_mp4(path: Path, frames: Sequence[np.ndarray], fps: int) -> None:
    """H.264 MP4 at ``fps`` frames per second (imageio's ffmpeg)."""
    import imageio.v2 as imageio

    with imageio.get_writer(
        str(path), fps=fps, codec="libx264", quality=7, pixelformat="yuv420p",
        macro_block_size=16, ffmpeg_log_level="error",
    ) as writer:  # fmt: skip
        for frame in frames:
            writer.append_data(frame)


def write_gif(path: Path, frames: Sequence[np.ndarray], fps: int, width: int = 240) -> None:
    """A small looping GIF for the report: every second frame, ``width`` pixels wide, one
    64-colour palette per frame (a few hundred kB for a 100-step episode)."""
    from PIL import Image

    images = []
    for frame in frames[::2]:
        height = round(frame.shape[0] * width / frame.shape[1])
        small = cv2.resize(frame, (width, height), interpolation=cv2.INTER_AREA)
        images.append(Image.fromarray(small).quantize(colors=64, dither=Image.Dither.NONE))
    images[0].save(
        path, save_all=True, append_images=images[1:], duration=round(2000 / fps), loop=0,
        optimize=True,
    )  # fmt: skip


@dataclass(frozen=True)
class RenderJob:
    """One render run, checked (mimicgen_pipe.stages.render.resolve): the first ``episodes``
    episodes of each of ``stores`` (kind -> the store, read whole: the kept "generated" one
    and the "failed" one of one generate run of ``variant`` of task ``task`` on back end
    ``backend`` with arm ``robot``, whose subtasks are ``subtasks``), replayed from their
    stored states by a renderer of ``make_renderer``, as captioned MP4s at ``fps`` [Hz] (and
    a GIF of each first one) in the media directory ``out``; their frame count goes into the
    metrics JSON ``metrics_path``."""

    task: str
    variant: str
    backend: str
    robot: str
    subtasks: tuple[SubtaskSpec, ...]
    stores: Mapping[str, EpisodeStore]
    episodes: int
    fps: int
    make_renderer: Callable[[], Renderer]
    out: Path
    metrics_path: Path


def render_videos(job: RenderJob, out_dir: Path) -> tuple[int, float]:
    """The job's videos, ``kept_<i>`` and ``failed_<i>``, written into the new directory
    ``out_dir`` (the temporary of the job's ``out``); returns the frames rendered and the
    seconds spent on them."""
    renderer = job.make_renderer()
    out_dir.mkdir()
    frames_total, seconds = 0, 0.0
    for kind, store in job.stores.items():
        name = "kept" if kind == "generated" else "failed"
        for i in range(min(job.episodes, store.n_episodes)):
            t0 = time.perf_counter()
            title = f"{job.task} {job.variant} {name} #{i}"
            ok, label = kind == "generated", f"render: {name} {i}"
            frames = episode_frames(renderer.frame, store, i, job.subtasks, title, ok, label)
            seconds += time.perf_counter() - t0
            frames_total += len(frames)
            video = f"{name}_{i}.mp4"
            write_mp4(out_dir / video, frames, job.fps)
            if i == 0:
                write_gif(out_dir / f"{name}_{i}.gif", frames, job.fps)
            print(f"render: {name} episode {i} ({len(frames)} frames) -> {job.out / video}")
    renderer.close()
    return frames_total, seconds
