"""The ``ray`` executor: blocks as Ray tasks, one CPU each, on a cluster or a local Ray.

The driver connects to ``address`` (or ``RAY_ADDRESS``) when given, else starts a Ray on
this machine with ``workers`` CPUs and stops it at the end. Every node of a cluster must have
the pinned dependencies installed (requirements.txt, the same Ray release as the driver); the
code of this package and of the back ends is shipped to it from the driver. A worker
process builds its simulator once, at its first block, and reuses it for the blocks that
follow. A task whose worker process or node dies is run again elsewhere (Ray retries it);
its result is the same, since a block depends on its seeds only.
"""

from __future__ import annotations

import logging
import os
import signal
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

from mimicgen_pipe.interrupts import deferred

T = TypeVar("T")
R = TypeVar("R")

RETRIES = 3  # a block whose worker or node dies is re-run up to this many times
OBJECT_STORE_BYTES = 256 * 2**20  # of a local Ray: results of a few blocks in flight
IN_FLIGHT_PER_CPU = 2  # blocks submitted ahead, so no CPU waits for the driver
WAIT_SECONDS = 0.25  # longest wait for a result between two looks at pending signals

_READY: str | None = None  # the run this worker process has built its simulator for


def _run(setup: tuple[str, Callable[..., None], tuple[Any, ...]], fn: Callable, task: Any) -> Any:
    """A block on a Ray worker: initialise once per run and process, then ``fn(task)``."""
    global _READY
    token, initializer, initargs = setup
    if _READY != token:
        initializer(*initargs)
        _READY = token
    return fn(task)


def _package_dir(name: str) -> str:
    import importlib

    return str(Path(importlib.import_module(name).__file__).parent)


def _connect(workers: int, address: str | None) -> bool:
    """Connect the driver to Ray; True when this call connected it (to disconnect at the end,
    which stops a Ray it started here)."""
    import ray

    if ray.is_initialized():  # the caller's own connection (tests, notebooks)
        return False
    address = address or os.environ.get("RAY_ADDRESS") or None
    # ERROR: Ray's start-up warnings (e.g. that token authentication is on) would add lines
    # to every stage's output; a failing block still raises its error in the driver
    kwargs: dict[str, Any] = {"logging_level": logging.ERROR, "log_to_driver": False}
    if address is None:
        kwargs |= {
            "num_cpus": workers,
            "include_dashboard": False,
            "object_store_memory": OBJECT_STORE_BYTES,
            # Ray starts workers at nice 15 by default, which starves them beside any other
            # load; the local executor's workers run at normal priority, and so do these
            "_system_config": {"worker_niceness": 0},
        }
    else:
        # the cluster's workers run the driver's own code of this package and the back ends
        # (Ray ships it to every node), so that an older install there cannot change a block
        kwargs["runtime_env"] = {"py_modules": [_package_dir(p) for p in ("mimicgen_pipe", "envs")]}
    # ray.init replaces the SIGTERM handler with one that exits at once, which during its
    # start-up would orphan the services it has started; the stage's handler stays, holding
    # the signal back (the caller defers) until Ray is up and can be shut down in order
    from ray._private import utils as ray_utils  # the pinned release's own hook

    own = ray_utils.set_sigterm_handler
    ray_utils.set_sigterm_handler = lambda handler: None
    try:
        ray.init(address=address, **kwargs)
    finally:
        ray_utils.set_sigterm_handler = own
    # Ray's C++ core also puts a crash reporter in front of SIGTERM that prints a stack dump
    # before passing the signal on; a SIGTERM is a request to stop, not a crash, so the
    # stage's own handler is put back (the reporter stays on SIGSEGV, SIGABRT and the like)
    if (handler := signal.getsignal(signal.SIGTERM)) is not None:  # None: set outside Python
        signal.signal(signal.SIGTERM, handler)
    return True


def imap_unordered(
    fn: Callable[[T], R],
    tasks: list[tuple[int, T]],
    workers: int,
    initializer: Callable[..., None],
    initargs: tuple[Any, ...] = (),
    address: str | None = None,
) -> Iterator[tuple[int, R]]:
    """(index, ``fn(task)``) for each (index, task), as the tasks finish. Close the iterator
    to stop early: unfinished tasks are cancelled and a Ray this started is stopped."""
    if not tasks:
        return
    import ray

    # Ray's calls run C++ code that a Python exception raised inside by the stage's signal
    # handler leaves in a broken state: signals are held back during each call and raised
    # between them (waits are short, so a Ctrl-C still stops the stage within a second)
    started = False
    pending: dict[Any, int] = {}
    try:
        with deferred():
            started = _connect(workers, address)
            remote = ray.remote(num_cpus=1, max_retries=RETRIES)(_run)
            setup = ray.put((uuid.uuid4().hex, initializer, initargs))
            cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
        queue = iter(tasks)
        while True:
            with deferred():
                for i, task in queue:
                    pending[remote.remote(setup, fn, task)] = i
                    if len(pending) >= IN_FLIGHT_PER_CPU * cpus:
                        break
                if not pending:
                    return
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=WAIT_SECONDS)
                if not ready:
                    continue
                i = pending.pop(ready[0])
                try:
                    result = ray.get(ready[0])
                except ray.exceptions.RayTaskError as err:  # the worker's own exception
                    raise err.as_instanceof_cause() from None
            yield i, result
    finally:
        with deferred():
            if started:
                ray.shutdown()  # ends this driver's job: Ray stops its unfinished tasks
            else:
                for ref in pending:
                    ray.cancel(ref)
