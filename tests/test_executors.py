"""Executors and resumable runs: results in order whatever order blocks finish in, finished
blocks saved and reused, the same stores from local 1/2 workers and Ray (local and a real
two-node cluster with a worker killed), and a SIGKILLed ``mimicgen-pipe generate`` that
resumes to the same store. Generation runs on PyBullet (seconds)."""

from __future__ import annotations

import hashlib
import os
import pickle
import re
import resource
import secrets
import shutil
import signal
import socket
import struct
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import zarr

from mimicgen_pipe.run.executors import Executor, map_blocks
from mimicgen_pipe.run.resume import WorkDir, code_digest, work_dir_of
from tests.conftest import PYBULLET_STACK, REPO, cli, stages_copied_to
from tests.test_interrupts_and_outputs import alive, children, own_lines, seconds_until_gone, start
from tests.test_store_integrity import tree_digest

# ---- map_blocks and work directories (no simulator) ----

CALLS: list[int] = []  # blocks run in this process (workers=1 runs in-process)


def _noop() -> None:
    pass


def _square(x: int) -> int:
    CALLS.append(x)
    return x * x


def _slow_first(x: int) -> tuple[int, int]:
    """Block 0 finishes last, so a pool returns the blocks out of order."""
    time.sleep(1.0 if x == 0 else 0.05)
    return x, os.getpid()


class PairCodec:
    """Block results that are ints or (int, int) pairs, as arrays."""

    def encode(self, index: int, result: int | tuple[int, int]) -> dict[str, np.ndarray]:
        return {"value": np.asarray(result, np.int64)}

    def decode(self, index: int, arrays: dict[str, np.ndarray]) -> int | tuple[int, int]:
        value = arrays["value"]
        return int(value) if value.ndim == 0 else (int(value[0]), int(value[1]))


def last_byte_of(f: Path, member: str) -> int:
    """Offset in zip file ``f`` of the last data byte of ``member`` (stored uncompressed)."""
    with zipfile.ZipFile(f) as z:
        info = z.getinfo(member)
    with f.open("rb") as fh:
        fh.seek(info.header_offset + 26)
        name_len, extra_len = struct.unpack("<HH", fh.read(4))
    return info.header_offset + 30 + name_len + extra_len + info.file_size - 1


def test_results_come_in_task_order_when_blocks_finish_out_of_order(tmp_path):
    work = WorkDir.open(tmp_path / "out.zarr", "k", PairCodec())
    got = list(map_blocks(_slow_first, range(6), Executor("local", 2), _noop, (), work))
    assert [x for x, _ in got] == list(range(6))
    assert len({pid for _, pid in got} - {os.getpid()}) == 2  # two worker processes ran them
    assert work.finished() == set(range(6))


def test_finished_blocks_are_reused_and_a_damaged_one_is_run_again(tmp_path):
    work = WorkDir.open(tmp_path / "out.zarr", "run-a", PairCodec())
    CALLS.clear()
    assert list(map_blocks(_square, range(6), Executor(), _noop, (), work)) == [0, 1, 4, 9, 16, 25]
    assert CALLS == [0, 1, 2, 3, 4, 5]
    block3 = work.path / "block-000003.npz"
    at = last_byte_of(block3, "result/value.npy")  # of the value 9, under the zip's CRC
    data = block3.read_bytes()
    block3.write_bytes(data[:at] + bytes([data[at] ^ 1]) + data[at + 1 :])
    block5 = work.path / "block-000005.npz"
    block5.write_bytes(block5.read_bytes()[:-1])  # cut short
    (work.path / "block-000001.npz").unlink()  # never finished
    (work.path / "block-000004.npz.tmp-123").write_bytes(b"half")  # killed while saving
    CALLS.clear()
    again = WorkDir.open(tmp_path / "out.zarr", "run-a", PairCodec())
    assert again.resumed == {0, 2, 4}
    assert [line.split(": ")[0] for line in again.discarded] == [
        str(again.path / "block-000003.npz"),
        str(again.path / "block-000005.npz"),
    ]  # the damaged blocks are reported; a temporary is what a kill leaves, and is not
    assert list(map_blocks(_square, range(6), Executor(), _noop, (), again)) == [0, 1, 4, 9, 16, 25]
    assert CALLS == [1, 3, 5]
    assert "block-000004.npz.tmp-123" not in {p.name for p in again.path.iterdir()}


def test_a_work_directory_of_another_run_is_discarded_not_mixed(tmp_path):
    out = tmp_path / "out.zarr"
    first = WorkDir.open(out, "params-a", PairCodec())
    first.save(0, 7)
    assert WorkDir.open(out, "params-a", PairCodec()).finished() == {0}
    other = WorkDir.open(out, "params-b", PairCodec())
    assert other.path == first.path == work_dir_of(out)
    assert other.finished() == set()
    assert (other.path / "key").read_text() == "params-b"


def test_the_code_digest_follows_the_source(tmp_path, monkeypatch):
    pkg = tmp_path / "pkg_under_test"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("X = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    before = code_digest("pkg_under_test")
    (pkg / "a.py").write_text("X = 2\n")
    assert code_digest("pkg_under_test") != before
    (pkg / "shaders").mkdir()  # a camera's shader makes its pictures as the Python does
    (pkg / "shaders" / "gbuffer.frag").write_text("void main() {}\n")
    with_shader = code_digest("pkg_under_test")
    assert with_shader != before
    (pkg / "shaders" / "gbuffer.frag").write_text("void main() { }\n")
    edited = code_digest("pkg_under_test")
    assert edited != with_shader
    (pkg / "notes.txt").write_text("not code\n")
    assert code_digest("pkg_under_test") == edited


def test_a_workers_exception_reaches_the_driver():
    with pytest.raises(ZeroDivisionError) as raised:
        list(map_blocks(_divide, [1, 0], Executor("local", 2), _noop))
    assert "in _divide" in str(raised.value.__cause__)  # the worker's traceback, as text


def _kill_self_on_three(x: int) -> int:
    if x == 3:
        os.kill(os.getpid(), signal.SIGKILL)  # as the kernel's OOM killer would
    return x


def test_a_worker_that_dies_is_an_error_naming_it_not_a_wait():
    from mimicgen_pipe.run.executors.local import WorkerDied

    with pytest.raises(WorkerDied, match=r"exit code -9 while running a block"):
        list(map_blocks(_kill_self_on_three, range(8), Executor("local", 2), _noop))


def _failing_init() -> None:
    raise FileNotFoundError("no scene here")


def test_an_initializer_that_raises_is_raised_once_not_retried():
    t0 = time.monotonic()
    with pytest.raises(FileNotFoundError, match="no scene here"):
        list(map_blocks(_square, range(8), Executor("local", 2), _failing_init))
    assert time.monotonic() - t0 < 60


def _divide(x: int) -> float:
    return 1 / x


def _pid_then_sleep(x: int) -> int:
    time.sleep(0.2)
    return os.getpid()


def test_closing_the_iterator_early_leaves_no_worker():
    """The local pool's promise: close its iterator and the workers are gone when that
    returns (here the parent lives on, so nothing but the teardown can end them)."""
    from mimicgen_pipe.run.executors import local

    results = local.imap_unordered(_pid_then_sleep, enumerate(range(20)), 2, _noop)
    pids = {next(results)[1] for _ in range(4)}
    results.close()
    assert pids and not [p for p in pids if alive(p)]


# ---- real generation on every executor ----

PARAMS = PYBULLET_STACK
ATTEMPTS = 48  # three blocks
STORES = ("stack_D0.zarr", "stack_D0_failed.zarr")


def generate(work: Path, name: str, generate_params: str, **kw) -> subprocess.CompletedProcess:
    (work / f"{name}.yaml").write_text(PARAMS + generate_params)
    return cli("generate", "--params", f"{name}.yaml", "--variant", "D0",
               "--parsed", "data/parsed/stack.zarr", "--attempts", str(ATTEMPTS),
               "--out", f"data/{name}/stack_D0.zarr", "--metrics", f"metrics/{name}.json",
               cwd=work, **kw)  # fmt: skip


@pytest.fixture(scope="module")
def work(tmp_path_factory, pybullet_stack) -> Path:
    """Three parsed PyBullet source demos of stack."""
    work = stages_copied_to(tmp_path_factory.mktemp("executors"), pybullet_stack)
    (work / "params.yaml").write_text(PARAMS)
    return work


@pytest.fixture(scope="module")
def reference(work: Path) -> None:
    """The run that same_stores compares with, in ``work``: local, 1 worker. Made only for
    the tests that compare (all slow), not for every test that needs the parsed demos."""
    generate(work, "local1", "generate: {workers: 1, seed: 3}\n")


def same_stores(work: Path, name: str) -> None:
    for store in STORES:
        assert tree_digest(work / f"data/{name}/{store}") == tree_digest(
            work / f"data/local1/{store}"
        ), f"{name}/{store} differs from the 1-worker run's"


@pytest.mark.sim
@pytest.mark.slow
@pytest.mark.usefixtures("reference")
def test_local_two_workers_and_ray_write_the_same_stores(work):
    """Also with numpy's BLAS told to use one thread (as Ray workers are: OMP_NUM_THREADS=1)
    where the reference run had the machine's default, its core count."""
    generate(work, "local2", "generate: {workers: 2, seed: 3}\n")
    same_stores(work, "local2")
    generate(work, "blas1", "generate: {workers: 2, seed: 3}\n", env={"OPENBLAS_NUM_THREADS": "1"})
    same_stores(work, "blas1")
    res = generate(work, "ray2", "generate: {workers: 2, seed: 3, executor: ray}\n")
    same_stores(work, "ray2")
    assert "Traceback" not in res.stderr
    assert not work_dir_of(work / "data/ray2/stack_D0.zarr").exists()  # removed when done


@pytest.mark.sim
@pytest.mark.slow  # about 1 min (2 on a loaded machine); the default run keeps under 20 min
@pytest.mark.usefixtures("reference")
def test_a_killed_run_resumes_from_its_finished_blocks(work):
    """SIGKILL a real generate once a block is saved; the same command again reuses the
    saved blocks, runs only the rest, and writes the uninterrupted run's stores."""
    (work / "resumed.yaml").write_text(PARAMS + "generate: {workers: 2, seed: 3}\n")
    args = ["generate", "--params", "resumed.yaml", "--variant", "D0", "--parsed",
            "data/parsed/stack.zarr", "--attempts", str(ATTEMPTS), "--out",
            "data/resumed/stack_D0.zarr", "--metrics", "metrics/resumed.json"]  # fmt: skip
    blocks = work_dir_of(work / "data/resumed/stack_D0.zarr")
    proc = start(work, *args)
    t0 = time.monotonic()
    while not list(blocks.glob("block-*.npz")):
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        assert time.monotonic() - t0 < 300
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)
    assert not (work / "data/resumed/stack_D0.zarr").exists()
    saved = len(list(blocks.glob("block-*.npz")))
    assert 1 <= saved < 3
    res = cli(*args, cwd=work)
    assert f"generate: resuming: {saved} finished blocks of attempts in " in res.stdout
    same_stores(work, "resumed")
    assert not blocks.exists()


NOTICES = ("; discarded, its block is run again", "; removed unread")


class Plant:
    """Unpickling this runs a shell command (what a planted block would do)."""

    def __init__(self, command: str) -> None:
        self.command = command

    def __reduce__(self) -> tuple:
        return (os.system, (self.command,))


def kill_after_first_block(work: Path, args: list[str], blocks: Path) -> None:
    proc = start(work, *args)
    t0 = time.monotonic()
    while not (blocks / "block-000000.npz").exists():
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        assert time.monotonic() - t0 < 300
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)


@pytest.mark.sim
@pytest.mark.slow
@pytest.mark.usefixtures("reference")
def test_planted_and_copied_blocks_are_discarded_never_unpickled(work, tmp_path):
    """(Its small form, block files read without unpickling, is in
    tests/test_resume_blocks.py.) In the work directory of a killed run (its key file right):
    a block file of the previous format (SHA-256 + pickle) and an .npz holding a pickled
    object array, both crafted to run a command when unpickled, a pickle named like a block,
    and block 0 copied over block 1. The same command resumes: nothing runs, each file is
    reported and discarded, and the stores equal the uninterrupted run's."""
    (work / "planted.yaml").write_text(PARAMS + "generate: {workers: 1, seed: 3}\n")
    args = ["generate", "--params", "planted.yaml", "--variant", "D0", "--parsed",
            "data/parsed/stack.zarr", "--attempts", str(ATTEMPTS), "--out",
            "data/planted/stack_D0.zarr", "--metrics", "metrics/planted.json"]  # fmt: skip
    blocks = work_dir_of(work / "data/planted/stack_D0.zarr")
    kill_after_first_block(work, args, blocks)
    marker = tmp_path / "ran"
    payload = pickle.dumps(Plant(f"touch {marker}"))
    pickle.loads(payload)  # the plant is live: unpickling it runs the command
    assert marker.exists()
    marker.unlink()
    (blocks / "block-000002.pkl").write_bytes(hashlib.sha256(payload).digest() + payload)
    (blocks / "block-000003.npz").write_bytes(payload)
    with zipfile.ZipFile(blocks / "block-000000.npz") as z:
        arrays = {n[:-4]: np.load(z.open(n), allow_pickle=False) for n in z.namelist()}
    arrays["index"] = np.int64(2)
    arrays["result/seed"] = np.array([Plant(f"touch {marker}")], dtype=object)
    np.savez(blocks / "block-000002.npz", **arrays)  # savez pickles the object array
    shutil.copyfile(blocks / "block-000000.npz", blocks / "block-000001.npz")

    res = cli(*args, cwd=work)
    assert not marker.exists()
    assert "generate: resuming: 1 finished blocks of attempts in " in res.stdout
    discarded = [ln for ln in res.stdout.splitlines() if ln.endswith(NOTICES)]
    assert sorted(Path(ln.split(": ")[1]).name for ln in discarded) == [
        "block-000001.npz",
        "block-000002.npz",
        "block-000002.pkl",
        "block-000003.npz",
    ], res.stdout
    assert any("block-000001.npz: holds block 0, not 1; discarded" in ln for ln in discarded)
    assert any("block-000002.pkl: not a block file; removed unread" in ln for ln in discarded)
    same_stores(work, "planted")
    seeds = zarr.open(str(work / "data/planted/stack_D0.zarr"), mode="r")["meta/episodes/seed"][:]
    assert len(set(seeds.tolist())) == len(seeds)


@pytest.mark.sim
def test_a_block_that_cannot_be_written_stops_the_run_in_one_line(work):
    """A file size limit (RLIMIT_FSIZE: EFBIG, as a full disk gives ENOSPC) met saving the
    first block: exit 2, one line naming the block file and the free space, no temporary
    left."""
    (work / "limited.yaml").write_text(PARAMS + "generate: {workers: 1, seed: 3}\n")
    out = work / "data/limited/stack_D0.zarr"
    res = subprocess.run(
        [sys.executable, "-m", "mimicgen_pipe.cli", "generate", "--params", "limited.yaml",
         "--variant", "D0", "--parsed", "data/parsed/stack.zarr", "--attempts", "2",
         "--out", str(out), "--metrics", "metrics/limited.json"],
        cwd=work, capture_output=True, text=True,
        env=dict(os.environ, PYTHONPATH=str(REPO), PYTHONWARNINGS="ignore"),
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (8192, 8192)),
    )  # fmt: skip
    assert res.returncode == 2, res.stderr[-3000:]
    lines = own_lines(res.stderr)
    block = work_dir_of(out) / "block-000000.npz"
    assert len(lines) == 1 and lines[0].startswith(
        f"mimicgen-pipe generate: error: {block}: could not be written (File too large); "
    ), lines
    assert " MB free there; the blocks saved before are kept" in lines[0]
    assert [p.name for p in work_dir_of(out).iterdir()] == ["key"]
    assert not out.exists()


@pytest.mark.sim
@pytest.mark.slow
def test_changed_params_do_not_reuse_the_blocks_of_another_run(work):
    """Blocks of a killed run with seed 3 are left in the work directory; a run with seed
    4 replaces them and writes what a fresh seed-4 run writes. (Its small form, a block of
    another run's key discarded, is in tests/test_resume_blocks.py.)"""
    out = work / "data/reseeded/stack_D0.zarr"
    generate(work, "fresh4", "generate: {workers: 2, seed: 4}\n")
    (work / "reseeded.yaml").write_text(PARAMS + "generate: {workers: 1, seed: 3}\n")
    blocks = work_dir_of(out)
    proc = start(work, "generate", "--params", "reseeded.yaml", "--variant", "D0", "--parsed",
                 "data/parsed/stack.zarr", "--attempts", str(ATTEMPTS), "--out", str(out),
                 "--metrics", "metrics/reseeded.json")  # fmt: skip
    t0 = time.monotonic()
    while not list(blocks.glob("block-*.npz")):
        assert proc.poll() is None and time.monotonic() - t0 < 300
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)
    res = generate(work, "reseeded", "generate: {workers: 2, seed: 4}\n")
    assert "resuming" not in res.stdout
    for store in STORES:
        assert tree_digest(work / f"data/reseeded/{store}") == tree_digest(
            work / f"data/fresh4/{store}"
        )


# ---- a real two-node Ray cluster, one worker killed mid-run ----


def ray_workers_of(raylet_pid: int) -> list[int]:
    """Ray worker processes a raylet started that are running one of our blocks."""
    return [p for p, cmd in children(raylet_pid).items() if cmd.startswith("ray::_run")]


@pytest.mark.sim
@pytest.mark.slow
@pytest.mark.usefixtures("reference")
def test_a_ray_cluster_losing_a_worker_still_writes_the_same_stores(work, monkeypatch):
    """Head and second node (one CPU each) with token authentication on, as the driver
    requires; the driver connects through ray.address with the cluster's token. Once the
    second node runs a block, its worker process is SIGKILLed: Ray runs the block again and
    the stores equal the local 1-worker run's."""
    from ray._raylet import Config
    from ray.cluster_utils import Cluster

    # the nodes (started from here), this process's own client and the driver: one token
    monkeypatch.setenv("RAY_AUTH_MODE", "token")
    monkeypatch.setenv("RAY_AUTH_TOKEN", secrets.token_hex(16))
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    Config.initialize("")  # Ray reads RAY_AUTH_MODE once per process: again now
    cluster = Cluster(
        initialize_head=True,
        head_node_args={"num_cpus": 1, "object_store_memory": 100 * 2**20,
                        "include_dashboard": False},
    )  # fmt: skip
    try:
        node = cluster.add_node(num_cpus=1, object_store_memory=100 * 2**20)
        cluster.wait_for_nodes()
        raylet = node.all_processes["raylet"][0].process.pid
        (work / "cluster.yaml").write_text(
            PARAMS + "generate: {workers: 1, seed: 3, executor: ray}\n"
            f"ray: {{address: '{cluster.address}'}}\n"
        )
        proc = start(work, "generate", "--params", "cluster.yaml", "--variant", "D0",
                     "--parsed", "data/parsed/stack.zarr", "--attempts", str(ATTEMPTS),
                     "--out", "data/cluster/stack_D0.zarr", "--metrics",
                     "metrics/cluster.json")  # fmt: skip
        t0 = time.monotonic()
        while not (victims := ray_workers_of(raylet)):
            assert proc.poll() is None, proc.communicate()[1][-3000:]
            assert time.monotonic() - t0 < 300, "the second node ran no block"
            time.sleep(0.05)
        time.sleep(0.5)  # inside the block
        os.kill(victims[0], signal.SIGKILL)
        _, err = proc.communicate(timeout=600)
        assert not alive(victims[0])
        assert proc.returncode == 0, err[-3000:]
        assert "Traceback" not in err, own_lines(err)
        same_stores(work, "cluster")
    finally:
        cluster.shutdown()


@pytest.mark.sim
def test_a_ray_cluster_without_token_authentication_is_refused_in_one_line(work):
    """RAY_AUTH_MODE=disabled with ray.address: a real ``mimicgen-pipe generate`` stops with
    one line naming the setting, exit 2, without connecting and writing no store."""
    listener = socket.create_server(("127.0.0.1", 0))  # the "cluster": records connections
    listener.setblocking(False)
    address = f"127.0.0.1:{listener.getsockname()[1]}"
    (work / "noauth.yaml").write_text(
        PARAMS + f"generate: {{workers: 1, executor: ray}}\nray: {{address: '{address}'}}\n"
    )
    res = cli("generate", "--params", "noauth.yaml", "--variant", "D0",
              "--parsed", "data/parsed/stack.zarr", "--attempts", "16",
              "--out", "data/noauth/stack_D0.zarr", "--metrics", "metrics/noauth.json",
              cwd=work, check=False, env={"RAY_AUTH_MODE": "disabled"})  # fmt: skip
    assert res.returncode == 2, res.stderr[-3000:]
    assert own_lines(res.stderr) == [
        "mimicgen-pipe generate: error: RAY_AUTH_MODE='disabled' turns Ray's token "
        f"authentication off, and the cluster of ray.address {address!r} is used only with it "
        "on: unset RAY_AUTH_MODE or set it to 'token', with the cluster's token in "
        "RAY_AUTH_TOKEN, a file named by RAY_AUTH_TOKEN_PATH, or ~/.ray/auth_token"
    ]
    with pytest.raises(BlockingIOError):  # nobody connected
        listener.accept()
    listener.close()
    assert not (work / "data/noauth/stack_D0.zarr").exists()
    assert not work_dir_of(work / "data/noauth/stack_D0.zarr").exists()  # no work started
    assert not (work / "metrics/noauth.json").exists()


def ray_processes(tag: str, running_blocks: bool = False) -> set[int]:
    """Pids of the Ray processes (services and workers) whose environment holds ``tag``
    (``NAME=value``: Ray's services inherit the environment of the run that starts them, and
    its workers theirs), so that another test's Ray is not counted; with ``running_blocks``,
    only workers running a block (Ray titles them after the function)."""
    pids = set()
    for d in Path("/proc").iterdir():
        try:
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            if tag.encode() not in (d / "environ").read_bytes().split(b"\0"):
                continue
        except (OSError, ValueError):
            continue
        if running_blocks:
            if cmd.startswith("ray::_run"):
                pids.add(int(d.name))
        elif cmd.startswith("ray::") or "raylet" in cmd or "gcs_server" in cmd:
            pids.add(int(d.name))
    return pids


# a log line of Ray's C++ core: "[2026-12-06 20:35:15,964 E 7864 8070] task_manager.cc:1545: ..."
RAY_CORE_LOG = re.compile(r"^\[\d{4}-\d\d-\d\d [\d:,]+ [DIWEF] \d+ \d+\] \w+\.cc:\d+: ")


@pytest.mark.sim
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_an_interrupted_ray_run_ends_in_one_line_and_stops_its_ray(work, sig):
    """Ctrl-C (to the process group) or SIGTERM while the local Ray it started runs blocks:
    one line, exit 128+sig, and no Ray process of its own left behind."""
    run = {"MIMICGEN_PIPE_TEST_RUN": secrets.token_hex(8)}  # marks this run's Ray processes
    tag = "=".join(*run.items())
    (work / f"ray_{sig.name}.yaml").write_text(PARAMS + "generate: {workers: 2, executor: ray}\n")
    proc = start(work, "generate", "--params", f"ray_{sig.name}.yaml", "--variant", "D0",
                 "--parsed", "data/parsed/stack.zarr", "--attempts", "400", "--out",
                 f"data/ray_{sig.name}/stack_D0.zarr", "--metrics", "metrics/r.json",
                 env=run)  # fmt: skip
    # a block running means ray.init has returned: until then Ray's crash reporter stands in
    # front of SIGTERM and prints a stack dump (the stage puts its own handler back after it)
    t0 = time.monotonic()
    while not any(alive(p) for p in ray_processes(tag, running_blocks=True)):
        assert proc.poll() is None and time.monotonic() - t0 < 120
        time.sleep(0.1)
    time.sleep(1.0)
    if sig == signal.SIGINT:
        os.killpg(proc.pid, sig)
    else:
        os.kill(proc.pid, sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig, err[-3000:]
    # Ray's C++ core may log a line of its own while it stops (a task's error it could not
    # hand to the driver that is leaving, seen on a loaded machine): ours is the one line
    # beside those, and the last
    lines = [ln for ln in own_lines(err) if not RAY_CORE_LOG.match(ln)]
    assert len(lines) == 1 and "Traceback" not in err, lines
    assert lines[0].startswith(f"mimicgen-pipe generate: interrupted ({sig.name}) after ")
    assert own_lines(err)[-1] == lines[0]
    # Ray's processes take a moment to exit after the run has, longer on a loaded machine
    left = ray_processes(tag)
    assert seconds_until_gone(left, timeout=60.0) < 60.0, sorted(left)
    assert {p for p in ray_processes(tag) if alive(p)} == set()
