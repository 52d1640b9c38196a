"""Executors and resumable runs: results in order whatever order blocks finish in, finished
blocks saved and reused, the same stores from local 1/2 workers and Ray (local and a real
two-node cluster with a worker killed), and a SIGKILLed ``mimicgen-pipe generate`` that
resumes to the same store. Generation runs on PyBullet (seconds)."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from mimicgen_pipe.executors import Executor, map_blocks
from mimicgen_pipe.resume import WorkDir, code_digest, work_dir_of
from tests.conftest import cli
from tests.test_interrupts_and_outputs import alive, children, own_lines, start
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


def test_results_come_in_task_order_when_blocks_finish_out_of_order(tmp_path):
    work = WorkDir.open(tmp_path / "out.zarr", "k")
    got = list(map_blocks(_slow_first, range(6), Executor("local", 2), _noop, (), work))
    assert [x for x, _ in got] == list(range(6))
    assert len({pid for _, pid in got} - {os.getpid()}) == 2  # two worker processes ran them
    assert work.finished() == set(range(6))


def test_finished_blocks_are_reused_and_a_damaged_one_is_run_again(tmp_path):
    work = WorkDir.open(tmp_path / "out.zarr", "run-a")
    CALLS.clear()
    assert list(map_blocks(_square, range(5), Executor(), _noop, (), work)) == [0, 1, 4, 9, 16]
    assert CALLS == [0, 1, 2, 3, 4]
    block3 = work.path / "block-000003.pkl"
    block3.write_bytes(block3.read_bytes()[:-1] + b"\0")  # one byte flipped
    (work.path / "block-000001.pkl").unlink()  # never finished
    (work.path / "block-000004.pkl.tmp-123").write_bytes(b"half")  # killed while saving
    CALLS.clear()
    again = WorkDir.open(tmp_path / "out.zarr", "run-a")
    assert list(map_blocks(_square, range(5), Executor(), _noop, (), again)) == [0, 1, 4, 9, 16]
    assert CALLS == [1, 3]
    assert sorted(p.name for p in again.path.iterdir())[-1] == "key"  # temporary removed


def test_a_work_directory_of_another_run_is_discarded_not_mixed(tmp_path):
    out = tmp_path / "out.zarr"
    first = WorkDir.open(out, "params-a")
    first.save(0, "from run a")
    assert WorkDir.open(out, "params-a").finished() == {0}
    other = WorkDir.open(out, "params-b")
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


def test_a_workers_exception_reaches_the_driver():
    with pytest.raises(ZeroDivisionError):
        list(map_blocks(_divide, [1, 0], Executor("local", 2), _noop))


def _divide(x: int) -> float:
    return 1 / x


# ---- real generation on every executor ----

PARAMS = "task: stack\nbackend: pybullet\nsource: {num_demos: 3, seed: 0}\n"
ATTEMPTS = 48  # three blocks
STORES = ("stack_D0.zarr", "stack_D0_failed.zarr")


def generate(work: Path, name: str, generate_params: str, **kw) -> subprocess.CompletedProcess:
    (work / f"{name}.yaml").write_text(PARAMS + generate_params)
    return cli("generate", "--params", f"{name}.yaml", "--variant", "D0",
               "--parsed", "data/parsed/stack.zarr", "--attempts", str(ATTEMPTS),
               "--out", f"data/{name}/stack_D0.zarr", "--metrics", f"metrics/{name}.json",
               cwd=work, **kw)  # fmt: skip


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """Three parsed PyBullet source demos of stack and a reference run: local, 1 worker."""
    work = tmp_path_factory.mktemp("executors")
    (work / "params.yaml").write_text(PARAMS)
    cli("source", cwd=work)
    cli("parse", cwd=work)
    generate(work, "local1", "generate: {workers: 1, seed: 3}\n")
    return work


def same_stores(work: Path, name: str) -> None:
    for store in STORES:
        assert tree_digest(work / f"data/{name}/{store}") == tree_digest(
            work / f"data/local1/{store}"
        ), f"{name}/{store} differs from the 1-worker run's"


@pytest.mark.sim
@pytest.mark.slow
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
    while not list(blocks.glob("block-*.pkl")):
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        assert time.monotonic() - t0 < 300
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)
    assert not (work / "data/resumed/stack_D0.zarr").exists()
    saved = len(list(blocks.glob("block-*.pkl")))
    assert 1 <= saved < 3
    res = cli(*args, cwd=work)
    assert f"generate: resuming: {saved} finished blocks of attempts in " in res.stdout
    same_stores(work, "resumed")
    assert not blocks.exists()


@pytest.mark.sim
def test_changed_params_do_not_reuse_the_blocks_of_another_run(work):
    """Blocks of a killed run with seed 3 are left in the work directory; a run with seed
    4 replaces them and writes what a fresh seed-4 run writes."""
    out = work / "data/reseeded/stack_D0.zarr"
    generate(work, "fresh4", "generate: {workers: 2, seed: 4}\n")
    (work / "reseeded.yaml").write_text(PARAMS + "generate: {workers: 1, seed: 3}\n")
    blocks = work_dir_of(out)
    proc = start(work, "generate", "--params", "reseeded.yaml", "--variant", "D0", "--parsed",
                 "data/parsed/stack.zarr", "--attempts", str(ATTEMPTS), "--out", str(out),
                 "--metrics", "metrics/reseeded.json")  # fmt: skip
    t0 = time.monotonic()
    while not list(blocks.glob("block-*.pkl")):
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
def test_a_ray_cluster_losing_a_worker_still_writes_the_same_stores(work):
    """Head and second node (one CPU each) on loopback; the driver connects through
    ray.address. Once the second node runs a block, its worker process is SIGKILLed: Ray
    runs the block again and the stores equal the local 1-worker run's."""
    from ray.cluster_utils import Cluster

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


def ray_processes() -> set[int]:
    """Pids of Ray's own processes (services and workers) on this machine."""
    pids = set()
    for d in Path("/proc").iterdir():
        try:
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, ValueError):
            continue
        if cmd.startswith("ray::") or "raylet" in cmd or "gcs_server" in cmd:
            pids.add(int(d.name))
    return pids


@pytest.mark.sim
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_an_interrupted_ray_run_ends_in_one_line_and_stops_its_ray(work, sig):
    """Ctrl-C (to the process group) or SIGTERM while the local Ray it started runs blocks:
    one line, exit 128+sig, and no Ray process of its own left behind."""
    before = ray_processes()
    (work / f"ray_{sig.name}.yaml").write_text(PARAMS + "generate: {workers: 2, executor: ray}\n")
    proc = start(work, "generate", "--params", f"ray_{sig.name}.yaml", "--variant", "D0",
                 "--parsed", "data/parsed/stack.zarr", "--attempts", "400", "--out",
                 f"data/ray_{sig.name}/stack_D0.zarr", "--metrics", "metrics/r.json")  # fmt: skip
    t0 = time.monotonic()
    while not any(p not in before for p in ray_processes() if alive(p)):
        assert proc.poll() is None and time.monotonic() - t0 < 120
        time.sleep(0.1)
    time.sleep(3.0)
    if sig == signal.SIGINT:
        os.killpg(proc.pid, sig)
    else:
        os.kill(proc.pid, sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig, err[-3000:]
    lines = own_lines(err)
    assert len(lines) == 1 and "Traceback" not in err, lines
    assert lines[0].startswith(f"mimicgen-pipe generate: interrupted ({sig.name}) after ")
    time.sleep(2.0)
    assert {p for p in ray_processes() - before if alive(p)} == set()
