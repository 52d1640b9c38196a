"""Output paths that cannot hurt and output sets that are all old or all new: what a stage may
replace, outputs against inputs, the failed store's name, kills at every step of a commit
(real ``mimicgen-pipe generate`` processes on PyBullet), full and read-only disks."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest
import zarr

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data import outputs
from mimicgen_pipe.data.layout import failed_store
from mimicgen_pipe.data.metrics import IDENTITY_FIELDS, write_metrics
from mimicgen_pipe.data.outputs import claim, release, store_kind
from mimicgen_pipe.data.store import write_store
from tests.conftest import PYBULLET_STACK, cli, stages_copied_to
from tests.test_interrupts_and_outputs import own_lines

PARAMS = PYBULLET_STACK
PARAMS += "generate: {workers: 1, seed: 3}\n"
GENERATE = ["generate", "--variant", "D0", "--parsed", "data/parsed/stack.zarr"]


def tree_digest(path: Path) -> str:
    """sha256 over every file's relative path and bytes under ``path`` (or of one file)."""
    h = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for f in files:
        h.update(str(f.relative_to(path.parent)).encode() + b"\0" + f.read_bytes())
    return h.hexdigest()


def user_files(folder: Path) -> Path:
    """A folder of somebody's files."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "notes.txt").write_text("mine")
    (folder / "sub").mkdir(exist_ok=True)
    (folder / "sub/data.bin").write_bytes(b"\1\2")
    return folder


def small_store(path: Path, kind: str = "generated", value: float = 0.0) -> Path:
    steps = [{"actions": np.full((3, 7), value, np.float32)}]
    return write_store(path, kind, steps, {"seed": np.array([1])}, {"task": "t"})


@pytest.fixture(autouse=True)
def _release_claims():
    yield
    release()


# --- what may be replaced --------------------------------------------------------------------


def test_claim_refuses_a_directory_or_file_that_is_not_an_output_of_its_kind(tmp_path):
    folder = user_files(tmp_path / "metrics.json")
    before = tree_digest(folder)
    with pytest.raises(InputError, match=r"metrics\.json: is not a file; expected a metrics"):
        claim(folder)
    text = tmp_path / "list.json"
    text.write_text("[1, 2]")
    with pytest.raises(InputError, match=r"list\.json: is JSON but not an object"):
        claim(text)
    cwd_like = user_files(tmp_path / "here")
    with pytest.raises(InputError, match=r"here: is not a Zarr store; expected a parsed store"):
        claim((cwd_like, store_kind("parsed")))
    png = tmp_path / "p.png"
    png.write_text("text")
    with pytest.raises(InputError, match="is not a PNG image"):
        claim(png)
    assert tree_digest(folder) == before and (cwd_like / "sub/data.bin").read_bytes() == b"\1\2"
    assert not list(tmp_path.glob(".*.lock")), "a refused claim leaves no lock behind"


def test_claim_accepts_absent_paths_and_outputs_of_their_kind(tmp_path):
    store = small_store(tmp_path / "s.zarr", "parsed")
    write_metrics(tmp_path / "m.json", {"a": 1})
    claim((store, store_kind("parsed")), tmp_path / "m.json", tmp_path / "new/x.csv")
    release()
    with pytest.raises(InputError, match="a store of kind 'parsed', not 'generated'"):
        claim((store, store_kind("generated")))


def test_outputs_are_checked_against_inputs_and_each_other(tmp_path):
    src = small_store(tmp_path / "S.zarr", "source")
    with pytest.raises(InputError, match=r"S\.zarr: the same place as the input .*S\.zarr"):
        claim((src, store_kind("source")), inputs=[src])
    link = tmp_path / "link.zarr"
    link.symlink_to(src)  # resolved before the check
    with pytest.raises(InputError, match="the same place as the input"):
        claim((link, store_kind("source")), inputs=[src])
    with pytest.raises(InputError, match="the same place as the input"):  # holds the input
        claim((tmp_path, outputs.directory_kind("any directory", ".*")), inputs=[src])
    with pytest.raises(InputError, match="the same place as the input"):  # inside the input
        claim(src / "data/x.zarr", inputs=[src])
    with pytest.raises(InputError, match=r"b\.json: the same place as the output .*a\.json"):
        (tmp_path / "a.json").symlink_to(tmp_path / "b.json")
        claim(tmp_path / "a.json", tmp_path / "b.json")
    assert (src / "zarr.json").is_file()


@pytest.mark.parametrize(
    ("kept", "failed"),
    [
        ("d/x_D0.zarr", "d/x_D0_failed.zarr"),
        ("d/mystore", "d/mystore_failed"),
        ("d/a.zarr.zarr", "d/a.zarr_failed.zarr"),
    ],  # fmt: skip
)
def test_failed_store_name_never_equals_the_kept_one(kept, failed):
    assert failed_store(Path(kept)) == Path(failed) != Path(kept)


def test_a_symlink_output_is_replaced_and_its_target_left_alone(tmp_path):
    target = small_store(tmp_path / "real.zarr", value=1.0)
    before = tree_digest(target)
    link = tmp_path / "out.zarr"
    link.symlink_to(target)
    claim(link)
    small_store(link, value=2.0)
    assert not link.is_symlink() and link.is_dir()
    assert zarr.open_array(str(link / "data/actions"))[0, 0] == 2.0
    assert tree_digest(target) == before


# --- all old or all new ----------------------------------------------------------------------


def _commit_in_child(tmp_path: Path, kill_at: int | None, value: float) -> int:
    """A child process commits a new (kept dir, failed dir, metrics) set over the old one,
    SIGKILLed before the kill_at-th filesystem operation of the commit."""
    code = f"""
import numpy as np
from pathlib import Path
from mimicgen_pipe.data.outputs import claim, output_set
from mimicgen_pipe.data.metrics import write_metrics
from tests.test_output_safety import small_store
d = Path({str(tmp_path)!r})
claim(d / "k.zarr", d / "f.zarr", d / "m.json")
with output_set(d / "f.zarr", d / "m.json", d / "k.zarr") as (f, m, k):
    small_store(k, "generated", {value}); small_store(f, "failed", {value})
    write_metrics(m, {{"v": {value}}})
"""
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).parents[1]))
    if kill_at is not None:
        env[outputs.KILL_AT_ENV] = str(kill_at)
    return subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path).returncode


def complete_commit(*paths: Path) -> None:
    """What the stage that writes ``paths`` does first when it runs again: claim them, which
    completes a commit a killed run left journaled (readers refuse such a set)."""
    claim(*paths)
    release()


def _set_values(d: Path) -> tuple[float, float, float]:
    complete_commit(d / "k.zarr", d / "f.zarr", d / "m.json")
    return (
        float(zarr.open_array(str(d / "k.zarr/data/actions"))[0, 0]),
        float(zarr.open_array(str(d / "f.zarr/data/actions"))[0, 0]),
        float(json.loads((d / "m.json").read_text())["v"]),
    )


def test_a_kill_at_every_step_of_a_commit_leaves_all_old_or_all_new(tmp_path):
    """The commit's filesystem operations counted on a full run; then a run killed before
    each of them, over an old set: its stage run again finds the old set or the new one,
    whole."""
    seen = set()
    for kill_at in range(1, 40):
        d = tmp_path / f"k{kill_at}"
        d.mkdir()
        assert _commit_in_child(d, None, 1.0) == 0
        rc = _commit_in_child(d, kill_at, 2.0)
        values = _set_values(d)
        assert values in ((1.0, 1.0, 1.0), (2.0, 2.0, 2.0)), (kill_at, values)
        seen.add(values[0])
        left = sorted(p.name for p in d.iterdir() if p.name.startswith("."))
        assert not [n for n in left if n.endswith(".commit")], left
        if rc == 0:  # the run got past its last operation: every step was tried
            break
        assert rc == -9, rc
        # the next run removes what the killed one left (its temporaries)
        assert _commit_in_child(d, None, 3.0) == 0 and _set_values(d) == (3.0, 3.0, 3.0)
        assert sorted(p.name for p in d.iterdir()) == ["f.zarr", "k.zarr", "m.json"]
    else:
        raise AssertionError("the commit never completed")
    assert kill_at > 10 and seen == {1.0, 2.0}, (kill_at, seen)


# --- full and read-only disks ----------------------------------------------------------------


@pytest.fixture
def small_disk(tmp_path):
    """A 4 MB tmpfs (needs root; skipped otherwise)."""
    where = tmp_path / "disk"
    where.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(where)],
                         capture_output=True)  # fmt: skip
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {res.stderr.decode().strip()}")
    yield where
    subprocess.run(["umount", "-l", str(where)], check=False)


def fill(disk: Path, leave: int) -> None:
    free = shutil.disk_usage(disk).free
    (disk / f"filler-{uuid.uuid4().hex[:6]}").write_bytes(b"\0" * max(0, free - leave))


def test_a_full_disk_is_one_error_and_the_old_output_stays(small_disk):
    old = small_store(small_disk / "s.zarr", value=1.0)
    before = tree_digest(old)
    fill(small_disk, 20_000)
    big = [{"actions": np.random.default_rng(0).random((20_000, 7))}]  # ~1 MB, incompressible
    with pytest.raises(InputError, match=r"s\.zarr: no space left on the device .* MB free"):
        write_store(old, "generated", big, {"seed": np.array([1])}, {"task": "t"})
    assert tree_digest(old) == before
    assert sorted(p.name for p in small_disk.iterdir() if p.name.startswith(".")) == []


def test_a_read_only_output_directory_is_one_error(small_disk):
    subprocess.run(["mount", "-o", "remount,ro", str(small_disk)], check=True)
    with pytest.raises(InputError, match=r"cannot write in .*disk \(Read-only file system\)"):
        claim(small_disk / "m.json")


# --- real stages ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def work(tmp_path_factory, pybullet_stack) -> Path:
    """Three PyBullet source demos of stack, parsed, and a small generated set."""
    work = stages_copied_to(tmp_path_factory.mktemp("safety"), pybullet_stack)
    (work / "params.yaml").write_text(PARAMS)
    return work


def one_line_error(res: subprocess.CompletedProcess, *needles: str) -> str:
    assert res.returncode == 2, res.stderr[-3000:]
    lines = own_lines(res.stderr)
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr[-3000:]
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


def test_stages_refuse_outputs_that_would_destroy_data(work):
    user_files(work / "mine")
    (work / "mine.json").mkdir()
    (work / "mine.json/keep.txt").write_text("keep")
    before = tree_digest(work / "data/parsed/stack.zarr"), tree_digest(work / "mine")
    cases = [
        (["parse", "--source", "data/source/stack.zarr", "--out", "data/source/stack.zarr"],
         "data/source/stack.zarr: the same place as the input"),
        ([*GENERATE, "--out", "data/parsed/stack.zarr"], "the same place as the input"),
        (["pose_noise", "--out", "."], ".: the same place as the input"),
        (["pose_noise", "--out", "mine"], "mine: is not a Zarr store"),
        ([*GENERATE, "--attempts", "2", "--metrics", "mine.json"], "mine.json: is not a file"),
        ([*GENERATE, "--attempts", "2", "--out", "mine/notes.txt"], "is not a Zarr store"),
    ]  # fmt: skip
    for args, needle in cases:
        one_line_error(cli(*args, cwd=work, check=False), needle)
    assert (tree_digest(work / "data/parsed/stack.zarr"), tree_digest(work / "mine")) == before
    assert (work / "mine.json/keep.txt").read_text() == "keep"
    assert (work / "params.yaml").is_file()


def test_generate_without_zarr_suffix_keeps_kept_and_failed_apart(work):
    cli(*GENERATE, "--attempts", "6", "--out", "data/plain/mystore", "--metrics",
        "metrics/plain.json", cwd=work)  # fmt: skip
    metrics = json.loads((work / "metrics/plain.json").read_text())
    kept = zarr.open_group(str(work / "data/plain/mystore"), mode="r")
    failed = zarr.open_group(str(work / "data/plain/mystore_failed"), mode="r")
    assert kept.attrs["kind"] == "generated" and failed.attrs["kind"] == "failed"
    assert kept["meta/episode_ends"].shape[0] == metrics["successes"]
    assert failed["meta/episode_ends"].shape[0] == metrics["attempts"] - metrics["successes"]
    # the run's times apart, in timings/ (not an output: written after the commit)
    timings = json.loads((work / "timings/plain.json").read_text())
    assert "wall_seconds" not in metrics and timings["run_id"] == metrics["run_id"]
    assert timings.keys() == {*IDENTITY_FIELDS, "run_id", "wall_seconds", "cpu",
                              "seconds_per_attempt_mean", "seconds_per_attempt_median"}  # fmt: skip


def _generate(work: Path, out: str, attempts: int, kill_at: int | None = None) -> int:
    args = [*GENERATE, "--attempts", str(attempts), "--out", f"{out}/s.zarr",
            "--metrics", f"{out}/m.json"]  # fmt: skip
    env = {outputs.KILL_AT_ENV: str(kill_at)} if kill_at else {}
    return cli(*args, cwd=work, check=False, env=env).returncode


def _run_ids(d: Path) -> tuple[str, str, str]:
    """Run ids of kept, failed and metrics, once generate has claimed them again (which
    completes a commit a killed run left journaled)."""
    complete_commit(d / "s.zarr", d / "s_failed.zarr", d / "m.json")
    return (
        zarr.open_group(str(d / "s.zarr"), mode="r").attrs["run_id"],
        zarr.open_group(str(d / "s_failed.zarr"), mode="r").attrs["run_id"],
        json.loads((d / "m.json").read_text())["run_id"],
    )


def _kill_generate_during_commit(work: Path, steps: list[int]) -> None:
    """An old set (4 attempts), then for each step a run of 5 attempts over a copy of it,
    SIGKILLed before that filesystem operation of its commit."""
    assert _generate(work, "data/old", 4) == 0
    old = _run_ids(work / "data/old")
    assert len(set(old)) == 1
    seen = set()
    for kill_at in steps:
        out = f"data/kill{kill_at}"
        shutil.copytree(work / "data/old", work / out)
        rc = _generate(work, out, 5, kill_at)
        ids = _run_ids(work / out)
        assert len(set(ids)) == 1, (kill_at, ids)
        seen.add(ids[0])
        if rc == 0:  # past the commit's last operation
            break
        assert rc == -9, rc
    assert old[0] in seen and len(seen) == 2, seen
    # a coverage run reads the set the killed run left, as any later stage would
    res = cli("coverage", "--variant", "D0", "--generated", f"{out}/s.zarr", "--metrics",
              f"{out}/c.json", "--table", f"{out}/c.csv", "--heatmap", f"{out}/c.png",
              cwd=work)  # fmt: skip
    assert json.loads((work / out / "c.json").read_text())["run_id"] == ids[0], res.stdout


@pytest.mark.sim
def test_generate_killed_during_its_commit_leaves_one_whole_set(work):
    """Three of the commit's 13 steps: in the journals, between moving the old kept store
    aside and moving the new one in, and while removing the old stores; then past the end."""
    _kill_generate_during_commit(work, [2, 9, 11, 99])


@pytest.mark.slow
def test_generate_killed_at_every_step_of_its_commit(work):
    _kill_generate_during_commit(work, list(range(1, 40)))


@pytest.mark.sim
def test_export_to_a_nearly_full_disk_is_one_error(work, small_disk):
    cli(*GENERATE, "--attempts", "6", "--out", "data/ex/s.zarr", "--metrics", "metrics/ex.json",
        cwd=work)  # fmt: skip
    (small_disk / "out").mkdir()
    fill(small_disk, 30_000)
    res = cli("export", "--store", "data/ex/s.zarr", "--formats", "robomimic", "--out",
              str(small_disk / "out/x"), "--metrics", str(small_disk / "m.json"), cwd=work,
              check=False)  # fmt: skip
    one_line_error(res, "out/x: not enough free space on the device", "needed")
    assert sorted(p.name for p in (small_disk / "out").iterdir()) == []
