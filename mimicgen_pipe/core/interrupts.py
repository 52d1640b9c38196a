"""Ctrl-C (SIGINT) and SIGTERM as one exception, raised in the main thread.

The command-line entry point turns both signals into :class:`Interrupted` so that every
``finally`` runs (worker pools are torn down, temporaries removed) and it can print one line
and exit with 128 + the signal number, as a shell expects. The few steps that must not be cut
in half (renaming a finished output set into place) run under :func:`deferred`.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(BaseException):
    """The stage was asked to stop. A BaseException, like KeyboardInterrupt, so that no
    ``except Exception`` on the way up swallows it. ``detail`` says how far the stage had got
    (a stage may set it on the way up)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum
        self.detail = ""

    @property
    def exit_code(self) -> int:
        return 128 + self.signum

    def describe(self) -> str:
        """Which signal and how far the stage got, e.g. "interrupted (SIGTERM) after 37 of
        200 attempts"."""
        detail = f" {self.detail}" if self.detail else ""
        return f"interrupted ({signal.Signals(self.signum).name}){detail}"


_deferring = 0
_pending: list[int] = []
_raised = False


def _handler(signum: int, frame: object) -> None:
    global _raised
    if _deferring:
        _pending.append(signum)
        return
    if _raised:
        # a second Ctrl-C while the first one is being cleaned up: stop at once. Workers die
        # with us (they watch their parent); stale temporaries go at the next run.
        name = signal.Signals(signum).name
        os.write(2, f"mimicgen-pipe: interrupted again ({name}); stopped at once\n".encode())
        os._exit(128 + signum)
    _raised = True
    raise Interrupted(signum)


@contextlib.contextmanager
def as_exceptions() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM raise Interrupted in the main thread; the previous
    handlers come back afterwards (tests call the entry point in-process). Outside the main
    thread signals cannot be handled, and nothing changes."""
    global _raised
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.getsignal(s) for s in SIGNALS}
    _raised = False
    _pending.clear()
    for s in SIGNALS:
        signal.signal(s, _handler)
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Hold SIGINT/SIGTERM back while the block runs (a few renames that must not be cut in
    half); a signal that came in meanwhile is raised when the outermost such block ends."""
    global _deferring, _raised
    _deferring += 1
    try:
        yield
    finally:
        _deferring -= 1
    if not _deferring and _pending:
        signum = _pending[0]
        _pending.clear()
        if not _raised:
            _raised = True
            raise Interrupted(signum)


PARENT_PID_ENV = "MIMICGEN_PIPE_PARENT_PID"  # set for a child process that must not outlive us
PARENT_POLL_SECONDS = 0.5  # where the kernel cannot signal a parent's death
_PR_SET_PDEATHSIG = 1


def child_environment() -> dict[str, str]:
    """The environment for a helper child process (a motion planner, a converter) that
    :func:`die_with_parent` ties to this process."""
    return dict(os.environ, **{PARENT_PID_ENV: str(os.getpid())})


def die_with_parent(parent: int | None = None) -> None:
    """In a child process: exit when ``parent`` (default: the pid :func:`child_environment`
    recorded; none recorded: do nothing) dies, however it dies (``kill -9`` included, which
    runs none of the parent's cleanup), so that no worker or planner outlives its stage. On
    Linux the kernel sends SIGKILL (``PR_SET_PDEATHSIG``); elsewhere a thread polls the
    parent's pid. A parent already gone: exit at once."""
    if parent is None:
        if PARENT_PID_ENV not in os.environ:
            return
        parent = int(os.environ[PARENT_PID_ENV])
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
