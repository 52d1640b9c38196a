"""Progress of rollouts step by step, while the workers run them.

The executors carry blocks and their results only, and a block of rollouts can run for
minutes (ten episodes of an image policy: half an hour on a CPU). So each worker keeps its
running counts, steps run and episodes finished with their steps and seconds, in a small
file of a directory the evaluator makes (:class:`StepCounter`), replaced whole at each
write; the evaluator sums the files every :data:`PROGRESS_SECONDS` into the project's usual
tqdm bar (stderr), here of steps: done / total, rate, time left. Once an episode has
finished it prints an estimate of the total time (:class:`StepProgress`).

A step of the bar is one step of an episode's horizon: an episode that succeeds early counts
its whole horizon once it ends, so the total is known up front and the time left assumes
each episode may run to its horizon. A worker that cannot reach the directory (a Ray node on
another machine) counts nothing there, and the bar moves as its blocks come back. Nothing
here reaches an output."""

from __future__ import annotations

import os
import shutil
import struct
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

PROGRESS_SECONDS = 2.0  # the evaluator reads the counts, and redraws its bar, this often
WRITE_SECONDS = 0.5  # a worker writes its counts this often within an episode, and at its end
# a worker's counts: steps run, episodes finished, their steps, their seconds
RECORD = struct.Struct("<qqqd")


class StepCounter:
    """A worker's running counts, in its file ``<directory>/<pid>``. :meth:`step` is called
    once after an episode's reset and once for each of its steps; :meth:`episode` ends an
    episode. A write that fails (the evaluator has ended and removed its directory) stops
    the writing, never the rollouts."""

    def __init__(self, directory: str) -> None:
        self.path = Path(directory) / str(os.getpid())
        self.steps = self.episodes = self.episode_steps = self.calls = 0
        self.seconds = 0.0
        self.written = time.monotonic()
        self.writing = True

    @classmethod
    def open(cls, directory: str | None) -> StepCounter | None:
        """A counter in ``directory``, None where there is none to write to."""
        return cls(directory) if directory and os.path.isdir(directory) else None

    def step(self, env: Any = None) -> None:
        self.calls += 1
        if self.calls > 1:  # the first call of an episode follows its reset
            self.steps += 1
        if time.monotonic() - self.written >= WRITE_SECONDS:
            self._write()

    def episode(self, steps: int, seconds: float) -> None:
        """An episode of ``steps`` steps ended after ``seconds`` (its reset included)."""
        self.calls = 0
        self.episodes += 1
        self.episode_steps += steps
        self.seconds += seconds
        self._write()

    def _write(self) -> None:
        self.written = time.monotonic()
        if not self.writing:
            return
        record = RECORD.pack(self.steps, self.episodes, self.episode_steps, self.seconds)
        tmp = self.path.with_name(f"{self.path.name}.tmp")
        try:
            tmp.write_bytes(record)
            os.replace(tmp, self.path)  # the evaluator reads a whole record, old or new
        except OSError:
            self.writing = False


@dataclass(frozen=True)
class Counts:
    """The workers' counts summed: steps run, episodes finished, their steps and seconds."""

    steps: int = 0
    episodes: int = 0
    episode_steps: int = 0
    seconds: float = 0.0

    def slots(self, horizon: int) -> int:
        """Steps of the bar: a finished episode's whole horizon, a running one's steps."""
        return self.episodes * horizon + self.steps - self.episode_steps


def read_counts(directory: str | os.PathLike) -> Counts:
    """The counts of every worker's file in ``directory``, summed."""
    total = [0, 0, 0, 0.0]
    for path in Path(directory).iterdir():
        if path.suffix:  # a record being written
            continue
        try:
            values = RECORD.unpack(path.read_bytes())
        except (OSError, struct.error):
            continue
        total = [a + b for a, b in zip(total, values, strict=True)]
    return Counts(int(total[0]), int(total[1]), int(total[2]), float(total[3]))


def duration(seconds: float) -> str:
    """``4.5 s``, ``45 s``, ``12 min``, ``2.1 h``."""
    if seconds < 10:
        return f"{seconds:.1f} s"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def estimate_line(
    label: str, counts: Counts, total: int, done: int, elapsed: float, parallel: int
) -> str:
    """What the evaluator says once an episode has finished: the time an episode took and a
    step, and the total time estimated from them, for ``total`` steps of which ``done`` are
    done after ``elapsed`` seconds, on ``parallel`` workers at once."""
    per_episode = counts.seconds / counts.episodes
    per_step = counts.seconds / max(counts.episode_steps, 1)
    left = max(total - done, 0) * per_step / parallel
    first = "first episode" if counts.episodes == 1 else f"first {counts.episodes} episodes"
    return (
        f"{label}: {first}: {per_episode:.3g} s each ({counts.episode_steps / counts.episodes:.0f}"
        f" steps, {1000 * per_step:.1f} ms a step); estimated total {duration(elapsed + left)} "
        f"for {total} steps on {parallel} worker{'s' if parallel > 1 else ''} (at most: an "
        "episode that succeeds ends early)"
    )


class StepProgress:
    """The evaluator's bar of ``episodes`` episodes of ``horizon`` steps, run on
    ``parallel`` workers at once, from the counts its workers keep in :attr:`directory`;
    :meth:`returned` tells it of episodes whose results came back. A context: the reading
    thread ends, and the directory goes, when it closes."""

    def __init__(self, label: str, episodes: int, horizon: int, parallel: int) -> None:
        self.label, self.horizon, self.parallel = label, horizon, max(parallel, 1)
        self.episodes_total, self.total = episodes, episodes * horizon
        self.episodes_returned = 0
        self.estimated = False
        self.directory = tempfile.mkdtemp(prefix="mimicgen-rollouts-")
        self.started = time.perf_counter()
        # counts arrive in bursts (every PROGRESS_SECONDS, or a block at a time): the time
        # left from the mean rate so far, which settles, not from the last burst's
        self.bar = tqdm(total=self.total, desc=label, unit="step", file=sys.stderr, smoothing=0)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="rollout-progress", daemon=True)
        self._thread.start()

    def returned(self, episodes: int) -> None:
        self.episodes_returned += episodes

    def _run(self) -> None:
        while not self._stop.wait(PROGRESS_SECONDS):
            try:
                self.poll()
            except OSError:  # a directory that cannot be read: no progress, the same rollouts
                return

    def poll(self, final: bool = False) -> None:
        """Read the counts; move the bar; say the estimate once an episode has finished."""
        counts = read_counts(self.directory)
        done = min(max(counts.slots(self.horizon), self.episodes_returned * self.horizon),
                   self.total)  # fmt: skip
        self.bar.update(done - self.bar.n)
        if counts.episodes and not self.estimated and not final:
            self.estimated = True
            elapsed = time.perf_counter() - self.started
            line = estimate_line(self.label, counts, self.total, done, elapsed, self.parallel)
            tqdm.write(line)

    def __enter__(self) -> StepProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        try:
            self.poll(final=True)
        finally:
            self.bar.close()
            shutil.rmtree(self.directory, ignore_errors=True)
