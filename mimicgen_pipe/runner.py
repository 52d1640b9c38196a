"""Running many generation attempts: in-process or over a pool of simulator processes.

Every attempt's seed is derived from (stage seed, variant, attempt index), and results are
consumed in attempt order, so the dataset is the same on one worker or many.
"""

from __future__ import annotations

import multiprocessing as mp
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from mimicgen_pipe.generation import Attempt, Env, GenerationConfig, SourceDemos, run_attempt
from mimicgen_pipe.taskspec import TaskSpec


def attempt_seed(seed: int, variant: str, attempt: int) -> int:
    """A 31-bit reset seed for one attempt (simulators take int32 seeds)."""
    ss = np.random.SeedSequence([seed, int.from_bytes(variant.encode(), "little"), attempt])
    return int(ss.generate_state(1, np.uint32)[0] & 0x7FFFFFFF)


@dataclass(frozen=True)
class AttemptJob:
    """Everything a worker needs, sent once per worker."""

    make_env: Callable[[], Env]
    sources: SourceDemos
    spec: TaskSpec
    config: GenerationConfig
    variant: str


_WORKER: tuple[AttemptJob, Env] | None = None


def _init_worker(job: AttemptJob) -> None:
    global _WORKER
    _WORKER = (job, job.make_env())


def _run_one(seed: int) -> tuple[int, Attempt, float]:
    assert _WORKER is not None
    job, env = _WORKER
    t0 = time.perf_counter()
    attempt = run_attempt(env, job.sources, job.spec, job.config, job.variant, seed)
    return seed, attempt, time.perf_counter() - t0


def run_attempts(job: AttemptJob, seeds: list[int], workers: int) -> Iterator[tuple[int, Attempt, float]]:
    """Yield (seed, attempt, seconds) in the order of ``seeds``. Stop consuming to stop early:
    the pool is torn down when the generator is closed."""
    if workers <= 1:
        _init_worker(job)
        for s in seeds:
            yield _run_one(s)
        return
    ctx = mp.get_context("spawn")
    pool = ctx.Pool(workers, initializer=_init_worker, initargs=(job,))
    try:
        yield from pool.imap(_run_one, seeds, chunksize=1)
    finally:
        pool.terminate()
        pool.join()
