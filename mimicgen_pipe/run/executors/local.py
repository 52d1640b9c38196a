"""The ``local`` executor: simulator processes that never outlive the stage that started
them.

Each worker is a spawned process with a pipe of its own and holds one block at a time: its
result is read before it gets the next, so no pipe ever fills, nothing is queued ahead (a
run may allow millions of blocks; tasks are read one per result taken), and no lock or
helper thread is shared between processes, so stopping never waits on one. What the pool
adds for a command a person stops with Ctrl-C or a scheduler stops with SIGTERM or SIGKILL:

- workers ignore SIGINT: a Ctrl-C in a terminal signals the whole process group, and the
  parent alone decides what to do (tear the pool down, print one line);
- workers die with their parent: on Linux the kernel sends them SIGKILL when it dies
  (``PR_SET_PDEATHSIG``); elsewhere a thread polls the parent's pid;
- leaving the iterator early, by an exception or by closing it, terminates the workers
  (SIGTERM, which they do not catch) and joins them, so that they write nothing more;
- a worker that dies (killed, out of memory, a crash inside the simulator) is an error in
  the parent naming it and its exit code, never a wait without end; an exception in a
  worker (its initializer's included) is raised in the parent with the worker's traceback.
"""

from __future__ import annotations

import itertools
import multiprocessing as mp
import os
import pickle
import signal
import traceback
from collections.abc import Callable, Iterable, Iterator
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess
from typing import Any, TypeVar

from mimicgen_pipe.core.interrupts import PARENT_POLL_SECONDS, die_with_parent

T = TypeVar("T")
R = TypeVar("R")


class WorkerDied(RuntimeError):
    """A worker process ended while it held a block."""


class _RemoteTraceback(Exception):
    def __str__(self) -> str:
        return f"\n\n(in the worker process)\n{self.args[0]}"


def _portable(error: BaseException) -> tuple[BaseException, str]:
    """The error and its traceback as text; the error itself when it pickles (so that the
    parent raises the same type), else a RuntimeError saying what it was."""
    text = "".join(traceback.format_exception(error))
    try:
        pickle.dumps(error)
    except Exception:  # noqa: BLE001 - whatever stops it crossing the pipe
        error = RuntimeError(f"{type(error).__name__}: {error}")
    return error, text


def _worker(
    conn: Connection, parent: int, initializer: Callable[..., None], initargs: tuple
) -> None:
    """Run the blocks sent on ``conn`` until it closes, answering each with (index, result,
    None) or (index, None, error)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(parent)
    try:
        initializer(*initargs)
    except BaseException as error:  # noqa: BLE001 - the parent raises it
        conn.send((None, None, _portable(error)))
        return
    while True:
        try:
            fn, i, task = conn.recv()
        except EOFError:
            return
        try:
            answer = (i, fn(task), None)
        except BaseException as error:  # noqa: BLE001 - the parent raises it
            answer = (i, None, _portable(error))
        conn.send(answer)


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
    through it) to stop early: the workers are gone when that returns. ``address`` is unused
    (a Ray cluster's, for the ray executor)."""
    tasks = iter(tasks)  # read one per result taken: ``tasks`` may be long and lazy
    first = list(itertools.islice(tasks, max(1, workers)))  # no more processes than tasks
    if not first:
        return
    if workers <= 1:
        initializer(*initargs)
        for i, task in itertools.chain(first, tasks):
            yield i, fn(task)
        return
    # Workers inherit a signal mask that blocks SIGINT: it would otherwise reach a worker
    # still importing its modules, before _worker ignores it (a traceback). A Ctrl-C
    # meanwhile stays pending here and is raised, inside the try, when the mask is restored.
    # (A worker that a SIGTERM here orphans finds its parent gone in _worker, and exits.)
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGINT])
    procs: dict[Any, BaseProcess] = {}  # each worker's end of the pipe here -> its process
    try:
        spawn = mp.get_context("spawn")
        for _ in first:
            here, there = spawn.Pipe()
            proc = spawn.Process(
                target=_worker, args=(there, os.getpid(), initializer, initargs), daemon=True
            )
            proc.start()
            there.close()
            procs[here] = proc
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
        pending = itertools.chain(first, tasks)
        busy = {conn for conn in procs if _hand(conn, fn, pending)}
        while busy:
            # a timeout, so that a Ctrl-C is raised while the blocks run
            for conn in wait(list(busy), timeout=PARENT_POLL_SECONDS):
                i, result, error = _receive(conn, procs[conn])
                if error is not None:
                    raise error[0] from _RemoteTraceback(error[1])
                if not _hand(conn, fn, pending):
                    busy.discard(conn)
                yield i, result
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
        for proc in procs.values():
            if proc.exitcode is None:
                proc.terminate()
        for conn, proc in procs.items():
            proc.join()
            conn.close()


def _hand(conn: Any, fn: Callable[[T], R], pending: Iterator[tuple[int, T]]) -> bool:
    """Send the next block to a worker holding none; False when there is none left."""
    item = next(pending, None)
    if item is None:
        return False
    conn.send((fn, *item))
    return True


def _receive(conn: Any, proc: BaseProcess) -> tuple[Any, Any, Any]:
    """A worker's answer, or WorkerDied when its pipe closed without one."""
    try:
        return conn.recv()
    except EOFError:
        proc.join()
        raise WorkerDied(
            f"local executor: worker process {proc.pid} ended with exit code "
            f"{proc.exitcode} while running a block (killed, out of memory, or a crash in "
            "the simulator)"
        ) from None
