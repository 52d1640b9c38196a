"""Ray on purpose: a local Ray started by the ``ray`` executor listens on the loopback
interface only, and a cluster is used only with Ray's token authentication on, which the
driver checks (refusing with one line) before it connects. Linux only (reads /proc)."""

from __future__ import annotations

import ipaddress
import json
import os
import secrets
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.run.executors import Executor
from mimicgen_pipe.run.executors import ray as ray_executor
from tests.conftest import REPO

pytestmark = pytest.mark.skipif(
    not Path("/proc/net/tcp").exists(), reason="needs Linux's /proc/net/tcp"
)

TOKEN_PLACES = "RAY_AUTH_TOKEN, a file named by RAY_AUTH_TOKEN_PATH, or ~/.ray/auth_token"


# ---- listening sockets of a process tree, from /proc (no tool needed) ----


def process_tree(root: int) -> set[int]:
    """``root`` and all its descendants."""
    children: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(d.name))
    tree, todo = set(), [root]
    while todo:
        pid = todo.pop()
        tree.add(pid)
        todo += children.get(pid, [])
    return tree


def _listening() -> dict[int, tuple[str, int]]:
    """Socket inode -> (address, port) of every listening TCP socket (IPv4 and IPv6)."""
    found = {}
    for table, family in (("tcp", socket.AF_INET), ("tcp6", socket.AF_INET6)):
        path = Path("/proc/net") / table
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            fields = line.split()
            if fields[3] != "0A":  # TCP_LISTEN
                continue
            addr, port = fields[1].split(":")
            raw = bytes.fromhex(addr)  # 32-bit words in host (little-endian) order
            raw = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
            found[int(fields[9])] = (socket.inet_ntop(family, raw), int(port, 16))
    return found


def listening_sockets(pids: set[int]) -> list[tuple[str, str, int]]:
    """(process name, address, port) of each listening TCP socket the processes hold."""
    listening = _listening()
    found = set()
    for pid in pids:
        try:
            name = (Path("/proc") / str(pid) / "cmdline").read_bytes().split(b"\0")[0].decode()
            fds = list((Path("/proc") / str(pid) / "fd").iterdir())
        except OSError:  # gone meanwhile
            continue
        for fd in fds:
            try:
                target = os.readlink(fd)
            except OSError:
                continue
            if target.startswith("socket:[") and int(target[8:-1]) in listening:
                found.add((Path(name).name or name, *listening[int(target[8:-1])]))
    return sorted(found)


def is_loopback(address: str) -> bool:
    ip = ipaddress.ip_address(address)
    mapped = getattr(ip, "ipv4_mapped", None)  # ::ffff:127.0.0.1 on a dual-stack socket
    return ip.is_loopback or (mapped is not None and mapped.is_loopback)


# ---- a local Ray: loopback only ----

# In a process of its own: starts a local Ray through the executor, takes the first result
# (Ray is up, a worker has run a block) and prints the listening sockets of its process tree
LOCAL_RAY = """
import json, os
from mimicgen_pipe.run.executors import Executor, map_blocks
from tests.test_ray_security import listening_sockets, process_tree

blocks = map_blocks(abs, [-1, -2, -3], Executor("ray", 1), int)
assert next(blocks) == 1
print(json.dumps(listening_sockets(process_tree(os.getpid()))))
blocks.close()
"""


def test_a_local_ray_listens_on_loopback_only():
    """Every listening socket of the driver, GCS, raylet (node manager and object manager),
    agents and workers of a Ray the executor starts is on 127.0.0.1, none on 0.0.0.0 or ::.
    Token authentication is not what is tested here: it is turned off."""
    env = dict(os.environ, PYTHONPATH=str(REPO), RAY_AUTH_MODE="disabled")
    env.pop("RAY_ADDRESS", None)
    res = subprocess.run(
        [sys.executable, "-c", LOCAL_RAY], env=env, capture_output=True, text=True, timeout=300
    )
    assert res.returncode == 0, res.stderr[-3000:]
    sockets = json.loads(res.stdout.splitlines()[-1])
    names = {name for name, _, _ in sockets}
    # the check sees Ray's services and a worker, not just the driver
    assert "gcs_server" in names and "raylet" in names, sockets
    assert any(n.startswith("ray::") for n in names), sockets
    assert [s for s in sockets if not is_loopback(s[1])] == [], sockets


# ---- a cluster: token authentication on, or refused before connecting ----


@pytest.fixture
def listener():
    """A TCP port on loopback that records whether anyone connected (nothing should)."""
    server = socket.create_server(("127.0.0.1", 0))
    server.setblocking(False)
    yield server
    server.close()


def nobody_connected(server: socket.socket) -> bool:
    try:
        server.accept()[0].close()
    except BlockingIOError:
        return True
    return False


@pytest.mark.parametrize("mode", ["disabled", "DISABLED", "", "k8s"])
def test_a_cluster_with_token_authentication_off_is_refused_before_connecting(
    monkeypatch, listener, mode
):
    address = f"127.0.0.1:{listener.getsockname()[1]}"
    monkeypatch.setenv("RAY_AUTH_MODE", mode)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    with pytest.raises(InputError) as err:
        Executor("ray", 2, address)  # as a stage makes it, before any work
    assert str(err.value) == (
        f"RAY_AUTH_MODE={mode!r} turns Ray's token authentication off, and the cluster of "
        f"ray.address {address!r} is used only with it on: unset RAY_AUTH_MODE or set it to "
        f"'token', with the cluster's token in {TOKEN_PLACES}"
    )
    monkeypatch.setenv("RAY_ADDRESS", address)  # the address from the environment instead
    with pytest.raises(InputError, match=rf"the cluster of RAY_ADDRESS={address!r} is used"):
        Executor("ray", 2)
    # the executor checks again where it connects
    blocks = ray_executor.imap_unordered(abs, [(0, -1)], 1, int, (), address)
    with pytest.raises(InputError, match="^RAY_AUTH_MODE="):
        next(blocks)
    assert nobody_connected(listener)


def test_a_local_ray_is_allowed_with_token_authentication_off(monkeypatch):
    """It listens on loopback only: Executor accepts it (nothing started here)."""
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    assert Executor("ray", 2).address is None


def test_a_ray_client_address_is_refused(monkeypatch):
    monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
    with pytest.raises(InputError) as err:
        Executor("ray", 1, "ray://head:10001")
    assert str(err.value) == (
        "ray.address 'ray://head:10001': Ray Client addresses (ray://) are not supported; "
        "give the address of the cluster's GCS, host:port (port 6379 unless its head node "
        "was started with another --port)"
    )


def test_a_cluster_without_a_token_here_is_refused_before_connecting(
    monkeypatch, listener, tmp_path
):
    for name in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH", "RAY_ADDRESS"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/.ray/auth_token
    address = f"127.0.0.1:{listener.getsockname()[1]}"
    with pytest.raises(InputError) as err:
        ray_executor.check_cluster(address)
    assert str(err.value) == (
        f"ray.address {address!r}: no Ray authentication token on this machine: put the "
        "token the cluster was started with (`ray get-auth-token` on its head node prints "
        f"it) in {TOKEN_PLACES}"
    )
    assert nobody_connected(listener)


# A Ray head on loopback, started in a process of its own by the executor's own code; prints
# its GCS address, then waits for stdin to close
HEAD = """
import sys
import ray
from mimicgen_pipe.run.executors.ray import _connect

_connect(1, None)
print(ray._private.worker._global_node.gcs_address, flush=True)
sys.stdin.read()
ray.shutdown()
"""


def start_head(auth: str, token: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(REPO), RAY_AUTH_MODE=auth, RAY_AUTH_TOKEN=token)
    env.pop("RAY_ADDRESS", None)
    return subprocess.Popen(
        [sys.executable, "-c", HEAD],
        env=env,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )


@pytest.mark.slow
def test_the_driver_asks_the_cluster_whether_it_checks_tokens(monkeypatch):
    """Two real heads (on loopback): one with token authentication off is refused, one with
    it on is refused with a wrong token and accepted with its own."""
    from ray._private import ray_constants

    token = secrets.token_hex(16)
    heads = {"off": start_head("disabled", token), "on": start_head("token", token)}
    try:
        gcs = {k: p.stdout.readline().strip() for k, p in heads.items()}
        assert all(gcs.values()), gcs
        # the heads listen on loopback; Ray, as on a single machine, keeps 127.0.0.1 as given
        monkeypatch.setattr(ray_constants, "ENABLE_RAY_CLUSTER", False)
        monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
        monkeypatch.delenv("RAY_ADDRESS", raising=False)
        monkeypatch.setenv("RAY_AUTH_TOKEN", token)
        t0 = time.monotonic()
        with pytest.raises(InputError) as err:
            ray_executor.check_cluster(gcs["off"])
        assert str(err.value) == (
            f"ray.address {gcs['off']!r}: the Ray cluster at {gcs['off']} lets in a driver "
            "without a token: its token authentication is off. Start every node's Ray "
            f"(`ray start`) with RAY_AUTH_MODE=token and the same token in {TOKEN_PLACES}, or "
            "use executor: local"
        )
        ray_executor.check_cluster(gcs["on"])  # its own token: no error
        monkeypatch.setenv("RAY_AUTH_TOKEN", secrets.token_hex(16))
        with pytest.raises(InputError, match=r"refuses this machine's token \(from RAY_AUTH_"):
            ray_executor.check_cluster(gcs["on"])
        assert time.monotonic() - t0 < 30  # three checks, each a second or so
    finally:
        for p in heads.values():
            p.communicate(timeout=60)  # closes stdin: the head stops its Ray


@pytest.mark.slow
def test_an_address_where_nothing_answers_is_named_as_given(monkeypatch):
    with socket.socket() as s:  # a loopback port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"127.0.0.1:{port}"
    monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
    monkeypatch.setenv("RAY_AUTH_TOKEN", secrets.token_hex(16))
    monkeypatch.setenv("RAY_ADDRESS", address)
    with pytest.raises(InputError) as err:
        ray_executor.check_cluster(None)
    message = str(err.value)
    assert message.startswith(f"RAY_ADDRESS={address!r}: the Ray cluster at {address}")
    assert message.endswith("does not answer (is the address right, the cluster up, its port "
                            "open to this machine?)")  # fmt: skip
