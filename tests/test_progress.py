"""Long stages show progress while they work: the motion planner's child reports each seed
it tried (source), and observe's workers count each frame they render, so that a bar moves
before a plan's or a block's results come back. No simulator: fake renderers and lines."""

from __future__ import annotations

import io

import numpy as np
import pytest
from tqdm import tqdm

from mimicgen_pipe.backends.maniskill.source import PLANNED, follow_planner, planned_counts
from mimicgen_pipe.data.store import write_store
from mimicgen_pipe.media import camera_images
from mimicgen_pipe.media.camera_images import ImageJob
from mimicgen_pipe.run import rollout_progress
from mimicgen_pipe.run.rollout_progress import read_counts


@pytest.mark.parametrize(
    ("line", "counts"),
    [
        (f"{PLANNED} 3 1\n", (3, 1)),
        (f"{PLANNED} 0 12", (0, 12)),
        (f"{PLANNED} 3\n", None),  # not the child's line
        (f"{PLANNED} three 1\n", None),
        ("3 1\n", None),  # the child's result, not a progress line
        ("[mplib] planning failed\n", None),
    ],
)
def test_planner_progress_lines(line, counts):
    assert planned_counts(line) == counts


def test_the_planning_bar_follows_the_childs_lines():
    """Each progress line moves the bar to the demos kept; the planners' own output is
    passed over; the result is the child's last other line."""
    lines = ["[mplib] warming up\n", f"{PLANNED} 0 1\n", f"{PLANNED} 1 1\n",
             "screw plan failed\n", f"{PLANNED} 2 1\n", "2 1\n"]  # fmt: skip
    seen = []
    with tqdm(total=2, file=io.StringIO()) as bar:

        def watched():
            for line in lines:
                yield line
                seen.append(bar.n)

        assert follow_planner(watched(), bar) == "2 1\n"
    assert seen == [0, 0, 1, 1, 2, 2]  # moved as each line came, not at the end
    assert bar.postfix == "failed=1"


class CountingRenderer:
    """A renderer that notes, at each frame, the frames its worker has counted so far."""

    def __init__(self, directory):
        self.directory, self.seen = directory, []
        self.seconds = {"front": 0.0}

    def images(self, state):
        self.seen.append(read_counts(self.directory).steps)
        return {"front": np.full((2, 3, 3), int(state[0]), np.uint8)}


def test_observe_workers_count_frames_before_a_block_ends(tmp_path, monkeypatch):
    """A worker's count moves frame by frame within the first episode of its first block,
    which is what the stage's bar reads every 2 s."""
    monkeypatch.setattr(rollout_progress, "WRITE_SECONDS", 0.0)  # every frame written
    monkeypatch.setattr(camera_images, "_WORKER", None)
    steps = [{"env_state": np.arange(n, dtype=np.float32)[:, None] * np.ones(4, np.float32),
              "actions": np.zeros((n, 7), np.float32)} for n in (5, 3)]  # fmt: skip
    attrs = {"task": "stack", "variant": "D0", "backend": "pybullet", "robot": "panda"}
    store = write_store(tmp_path / "g.zarr", "generated", steps, {}, attrs)
    directory = tmp_path / "progress"
    directory.mkdir()
    renderer = CountingRenderer(directory)
    job = ImageJob(store, "pybullet", "stack", "panda", ("front",), 2, 3,
                     lambda *a: renderer, progress=str(directory))  # fmt: skip
    camera_images._init_worker(job)
    images = camera_images._render_block([0, 1])
    assert renderer.seen == list(range(8))  # counted before the next frame, episode 0 too
    assert read_counts(directory).steps == 8
    assert images["front"].shape == (8, 2, 3, 3)


def test_generates_time_left_settles_when_attempts_come_back_in_bursts():
    """Two blocks of 5 demos, at 20 s and at 40 s, each counted demo by demo within a
    millisecond: the time left for the other 10 is taken from the mean rate so far (40 s),
    not from a moving average that the bursts pull towards 0 s."""
    from mimicgen_pipe.run.runner import attempts_bar

    now = [0.0]
    bar = attempts_bar(20, "demo", "generate", file=io.StringIO(), mininterval=0)
    bar._time = lambda: now[0]
    bar.start_t = bar.last_print_t = 0.0
    for block in (20.0, 40.0):
        for k in range(5):
            now[0] = block + k * 1e-4
            bar.update(1)
    info = bar.format_dict
    rate = info["rate"] or (info["n"] - info["initial"]) / info["elapsed"]
    assert 36 < (info["total"] - info["n"]) / rate < 44
    bar.close()
