"""Running many generation attempts, on any executor (mimicgen_pipe.executors).

Every attempt's seed is derived from (stage seed, variant, attempt index), and results are
consumed in attempt order. A simulator carries history from one episode to the next (PhysX
keeps contact caches across resets), so attempts run in fixed blocks of
``ATTEMPTS_PER_BLOCK``, each on a freshly rebuilt scene: the dataset is then the same on one
worker or many, whichever worker runs a block.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from mimicgen_pipe.executors import Executor, map_blocks
from mimicgen_pipe.generation import Attempt, Env, GenerationConfig, SourceDemos, run_attempt
from mimicgen_pipe.resume import WorkDir
from mimicgen_pipe.taskspec import TaskSpec


def attempt_seed(seed: int, variant: str, attempt: int) -> int:
    """A reset seed for one attempt, in [0, 2**30): simulators take int32 seeds, and
    [2**30, 2**31) is kept for policy evaluation (mimicgen_pipe.evaluation)."""
    ss = np.random.SeedSequence([seed, int.from_bytes(variant.encode(), "little"), attempt])
    return int(ss.generate_state(1, np.uint32)[0] & 0x3FFFFFFF)


@dataclass(frozen=True)
class AttemptJob:
    """Everything a worker needs, sent once per worker."""

    make_env: Callable[[], Env]
    sources: SourceDemos
    spec: TaskSpec
    config: GenerationConfig
    variant: str


ATTEMPTS_PER_BLOCK = 16  # rebuilding a ManiSkill scene costs ~0.24 s, ~4% of a block
_WORKER: tuple[AttemptJob, Env] | None = None


def _init_worker(job: AttemptJob) -> None:
    global _WORKER
    _WORKER = (job, job.make_env())


def _run_block(seeds: list[int]) -> list[tuple[int, Attempt, float]]:
    """Attempts of one block, on a freshly rebuilt scene; seconds include the rebuild share."""
    assert _WORKER is not None
    job, env = _WORKER
    t0 = time.perf_counter()
    env.rebuild()
    share = (time.perf_counter() - t0) / max(1, len(seeds))
    out = []
    for seed in seeds:
        t0 = time.perf_counter()
        attempt = run_attempt(env, job.sources, job.spec, job.config, job.variant, seed)
        out.append((seed, attempt, time.perf_counter() - t0 + share))
    return out


def attempt_blocks(seeds: list[int]) -> list[list[int]]:
    """The fixed blocks the attempts run in (a resumed run must cut them the same way)."""
    return [seeds[i : i + ATTEMPTS_PER_BLOCK] for i in range(0, len(seeds), ATTEMPTS_PER_BLOCK)]


def run_attempts(
    job: AttemptJob, seeds: list[int], executor: Executor, work: WorkDir | None = None
) -> Iterator[tuple[int, Attempt, float]]:
    """Yield (seed, attempt, seconds) in the order of ``seeds``; with ``work``, finished
    blocks are saved there and those an earlier run saved are reused. Stop consuming to stop
    early: the workers are gone when the generator is closed (or an exception, such as an
    interrupt, goes through it)."""
    results = map_blocks(_run_block, attempt_blocks(seeds), executor, _init_worker, (job,), work)
    try:
        for block in results:
            yield from block
    finally:
        results.close()
