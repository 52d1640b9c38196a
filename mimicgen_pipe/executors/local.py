"""The ``local`` executor: a pool of simulator processes that never outlives the stage that
started it.

The pool here adds what a plain ``multiprocessing.Pool`` lacks for a command a person stops
with Ctrl-C or a scheduler stops with SIGTERM or SIGKILL:

- workers ignore SIGINT: a Ctrl-C in a terminal signals the whole process group, and the
  parent alone decides what to do (tear the pool down, print one line);
- workers die with their parent: on Linux the kernel sends them SIGKILL when it dies
  (``PR_SET_PDEATHSIG``); elsewhere a thread polls the parent's pid;
- leaving the iterator early, by an exception or by closing it, terminates the workers
  (SIGTERM, which they do not catch) and joins them, so that they write nothing more.
"""

from __future__ import annotations

import contextlib
import ctypes
import itertools
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TypeVar

T = TypeVar("T")
R = TypeVar("R")

_PR_SET_PDEATHSIG = 1
PARENT_POLL_SECONDS = 0.5


def _die_with_parent(parent: int) -> None:
    """Make this process exit when ``parent`` does, however the parent ends."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0:
                if os.getppid() != parent:  # it died before prctl took effect
                    os._exit(1)
                return

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_SECONDS)
        os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _init(parent: int, initializer: Callable[..., None], initargs: tuple) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _die_with_parent(parent)
    initializer(*initargs)


def _indexed(item: tuple[Callable[[T], R], int, T]) -> tuple[int, R]:
    fn, i, task = item
    return i, fn(task)


def check_settings(address: str | None) -> None:
    """Nothing to refuse: a local pool reads no settings (``address`` is Ray's)."""


def imap_unordered(
    fn: Callable[[T], R],
    tasks: Iterable[tuple[int, T]],
    workers: int,
    initializer: Callable[..., None],
    initargs: tuple[Any, ...] = (),
    address: str | None = None,
) -> Iterator[tuple[int, R]]:
    """(index, ``fn(task)``) for each (index, task), as they finish: in this process, in
    order, when ``workers`` <= 1 (after ``initializer(*initargs)``), else on that many
    spawned processes, each initialised once. Close the iterator (or let an exception
    through it) to stop early: the pool is gone when that returns. ``address`` is unused (a
    Ray cluster's, for the ray executor)."""
    tasks = iter(tasks)  # read as the pool asks for them: ``tasks`` may be long and lazy
    first = list(itertools.islice(tasks, max(1, workers)))  # no more processes than tasks
    if not first:
        return
    if workers <= 1:
        initializer(*initargs)
        for i, task in itertools.chain(first, tasks):
            yield i, fn(task)
        return
    # Workers inherit a signal mask that blocks SIGINT: it would otherwise reach a worker
    # still importing its modules, before _init ignores it (a traceback). A Ctrl-C meanwhile
    # stays pending here and is raised, inside the try, when the mask is restored. (A worker
    # that a SIGTERM here orphans finds its parent gone in _init, and exits.)
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGINT])
    pool = None
    try:
        pool = mp.get_context("spawn").Pool(
            len(first),
            initializer=_init,
            initargs=(os.getpid(), initializer, initargs),
        )
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
        items = ((fn, i, t) for i, t in itertools.chain(first, tasks))
        yield from pool.imap_unordered(_indexed, items, chunksize=1)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
        if pool is not None:
            pool.terminate()
            pool.join()
