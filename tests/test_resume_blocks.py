"""Generation blocks in a work directory (mimicgen_pipe.run.resume with runner's codec): plain
arrays that rebuild a block's results exactly, accepted only as the block they hold, a
write that fails leaving nothing behind; and seeds and blocks made on demand, so that a
run allowing millions of attempts holds none of them up front. No simulator."""

from __future__ import annotations

import errno
import itertools
import shutil
import time
import tracemalloc
import zipfile
from collections.abc import Sequence

import numpy as np
import pytest

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.method.generation import Attempt
from mimicgen_pipe.run.executors import Executor, map_blocks
from mimicgen_pipe.run.resume import WorkDir
from mimicgen_pipe.run.runner import (
    ATTEMPTS_PER_BLOCK,
    AttemptBlockCodec,
    AttemptSeeds,
    attempt_blocks,
    attempt_seed,
)

N_ATTEMPTS = 40  # two full blocks and a short one


def fake_attempt(seed: int, k: int) -> Attempt:
    """An attempt with the kinds of arrays run_attempt records, k steps (0: stopped at IK
    before its first step, so no steps at all)."""
    rng = np.random.default_rng(seed)
    steps: dict[str, np.ndarray] = {}
    if k:
        # not in sorted order, with the names StepRecorder gives
        steps["actions"] = rng.standard_normal((k, 7)).astype(np.float32)
        steps["eef_pose"] = rng.standard_normal((k, 4, 4))
        steps["env_state"] = rng.standard_normal((k, 31)).astype(np.float32)
        steps["object_poses/cube_b"] = rng.standard_normal((k, 4, 4))
        steps["subtask_signals/grasp"] = rng.random(k) > 0.5
        steps["obs/eef_pos"] = rng.standard_normal((k, 3))
        steps["gripper"] = steps["actions"][:, -1].astype(np.float32)
    return Attempt(
        seed=seed,
        steps=steps,
        success=bool(k % 2),
        failed_subtask=-1 if k % 2 else int(k % 3),
        ik_failed=k == 0,
        source_demo=np.array([k % 3, 2], np.int64),
        initial_state=rng.standard_normal(31).astype(np.float32),
        initial_object_poses=rng.standard_normal((2, 4, 4)),
    )


def fake_block(seeds: list[int]) -> list[tuple[int, Attempt, float]]:
    return [(s, fake_attempt(s, k % 5), 0.25 * k + 1e-9) for k, s in enumerate(seeds)]


def same(a: object, b: object) -> None:
    """Equal in value, type, dtype, shape and dict key order."""
    assert type(a) is type(b), (type(a), type(b))
    if isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b), (a, b)
    elif isinstance(a, dict):
        assert list(a) == list(b)
        for key in a:
            same(a[key], b[key])
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            same(x, y)
    elif isinstance(a, Attempt):
        for name in Attempt.__dataclass_fields__:
            same(getattr(a, name), getattr(b, name))
    else:
        assert a == b, (a, b)


@pytest.fixture
def seeds() -> AttemptSeeds:
    return AttemptSeeds(3, "D0", N_ATTEMPTS)


def open_work(tmp_path, seeds: Sequence[int], key: str = "run-a") -> WorkDir:
    return WorkDir.open(tmp_path / "out.zarr", key, AttemptBlockCodec(seeds))


def test_a_saved_block_reads_back_exactly(tmp_path, seeds):
    work = open_work(tmp_path, seeds)
    blocks = attempt_blocks(seeds)
    results = [fake_block(b) for b in blocks]
    for i, result in enumerate(results):
        work.save(i, result)
    again = open_work(tmp_path, seeds)
    assert again.resumed == {0, 1, 2} and again.discarded == ()
    for i, result in enumerate(results):
        same(again.load(i), result)
    assert len(results[2]) == N_ATTEMPTS - 2 * ATTEMPTS_PER_BLOCK
    # nothing in a block file is a pickle: every member loads with pickling refused
    with zipfile.ZipFile(work.path / "block-000001.npz") as z:
        for name in z.namelist():
            assert np.load(z.open(name), allow_pickle=False).dtype != object


def test_a_block_copied_over_another_or_from_another_run_is_discarded(tmp_path, seeds):
    work = open_work(tmp_path, seeds)
    for i, block in enumerate(attempt_blocks(seeds)):
        work.save(i, fake_block(block))
    shutil.copyfile(work.path / "block-000000.npz", work.path / "block-000001.npz")
    # block 0 of the same seeds in another run (e.g. other action noise): its key differs
    other = WorkDir.open(tmp_path / "other.zarr", "run-b", AttemptBlockCodec(seeds))
    other.save(0, fake_block(attempt_blocks(seeds)[0]))
    shutil.copyfile(other.path / "block-000000.npz", work.path / "block-000000.npz")
    # block 2 of the seeds of another stage seed, its key forged to this run's: the seeds
    # give it away
    reseeded = AttemptSeeds(4, "D0", N_ATTEMPTS)
    forged = WorkDir.open(tmp_path / "f.zarr", "run-a", AttemptBlockCodec(reseeded))
    forged.save(2, fake_block(attempt_blocks(reseeded)[2]))
    shutil.copyfile(forged.path / "block-000002.npz", work.path / "block-000002.npz")
    (work.path / "block-000007.npz").write_bytes((work.path / "block-000001.npz").read_bytes())
    again = open_work(tmp_path, seeds)
    assert again.resumed == set()
    why = {line.split(": ")[0].rsplit("/", 1)[1]: line for line in again.discarded}
    assert sorted(why) == [f"block-00000{i}.npz" for i in (0, 1, 2, 7)]
    assert "a block of another run" in why["block-000000.npz"]
    assert "holds block 0, not 1" in why["block-000001.npz"]
    assert "holds other seeds than block 2's" in why["block-000002.npz"]
    assert "holds block 0, not 7" in why["block-000007.npz"]
    assert sorted(p.name for p in again.path.iterdir()) == ["key"]


def test_a_file_that_is_not_a_block_is_removed_unread(tmp_path, seeds):
    work = open_work(tmp_path, seeds)
    work.save(0, fake_block(attempt_blocks(seeds)[0]))
    (work.path / "block-000001.pkl").write_bytes(b"\x80\x05anything")
    (work.path / "block-000002.npz").write_bytes(b"\x80\x05not a zip")
    (work.path / "block-000003.npz").symlink_to(work.path / "block-000000.npz")
    again = open_work(tmp_path, seeds)
    assert again.resumed == {0}
    why = {line.split(": ")[0].rsplit("/", 1)[1]: line for line in again.discarded}
    assert "not a block file" in why["block-000001.pkl"]
    assert "unreadable (File is not a zip file)" in why["block-000002.npz"]
    assert "not a regular file" in why["block-000003.npz"]
    assert sorted(p.name for p in again.path.iterdir()) == ["block-000000.npz", "key"]


def test_a_full_disk_while_saving_removes_the_temporary_and_says_so(tmp_path, seeds, monkeypatch):
    work = open_work(tmp_path, seeds)
    real = np.lib.format.write_array
    written = itertools.count()

    def fill_up(fp, array, **kw):  # the third array no longer fits
        if next(written) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        real(fp, array, **kw)

    monkeypatch.setattr(np.lib.format, "write_array", fill_up)
    with pytest.raises(InputError) as err:
        work.save(1, fake_block(attempt_blocks(seeds)[1]))
    msg = str(err.value)
    assert msg.startswith(f"{work.path / 'block-000001.npz'}: could not be written (No space ")
    shown = float(msg.split("); ")[1].split(" MB free there; ")[0])
    assert abs(shown - shutil.disk_usage(work.path).free / 2**20) < 256  # others write too
    assert msg.endswith(
        "; the blocks saved before are kept, and the same command resumes from them"
    )
    assert "\n" not in msg
    assert sorted(p.name for p in work.path.iterdir()) == ["key"]


def test_seeds_and_blocks_are_the_eager_ones():
    eager = [attempt_seed(3, "D1", i) for i in range(N_ATTEMPTS)]
    lazy = AttemptSeeds(3, "D1", N_ATTEMPTS)
    assert len(lazy) == N_ATTEMPTS and list(lazy) == eager
    assert lazy[0] == eager[0] and lazy[-1] == eager[-1] and lazy[17] == eager[17]
    for cut in (slice(None, 8), slice(5, 29, 3), slice(-7, None), slice(100, 200)):
        assert lazy[cut] == eager[cut]
    with pytest.raises(IndexError):
        lazy[N_ATTEMPTS]
    blocks = attempt_blocks(lazy)
    eager_blocks = [eager[i : i + ATTEMPTS_PER_BLOCK] for i in range(0, N_ATTEMPTS, 16)]
    assert len(blocks) == 3 and list(blocks) == eager_blocks and blocks[-1] == eager_blocks[-1]
    assert attempt_blocks(eager)[1] == eager_blocks[1]
    with pytest.raises(IndexError):
        blocks[3]


def test_ten_million_attempts_hold_no_seed_up_front():
    """generate.max_attempts at its maximum: the seeds, the blocks and the first blocks of
    map_blocks cost the same as for a short run (an eager list took minutes and GBs)."""
    tracemalloc.start()
    t0 = time.perf_counter()
    seeds = AttemptSeeds(0, "D0", 10_000_000)
    blocks = attempt_blocks(seeds)
    assert len(blocks) == 625_000 and blocks[-1] == seeds[-ATTEMPTS_PER_BLOCK:]
    got = map_blocks(len, blocks, Executor(), _noop)
    assert list(itertools.islice(got, 3)) == [ATTEMPTS_PER_BLOCK] * 3
    got.close()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert time.perf_counter() - t0 < 5.0
    assert peak < 2 * 2**20, peak


class Counted(Sequence[int]):
    """A long sequence of tasks that counts the ones read."""

    def __init__(self, n: int) -> None:
        self.n, self.read = n, 0

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> int:  # type: ignore[override]
        self.read += 1
        assert self.read < 100_000, "tasks read far ahead of the results taken"
        return i


def _noop() -> None:
    pass


def _double(x: int) -> int:
    return 2 * x


@pytest.mark.parametrize("workers", [1, 2])
def test_map_blocks_reads_tasks_as_they_are_run(workers):
    tasks = Counted(10**12)
    got = map_blocks(_double, tasks, Executor("local", workers), _noop)
    assert list(itertools.islice(got, 5)) == [0, 2, 4, 6, 8]
    got.close()
    assert tasks.read < 100_000


def test_a_work_directory_that_is_a_link_is_replaced_not_followed(tmp_path, seeds):
    """A link where the work directory goes, to a folder holding a matching key file: the
    link is removed and nothing in the folder it points to is touched."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "key").write_text("run-a")
    (elsewhere / "notes.txt").write_text("keep me")
    (tmp_path / ".out.zarr.work").symlink_to(elsewhere)
    work = open_work(tmp_path, seeds)
    assert not work.path.is_symlink() and work.path.is_dir() and work.resumed == set()
    assert sorted(p.name for p in elsewhere.iterdir()) == ["key", "notes.txt"]
    (work.path / "key").write_bytes(b"\xff\xfe not text")  # another run's key, or garbage
    assert open_work(tmp_path, seeds).path.joinpath("key").read_text() == "run-a"
