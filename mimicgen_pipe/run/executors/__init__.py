"""Executors: one place that maps blocks of work (generation attempts, evaluation rollouts)
to their results.

``local`` runs the blocks on a pool of spawned processes on this machine
(:mod:`.local`); ``ray`` runs the same worker function as Ray tasks on a cluster
(:mod:`.ray`). Either way :func:`map_blocks` yields the results in task order, to the driver
alone, which writes every output. A block's result depends only on the block (each one runs
on a freshly rebuilt scene from its own seeds), so the bytes written are the same whichever
executor and however many workers ran it.

With a :class:`~mimicgen_pipe.run.resume.WorkDir`, every finished block is saved there as it
comes back (in whatever order), and blocks that an earlier, killed run of the same work
finished are read back instead of run again.

An executor is one module of this package, named as ``generate.executor`` and
``evaluate.executor`` name it (mimicgen_pipe.core.registry), defining

- ``check_settings(address) -> None``: InputError for settings it cannot run with, read from
  the environment alone (nothing started or contacted), when the Executor is made, before
  any work;
- ``imap_unordered(fn, tasks, workers, initializer, initargs, address)``: (index,
  ``fn(task)``) for each (index, task) of the iterable ``tasks``, as they finish, every
  worker calling ``initializer(*initargs)`` once before its first block; closing the
  iterator stops the work, its workers gone when that returns.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, TypeVar

from mimicgen_pipe.core.registry import load
from mimicgen_pipe.run.resume import WorkDir

if TYPE_CHECKING:
    from mimicgen_pipe.data.params import Params

T = TypeVar("T")
R = TypeVar("R")


@dataclass(frozen=True)
class Executor:
    """kind: an executor of this package, ``local`` (process pool here) or ``ray``. workers:
    local processes, or for Ray the CPUs of the local Ray instance it starts when no cluster
    address is given (on a cluster every CPU it offers is used). address: a Ray cluster's
    GCS (``auto`` or ``host:port``); None uses ``RAY_ADDRESS`` when set, else starts a local
    Ray (loopback only). A cluster is used only with Ray's token authentication on: settings
    that turn it off are refused here, when the executor is made, before any work."""

    kind: str = "local"
    workers: int = 1
    address: str | None = None

    def __post_init__(self) -> None:
        load("mimicgen_pipe.run.executors", self.kind).check_settings(self.address)


def stage_executor(params: Params, stage: Literal["generate", "evaluate"]) -> Executor:
    """Where a stage's blocks run: its ``executor`` and ``workers`` keys, and ``ray``."""
    section = params.generate if stage == "generate" else params.evaluate
    return Executor(section.executor, section.workers, params.ray.address)


def map_blocks(
    fn: Callable[[T], R],
    tasks: Sequence[T],
    executor: Executor,
    initializer: Callable[..., None],
    initargs: tuple[Any, ...] = (),
    work: WorkDir | None = None,
) -> Iterator[R]:
    """``fn`` over ``tasks``, results in task order. Every worker calls
    ``initializer(*initargs)`` once before its first block (to build its simulator). ``fn``
    and ``initializer`` must be module-level functions (they are sent by reference).

    Close the iterator (or let an exception through it) to stop early: the workers are gone
    when that returns. Blocks that finished are in ``work`` by then."""
    done = work.resumed if work is not None else frozenset()
    # lazily: a run may allow far more blocks than it runs (and each task is made on demand)
    todo = ((i, tasks[i]) for i in range(len(tasks)) if i not in done)
    results = _unordered(executor, fn, todo, initializer, initargs)
    waiting: dict[int, R] = {}
    try:
        for i in range(len(tasks)):
            while i not in waiting and i not in done:
                j, result = next(results)
                if work is not None:
                    work.save(j, result)
                waiting[j] = result
            if i in waiting:
                yield waiting.pop(i)
            else:
                assert work is not None
                yield work.load(i)
    finally:
        results.close()


def _unordered(
    executor: Executor,
    fn: Callable[[T], R],
    tasks: Iterable[tuple[int, T]],
    initializer: Callable[..., None],
    initargs: tuple[Any, ...],
) -> Iterator[tuple[int, R]]:
    module = load("mimicgen_pipe.run.executors", executor.kind)
    return module.imap_unordered(
        fn, tasks, executor.workers, initializer, initargs, executor.address
    )
