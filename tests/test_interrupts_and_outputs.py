"""Stopping a stage and trusting what it left: Ctrl-C/SIGTERM/SIGKILL of a real
``mimicgen-pipe generate`` with worker processes, one writer per output set, stale
temporaries, run ids that readers check. Generation runs on PyBullet (seconds)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zarr

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data.metrics import write_metrics
from mimicgen_pipe.data.outputs import check_same_run, claim, lock_file, release, run_id
from mimicgen_pipe.data.params import Params, data_params
from tests.conftest import PYBULLET_STACK, REPO, cli, stages_copied_to

PARAMS = PYBULLET_STACK
GENERATE = ["generate", "--variant", "D0", "--parsed", "data/parsed/stack.zarr"]


@pytest.fixture(scope="module")
def work(tmp_path_factory, pybullet_stack) -> Path:
    """Three PyBullet source demos of stack, parsed."""
    work = stages_copied_to(tmp_path_factory.mktemp("interrupts"), pybullet_stack)
    (work / "params.yaml").write_text(PARAMS + "generate: {workers: 1, seed: 3}\n")
    (work / "two.yaml").write_text(PARAMS + "generate: {workers: 2, seed: 3}\n")
    return work


def start(work: Path, *args: str, env: dict[str, str] | None = None) -> subprocess.Popen:
    """``mimicgen-pipe`` in its own process group (a terminal's Ctrl-C signals a group), with
    ``env`` added to the environment."""
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONWARNINGS="ignore", **(env or {}))
    return subprocess.Popen(
        [sys.executable, "-m", "mimicgen_pipe.cli", *args],
        cwd=work,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )


def children(pid: int) -> dict[int, str]:
    """Live child processes of ``pid`` (from /proc): pid -> command line."""
    out = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text().rsplit(")", 1)[1].split()
            if int(stat[1]) == pid and stat[0] != "Z":
                out[int(d.name)] = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, ValueError, IndexError):
            continue
    return out


def alive(pid: int) -> bool:
    try:
        return (Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]) != "Z"
    except OSError:
        return False


def wait_for_workers(proc: subprocess.Popen, n: int, timeout: float = 90.0) -> dict[int, str]:
    """The pool's worker processes once all ``n`` run, with every other child (the resource
    tracker)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        kids = children(proc.pid)
        if sum("spawn_main" in c for c in kids.values()) == n:
            return kids
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        time.sleep(0.1)
    proc.kill()
    raise AssertionError(f"no {n} workers after {timeout} s")


def seconds_until_gone(pids, timeout: float = 10.0) -> float:
    t0 = time.monotonic()
    while any(alive(p) for p in pids):
        if time.monotonic() - t0 > timeout:
            return float("inf")
        time.sleep(0.02)
    return time.monotonic() - t0


def own_lines(stderr: str) -> list[str]:
    """stderr without progress bars and the simulator's banner."""
    lines = [ln.split("\r")[-1].strip() for ln in stderr.splitlines()]
    return [ln for ln in lines if ln and "|" not in ln and not ln.startswith("pybullet build")]


@pytest.mark.sim
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_interrupt_stops_generate_with_one_line(work, sig):
    """Ctrl-C (SIGINT to the whole process group, as a terminal sends it) or SIGTERM (to the
    main process only, as a scheduler sends it) while two workers generate: exit 128+sig,
    one line saying what was interrupted, no traceback or BrokenPipe from workers, no worker
    left once the stage has exited, nothing at --out."""
    out = f"data/int_{sig.name}/stack_D0.zarr"
    proc = start(work, *GENERATE, "--params", "two.yaml", "--attempts", "400", "--out", out,
                 "--metrics", f"metrics/int_{sig.name}.json")  # fmt: skip
    kids = wait_for_workers(proc, 2)
    time.sleep(1.5)  # the workers are running attempts
    t0 = time.monotonic()
    if sig == signal.SIGINT:
        os.killpg(proc.pid, sig)
    else:
        os.kill(proc.pid, sig)
    _, err = proc.communicate(timeout=60)
    exit_seconds = time.monotonic() - t0
    workers = [p for p, c in kids.items() if "spawn_main" in c]
    assert proc.returncode == 128 + sig, err[-3000:]
    # The stage joins its workers before it exits: none may outlive it. The time bound only
    # tells a stop from a run that went on (the 400 attempts take minutes); how fast a loaded
    # machine tears a pool down is not this test's business.
    assert not [p for p in workers if alive(p)], f"workers outlived the stage ({sig.name})"
    assert exit_seconds < 30.0, f"the stage took {exit_seconds:.1f} s to stop"
    assert seconds_until_gone(kids) < 10.0  # the resource tracker follows its parent
    assert "Traceback" not in err and "Error" not in err, err[-3000:]
    lines = own_lines(err)
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"mimicgen-pipe generate: interrupted ({sig.name}) after ")
    assert lines[0].endswith(
        f" of 400 attempts; finished blocks kept in data/int_{sig.name}/.stack_D0.zarr.work "
        "(the same command resumes); nothing written"
    )
    folder = work / out.rsplit("/", 1)[0]
    # no store, no temporary, no lock file: only the finished blocks, for a re-run to resume
    assert [p.name for p in folder.iterdir()] == [".stack_D0.zarr.work"]
    assert not (work / f"metrics/int_{sig.name}.json").exists()


@pytest.mark.sim
def test_workers_die_with_a_killed_main_process(work):
    """SIGKILL cannot be caught: the workers notice their parent is gone and exit."""
    args = ["--out", "data/killed/stack_D0.zarr", "--metrics", "metrics/killed.json"]
    proc = start(work, *GENERATE, "--params", "two.yaml", "--attempts", "400", *args)
    kids = wait_for_workers(proc, 2)
    time.sleep(1.0)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)
    gone = seconds_until_gone([p for p, c in kids.items() if "spawn_main" in c])
    # the kernel kills them at once (PR_SET_PDEATHSIG); 10 s tells that from a worker left
    # running its attempts
    assert gone < 10.0, f"workers alive {gone:.1f} s after the main process was killed"
    assert not (work / "data/killed/stack_D0.zarr").exists()


@pytest.mark.sim
def test_one_writer_per_output_set_and_stale_temporaries_removed(work):
    """While another process holds the lock of one output (here this test, through the
    library's own claim: no race between two runs), a generate on the same --out stops
    (exit 2, one line naming the path and the holder's pid) before any attempt; once it is
    let go, a run completes, removes what killed runs left beside its outputs (and nothing
    else), and its kept store, failed store and metrics carry one run id."""
    gen = work / "data/locked"
    args = ["--out", "data/locked/stack_D0.zarr", "--metrics", "metrics/locked.json"]
    claim(gen / "stack_D0.zarr")  # held by this process until released below
    try:
        # the temporaries killed runs left (after claiming: claim removes them too)
        (gen / ".stack_D0.zarr.tmp-abc").mkdir()
        (gen / ".stack_D0.zarr.tmp-abc" / "zarr.json").write_text("{}")
        (gen / "..stack_D0_failed.zarr.tmp-1-a.tmp-2-b").mkdir()  # a nested writer's
        (gen / ".stack_D0.zarr.old-1-c").mkdir()
        (gen / ".other.zarr.tmp-abc").mkdir()  # another output's: not ours to remove
        (work / "metrics").mkdir(exist_ok=True)
        (work / "metrics/.locked.json.tmp-1-d").write_text("{")
        second = cli(*GENERATE, "--attempts", "4", *args, cwd=work, check=False)
        assert lock_file(gen / "stack_D0.zarr").is_file(), "the holder's lock stays"
    finally:
        release([lock_file(gen / "stack_D0.zarr")])
    # refused before any attempt of its own: no progress bar
    assert second.returncode == 2, second.stderr[-3000:]
    assert not any("|" in ln for ln in second.stderr.splitlines()), second.stderr[-3000:]
    lines = own_lines(second.stderr)
    assert len(lines) == 1 and "Traceback" not in second.stderr, second.stderr[-3000:]
    assert lines[0].startswith("mimicgen-pipe generate: error: data/locked/stack_D0.zarr: ")
    assert f"another mimicgen-pipe run (pid {os.getpid()}) is writing this output" in lines[0]
    first = cli(*GENERATE, "--attempts", "16", *args, cwd=work, check=False)
    assert first.returncode == 0, first.stderr[-3000:]
    assert any("|" in ln for ln in first.stderr.splitlines()), "a run that generates shows its bar"
    assert sorted(p.name for p in gen.iterdir()) == [
        ".other.zarr.tmp-abc",
        "stack_D0.zarr",
        "stack_D0_failed.zarr",
    ]
    assert [p.name for p in (work / "metrics").glob(".locked*")] == []
    metrics = json.loads((work / "metrics/locked.json").read_text())
    assert metrics["attempts"] == 16
    kept = zarr.open_group(str(gen / "stack_D0.zarr"), mode="r").attrs["run_id"]
    failed = zarr.open_group(str(gen / "stack_D0_failed.zarr"), mode="r").attrs["run_id"]
    assert kept == failed == metrics["run_id"] and len(kept) == 16


@pytest.fixture(scope="module")
def generated(work) -> Path:
    """A small generated pair (kept + failed) with its metrics."""
    cli(*GENERATE, "--attempts", "8", "--out", "data/gen/stack_D0.zarr",
        "--metrics", "metrics/generate_stack_D0.json", cwd=work)  # fmt: skip
    return work


COVERAGE = ["coverage", "--variant", "D0", "--metrics", "metrics/coverage_stack_D0.json",
            "--table", "plots/c.csv", "--heatmap", "plots/c.png"]  # fmt: skip


@pytest.mark.sim
def test_coverage_refuses_kept_and_failed_stores_of_different_runs(generated):
    work = generated
    res = cli(*COVERAGE, "--generated", "data/gen/stack_D0.zarr", cwd=work)
    gen_metrics = json.loads((work / "metrics/generate_stack_D0.json").read_text())
    cov_metrics = json.loads((work / "metrics/coverage_stack_D0.json").read_text())
    assert cov_metrics["run_id"] == gen_metrics["run_id"], res.stdout
    # the kept store beside the failed store of another run (as a killed re-run could leave)
    mixed = work / "data/mixed"
    shutil.copytree(work / "data/gen", mixed)
    other = mixed / "stack_D0_failed.zarr"
    zarr.open_group(str(other), mode="r+").attrs["run_id"] = "0123456789abcdef"
    res = cli(*COVERAGE, "--generated", "data/mixed/stack_D0.zarr", cwd=work, check=False)
    assert res.returncode == 2, res.stderr[-3000:]
    lines = own_lines(res.stderr)
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr[-3000:]
    assert "outputs of different generate runs" in lines[0]
    assert "data/mixed/stack_D0_failed.zarr has run id '0123456789abcdef'" in lines[0]
    assert f"data/mixed/stack_D0.zarr has run id '{gen_metrics['run_id']}'" in lines[0]


def test_run_id_depends_on_data_shaping_params_and_input_only():
    """Same data-shaping params and input -> same id (so stores stay byte-identical for any
    worker count); another param or another input -> another id."""
    from dataclasses import replace

    p = Params()

    def rid(params: Params, digest: str = "in") -> str:
        return run_id({"task": params.task, **data_params(params, "generate")}, digest)

    assert rid(p) == rid(replace(p, generate=replace(p.generate, workers=7)))
    assert rid(p) != rid(replace(p, generate=replace(p.generate, action_noise=0.0)))
    assert rid(p) != rid(p, "other input")
    check_same_run({"a": rid(p), "b": rid(p)})
    with pytest.raises(InputError, match="outputs of different generate runs"):
        check_same_run({"a": rid(p), "b": None})


def test_concurrent_metrics_writers_do_not_collide(tmp_path):
    """Writers of one metrics file use their own temporary names: none fails, the file is
    always whole, and no temporary stays behind."""
    path = tmp_path / "m.json"
    errors: list[BaseException] = []

    def writer(k: int) -> None:
        try:
            for i in range(100):
                write_metrics(path, {"writer": k, "i": i, "x": list(range(200))})
        except BaseException as exc:  # noqa: BLE001 - collected for the assertion
            errors.append(exc)

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert json.loads(path.read_text())["i"] == 99
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json"]


def test_claim_is_exclusive_between_processes(tmp_path):
    """The lock is held by the process (flock): another process cannot claim the output, and
    can once this one lets go; no lock file stays behind."""
    out = tmp_path / "x.zarr"
    code = (
        "import sys\nfrom mimicgen_pipe.data.outputs import claim\n"
        "from mimicgen_pipe.core.errors import InputError\n"
        "try:\n    claim(sys.argv[1])\nexcept InputError as e:\n    print(e); sys.exit(2)"
    )
    env = dict(os.environ, PYTHONPATH=str(REPO))

    def other() -> subprocess.CompletedProcess:
        cmd = [sys.executable, "-c", code, str(out)]
        return subprocess.run(cmd, env=env, capture_output=True, text=True)

    claim(out)
    try:
        res = other()
        assert res.returncode == 2 and f"(pid {os.getpid()}) is writing" in res.stdout
    finally:
        release([lock_file(out)])
    assert other().returncode == 0
    assert list(tmp_path.iterdir()) == []


def test_a_helper_child_dies_with_its_parent_even_on_sigkill(tmp_path):
    """A motion planner's child process (interrupts.die_with_parent) ends when the stage
    that started it is killed with SIGKILL, which runs none of the stage's own cleanup."""
    child = (
        "from mimicgen_pipe.core.interrupts import die_with_parent; die_with_parent(); "
        "import time; time.sleep(120)"
    )
    parent = (
        "import subprocess, sys, time; "
        "from mimicgen_pipe.core.interrupts import child_environment; "
        f"p = subprocess.Popen([sys.executable, '-c', {child!r}], env=child_environment()); "
        "print(p.pid, flush=True); time.sleep(120)"
    )
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen([sys.executable, "-c", parent], stdout=subprocess.PIPE, env=env,
                            text=True)  # fmt: skip
    pid = int(proc.stdout.readline())
    proc.kill()
    proc.wait()
    deadline = time.monotonic() + 60  # generous: the kernel signals at once
    while time.monotonic() < deadline and _alive(pid):
        time.sleep(0.2)
    assert not _alive(pid), "the child outlived its parent"


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, reaped by init soon, counts as gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1][0] != "Z"
    except (FileNotFoundError, IndexError):
        return False
