"""The ``ray`` executor: blocks as Ray tasks, one CPU each, on a cluster or a local Ray.

The driver connects to ``address`` (or ``RAY_ADDRESS``) when given, else starts a Ray on
this machine with ``workers`` CPUs and stops it at the end. Every node of a cluster must have
the pinned dependencies installed (requirements.txt, the same Ray release as the driver); the
code of this package and of the back ends is shipped to it from the driver. A worker
process builds its simulator once, at its first block, and reuses it for the blocks that
follow. A task whose worker process or node dies is run again elsewhere (Ray retries it);
its result is the same, since a block depends on its seeds only.

Whoever can reach a Ray's services can run code in it, and the driver unpickles what its
workers return, so: a local Ray listens on the loopback interface only (its GCS, raylet,
object manager, agents and workers; no dashboard), and a cluster is used only with Ray's
token authentication on at both ends. Before connecting, the driver refuses
``RAY_AUTH_MODE`` set to anything but ``token``, a missing token, a cluster that lets in a
driver without a token, and a cluster that refuses this driver's token, each with one line.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import subprocess
import sys
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

from mimicgen_pipe.core.errors import InputError, StageError
from mimicgen_pipe.core.interrupts import deferred
from mimicgen_pipe.data import outputs
from mimicgen_pipe.run import arithmetic

T = TypeVar("T")
R = TypeVar("R")

RETRIES = 3  # a block whose worker or node dies is re-run up to this many times
OBJECT_STORE_BYTES = 256 * 2**20  # of a local Ray: results of a few blocks in flight
IN_FLIGHT_PER_CPU = 2  # blocks submitted ahead, so no CPU waits for the driver
WAIT_SECONDS = 0.25  # longest wait for a result between two looks at pending signals
LOOPBACK = "127.0.0.1"  # the only interface a local Ray listens on
AUTH_MODE = "RAY_AUTH_MODE"  # Ray's switch: "token" (any case) turns token authentication on
TOKEN_PLACES = "RAY_AUTH_TOKEN, a file named by RAY_AUTH_TOKEN_PATH, or ~/.ray/auth_token"
PROBE_TIMEOUT_MS = 10_000  # a probe's wait for the cluster's GCS to answer
PROBE_SECONDS = 120  # the probe process's own limit (it imports Ray, then waits twice)

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


def cluster_address(address: str | None) -> str | None:
    """The cluster the driver connects to: ``address``, else ``RAY_ADDRESS``; None: none (a
    local Ray is started)."""
    return address or os.environ.get("RAY_ADDRESS") or None


def _named(address: str | None) -> str:
    """The setting that names the cluster, for messages."""
    if address:
        return f"ray.address {address!r}"
    return f"RAY_ADDRESS={os.environ.get('RAY_ADDRESS')!r}"


def check_settings(address: str | None) -> None:
    """Refuse, from the environment alone (nothing imported or contacted), a cluster
    connection that could not be authenticated: ``RAY_AUTH_MODE`` other than ``token``, or a
    Ray Client (``ray://``) address, whose server this driver cannot check. Nothing to check
    for a local Ray: it listens on loopback only."""
    target = cluster_address(address)
    if target is None:
        return
    mode = os.environ.get(AUTH_MODE)
    if mode is not None and mode.lower() != "token":  # Ray's own test of the switch
        raise InputError(
            f"{AUTH_MODE}={mode!r} turns Ray's token authentication off, and the cluster of "
            f"{_named(address)} is used only with it on: unset {AUTH_MODE} or set it to "
            f"'token', with the cluster's token in {TOKEN_PLACES}"
        )
    if target.startswith("ray://"):
        raise InputError(
            f"{_named(address)}: Ray Client addresses (ray://) are not supported; give the "
            "address of the cluster's GCS, host:port (port 6379 unless its head node was "
            "started with another --port)"
        )


# Run in a separate process, so that the C++ client's log lines stay out of the stage's
# output and the driver's own Ray state is untouched. Exit status: 0 the cluster refuses a
# driver without a token and accepts this one's; 10 it lets in a driver without a token;
# 11 it refuses this one's token; 12 it does not answer.
_PROBE = """
import os, sys
from ray._raylet import AuthenticationTokenLoader, Config, InnerGcsClient
from ray.exceptions import AuthenticationError

def admitted():
    try:
        InnerGcsClient.standalone(sys.argv[1], None, int(sys.argv[2]))
    except AuthenticationError:
        return False
    except Exception:
        sys.exit(12)
    return True

if admitted():
    sys.exit(10)
os.environ["RAY_AUTH_MODE"] = "token"
Config.initialize("")
AuthenticationTokenLoader.instance().reset_cache()
sys.exit(0 if admitted() else 11)
"""


def check_cluster(address: str | None) -> None:
    """Before connecting to a cluster: the checks of :func:`check_settings`, a token on this
    machine, and, asked of the cluster's GCS (which every node registers with, so a GCS with
    token authentication means a cluster with it), that it refuses a driver without a token
    and accepts this driver's. Takes about a second (10-30 s for an address where nothing
    answers)."""
    check_settings(address)
    target = cluster_address(address)
    assert target is not None
    from ray._private import services
    from ray._private.authentication.authentication_token_setup import _enable_token_auth
    from ray._raylet import AuthenticationTokenLoader

    if os.environ.get(AUTH_MODE) is None:
        # with an address given, Ray leaves token authentication off unless RAY_AUTH_MODE
        # says otherwise; the pinned release's own switch turns it on for this process
        _enable_token_auth()
    loader = AuthenticationTokenLoader.instance()
    loader.reset_cache()
    if not loader.has_token(ignore_auth_mode=True):
        raise InputError(
            f"{_named(address)}: no Ray authentication token on this machine: put the token "
            f"the cluster was started with (`ray get-auth-token` on its head node prints it) "
            f"in {TOKEN_PLACES}"
        )
    try:
        gcs = services.canonicalize_bootstrap_address(target)
    except (ConnectionError, ValueError) as err:  # "auto" with no cluster here, a bad address
        raise InputError(f"{_named(address)}: {err}") from None
    env = dict(os.environ, **{AUTH_MODE: "disabled"})  # the first try carries no token
    probe = subprocess.run(
        [sys.executable, "-c", _PROBE, gcs, str(PROBE_TIMEOUT_MS)],
        env=env,
        capture_output=True,
        timeout=PROBE_SECONDS,
    )
    problem = {
        10: "lets in a driver without a token: its token authentication is off. Start every "
        f"node's Ray (`ray start`) with {AUTH_MODE}=token and the same token in "
        f"{TOKEN_PLACES}, or use executor: local",
        11: f"refuses this machine's token (from {TOKEN_PLACES}): use the token the cluster "
        "was started with (`ray get-auth-token` on its head node prints it)",
        12: "does not answer (is the address right, the cluster up, its port open to this "
        "machine?)",
    }
    if probe.returncode != 0:
        detail = problem.get(probe.returncode)
        if detail is None:  # the probe itself failed: its own last line says why
            detail = f"could not be checked: {probe.stderr.decode().strip().splitlines()[-1:]}"
        # the address as given: Ray's form of it may be this machine's own outward one
        seen = f" (to Ray: {gcs})" if gcs != target else ""
        raise InputError(f"{_named(address)}: the Ray cluster at {target}{seen} {detail}")


def _connect(workers: int, address: str | None) -> bool:
    """Connect the driver to Ray: to the cluster at ``address`` (checked by
    :func:`check_cluster`), else to a Ray started here; True when this call connected it (to
    disconnect at the end, which stops a Ray it started here)."""
    import ray

    if ray.is_initialized():  # the caller's own connection (tests, notebooks)
        return False
    # ERROR: Ray's start-up warnings (e.g. that token authentication is on) would add lines
    # to every stage's output; a failing block still raises its error in the driver
    kwargs: dict[str, Any] = {"logging_level": logging.ERROR, "log_to_driver": False}
    if address is None:
        kwargs |= {
            # "local": a new Ray, even where `ray start` left one that ray.init would join
            "address": "local",
            "num_cpus": workers,
            "include_dashboard": False,
            "object_store_memory": OBJECT_STORE_BYTES,
            # Ray starts workers at nice 15 by default, which starves them beside any other
            # load; the local executor's workers run at normal priority, and so do these
            "_system_config": {"worker_niceness": 0},
            # every service and worker listens on this address only (no 0.0.0.0)
            "_node_ip_address": LOOPBACK,
        }
    else:
        kwargs["address"] = address
        # the cluster's workers run the driver's own code of this package and the back ends
        # (Ray ships it to every node), so that an older install there cannot change a block
        # and with the driver's arithmetic (mimicgen_pipe.run.arithmetic), not the node's own
        kwargs["runtime_env"] = {
            "py_modules": [_package_dir(p) for p in ("mimicgen_pipe",)],
            "env_vars": arithmetic.switches(),
        }
    # ray.init replaces the SIGTERM handler with one that exits at once, which during its
    # start-up would orphan the services it has started; the stage's handler stays, holding
    # the signal back (the caller defers) until Ray is up and can be shut down in order
    from ray._private import utils as ray_utils  # the pinned release's own hook

    own = ray_utils.set_sigterm_handler
    ray_utils.set_sigterm_handler = lambda handler: None
    # ray.init turns a loopback node address into this machine's outward one, unless Ray
    # runs as a single-machine instance (its default on macOS and Windows), which is what a
    # local Ray is; the flag is read only while ray.init sets the node up
    from ray._private import ray_constants

    clusters = ray_constants.ENABLE_RAY_CLUSTER
    if address is None:
        ray_constants.ENABLE_RAY_CLUSTER = False
    try:
        ray.init(**kwargs)
    finally:
        ray_utils.set_sigterm_handler = own
        ray_constants.ENABLE_RAY_CLUSTER = clusters
    # Ray's C++ core also puts a crash reporter in front of SIGTERM that prints a stack dump
    # before passing the signal on; a SIGTERM is a request to stop, not a crash, so the
    # stage's own handler is put back (the reporter stays on SIGSEGV, SIGABRT and the like)
    if (handler := signal.getsignal(signal.SIGTERM)) is not None:  # None: set outside Python
        signal.signal(signal.SIGTERM, handler)
    return True


def _stage_error(err: Exception) -> StageError:
    """One line of ours for Ray's own failure (a raylet, node or worker that died), with the
    first line of Ray's message."""
    first = (str(err).strip().splitlines() or [""])[0][:200]
    return StageError(f"Ray stopped during the stage ({type(err).__name__}: {first})")


@contextlib.contextmanager
def _ray_failures() -> Iterator[None]:
    """Around Ray's calls: a task's own exception is raised as itself, any other error of
    Ray's (from a submission, a wait, a result or the teardown) as :func:`_stage_error`.
    After such a failure the stage's output locks are let go at once, before Ray is torn
    down: nothing Ray does while it stops can leave them behind."""
    import ray

    try:
        yield
    except ray.exceptions.RayTaskError as err:  # the worker's own exception
        raise err.as_instanceof_cause() from None
    except ray.exceptions.RayError as err:
        outputs.release()
        raise _stage_error(err) from None


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
    target = None if ray.is_initialized() else cluster_address(address)
    if target is not None:
        # before any work, and outside `deferred`: the check may wait seconds on the
        # network, and a Ctrl-C meanwhile stops it at once (its probe process is killed)
        check_cluster(address)
    try:
        with deferred():
            started = _connect(workers, target)
        with _ray_failures():
            with deferred():
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
                    result = ray.get(ready[0])
                yield i, result
    finally:
        # a Ray that failed may fail again while it stops: that too is one line of ours
        with deferred(), _ray_failures():
            if started:
                ray.shutdown()  # ends this driver's job: Ray stops its unfinished tasks
            else:
                for ref in pending:
                    ray.cancel(ref)
