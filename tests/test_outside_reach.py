"""Nothing beside an input or an output reaches outside its folder: a planted commit journal
beside an input store, a lock file that is a symbolic link, an output path through a link
into a pipeline's tracked results, and a Ray that dies under a stage (its locks released)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from mimicgen_pipe.core.errors import InputError, StageError
from mimicgen_pipe.data import outputs
from mimicgen_pipe.data.outputs import claim, journal_of, lock_file, release, store_kind
from mimicgen_pipe.data.store import open_store, read_store, write_store
from tests.test_output_safety import tree_digest, user_files


@pytest.fixture(autouse=True)
def _release_claims():
    yield
    release()


def source_store(path: Path) -> Path:
    steps = [{"actions": np.zeros((3, 7), np.float32)}]
    return write_store(path, "source", steps, {"seed": np.array([1])}, {"task": "t"})


def plant_journal(store: Path, entries: list[tuple[Path, Path, Path]]) -> Path:
    """A journal beside ``store`` as a writer's would look, naming paths of anyone's choice."""
    journal = journal_of(store)
    text = json.dumps({"commit": [[str(t), str(f), str(b)] for t, f, b in entries]})
    journal.write_text(text)
    return journal


@pytest.mark.parametrize("reader", [read_store, open_store], ids=["read_store", "open_store"])
def test_a_journal_beside_an_input_moves_and_deletes_nothing(tmp_path, reader):
    """A journal placed beside a source store names a folder elsewhere as the 'old output'
    to remove and a file elsewhere as the 'temporary' to move in: reading the store refuses
    in one line, and so does the stage that owns the store; nothing is deleted or moved."""
    store = source_store(tmp_path / "in/stack.zarr")
    victim = user_files(tmp_path / "victim")
    loot = tmp_path / "elsewhere/secret.txt"
    loot.parent.mkdir()
    loot.write_text("secret")
    journal = plant_journal(
        store,
        [
            (tmp_path / "gone", store.absolute(), victim),  # its "old output" is removed
            (loot, store.absolute(), tmp_path / "in/.x"),  # moved in over the store
        ],
    )
    before = {p: tree_digest(p) for p in (store, victim, loot)}
    listing = sorted(os.listdir(store.parent))
    with pytest.raises(InputError, match=r"\.stack\.zarr\.commit: not a commit journal of "):
        reader(store)
    with pytest.raises(InputError, match=r"\.stack\.zarr\.commit: not a commit journal of "):
        claim((store, store_kind("source")))
    assert {p: tree_digest(p) for p in (store, victim, loot)} == before
    assert sorted(os.listdir(store.parent)) == listing and journal.is_file()


def test_a_journal_that_is_a_link_is_not_followed(tmp_path):
    store = source_store(tmp_path / "in/stack.zarr")
    real = tmp_path / "elsewhere.json"
    real.write_text(json.dumps({"commit": []}))
    journal_of(store).symlink_to(real)
    with pytest.raises(InputError, match=r"\.stack\.zarr\.commit: not a regular file"):
        read_store(store)


def test_an_interrupted_commit_beside_an_input_is_left_to_its_stage(tmp_path):
    """A journal the writer made, with its new store not yet moved in: a reader refuses it
    (naming the journal) and moves nothing; the stage that owns the store completes it."""
    store = source_store(tmp_path / "s.zarr")
    new = outputs.temporary_name(store)
    source_store(new)
    old = outputs.temporary_name(store, "old")
    plant_journal(store, [(new.absolute(), store.absolute(), old.absolute())])
    with pytest.raises(InputError, match=r"s\.zarr: the run that wrote it was stopped while "):
        read_store(store)
    assert new.is_dir() and store.is_dir()
    claim((store, store_kind("source")))
    assert not new.exists() and not journal_of(store).exists() and not old.exists()
    read_store(store)


def test_a_lock_file_that_is_a_link_is_refused_and_its_target_left_alone(tmp_path):
    target = tmp_path / "precious.txt"
    target.write_text("mine")
    out = tmp_path / "out/m.json"
    out.parent.mkdir()
    lock_file(out).symlink_to(target)
    with pytest.raises(InputError, match=r"\.m\.json\.lock: not a regular file"):
        claim(out)
    assert target.read_text() == "mine" and lock_file(out).is_symlink()
    lock_file(out).unlink()
    os.mkfifo(lock_file(out))  # opening a FIFO must not wait for a writer either
    with pytest.raises(InputError, match=r"\.m\.json\.lock: not a regular file"):
        claim(out)


def test_an_output_through_a_link_into_tracked_results_is_refused(tmp_path, monkeypatch):
    """The repository's tracked output reached through a link that lies outside it."""
    monkeypatch.delenv("DVC_STAGE", raising=False)
    repo = tmp_path / "repo"
    (repo / ".dvc").mkdir(parents=True)
    (repo / "quickstart/data").mkdir(parents=True)
    (repo / "quickstart/dvc.yaml").write_text("stages:\n  gen:\n    cmd: x\n")
    lock = {"stages": {"gen": {"cmd": "x", "outs": [{"path": "data/g.zarr"}]}}}
    (repo / "quickstart/dvc.lock").write_text(json.dumps(lock))
    link = tmp_path / "link"
    link.symlink_to(repo / "quickstart/data")
    for path in (repo / "quickstart/data/g.zarr", link / "g.zarr"):
        with pytest.raises(InputError, match=r"g\.zarr: tracked by quickstart/dvc\.yaml"):
            claim(path)
    assert os.listdir(repo / "quickstart/data") == []


ray = pytest.importorskip("ray")


class _DeadRay:
    """Ray's calls as a driver sees them once its raylet has died: each raises Ray's error."""

    def __init__(self, error: Exception) -> None:
        self.error = error

    def __call__(self, *args: object, **kwargs: object) -> object:
        raise self.error


def test_a_dead_raylet_is_one_line_of_ours_and_the_locks_are_released(tmp_path, monkeypatch):
    """Ray's own errors (a raylet or worker that died), wherever Ray raises them, become one
    StageError line, and the claims of the stage are released (no lock file left)."""
    from mimicgen_pipe.run.executors import ray as ray_executor

    out = tmp_path / "m.json"
    died = ray.exceptions.LocalRayletDiedError()
    calls = {"is_initialized": lambda: True, "put": lambda x: x, "cancel": _DeadRay(died),
             "cluster_resources": lambda: {"CPU": 2}, "wait": _DeadRay(died)}  # fmt: skip
    for name, fake in calls.items():
        monkeypatch.setattr(ray, name, fake)
    remote = type("Remote", (), {"remote": staticmethod(lambda *a: object())})
    monkeypatch.setattr(ray, "remote", lambda **kw: lambda fn: remote)
    with pytest.raises(StageError) as err, outputs.claims():
        claim(out)
        assert lock_file(out).exists()
        for _ in ray_executor.imap_unordered(abs, [(0, 1), (1, 2)], 2, lambda: None):
            pass
    message = str(err.value)
    assert message.startswith("Ray stopped during the stage (LocalRayletDiedError: ")
    assert "\n" not in message and "Traceback" not in message
    assert not lock_file(out).exists() and os.listdir(tmp_path) == []
