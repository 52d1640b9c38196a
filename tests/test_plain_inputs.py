"""Demo files a user brings in are plain and hold what they claim: every reader (robomimic
source files, ManiSkill trajectory files, the robomimic dataset train_robomimic trains on)
refuses, with one InputError line naming the file, an HDF5 file that reads other files, a
file that is not a regular file, loosely named demos, and data of the wrong type, byte
order, size or range; before any data is read (no simulator here)."""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import h5py
import numpy as np
import pytest

from mimicgen_pipe.backends.maniskill.source import (
    TrajectoryFileEpisode,
    read_trajectory_file,
    state_for_env,
)
from mimicgen_pipe.core import plain_files
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.sources import robomimic_source
from tests.test_user_files import one_line, robomimic_file, trajectory_file

STEPS = 5  # of every crafted demo


@dataclass(frozen=True)
class Reader:
    """A reader of a user's demo file: how to make a valid one in a folder, read it, and
    where its first demo's groups lie."""

    name: str
    make: Callable[[Path], Path]
    read: Callable[[Path], object]
    demo: str  # the first demo's group
    sibling: Callable[[int], str]  # the group of demo i

    def actions(self) -> str:
        return f"{self.demo}/actions"


def _robomimic(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = robomimic_file(folder / "d.hdf5", 1)
    with h5py.File(path, "a") as f:  # STEPS steps, as the trajectory file's
        for key in ("actions", "states"):
            del f[f"data/demo_0/{key}"]
        f["data/demo_0/actions"] = np.zeros((STEPS, 7), np.float32)
        f["data/demo_0/states"] = np.zeros((STEPS, 9), np.float32)
    return path


READERS = [
    Reader("robomimic source", _robomimic,
           lambda p: robomimic_source.read(p, "pybullet", "stack"), "data/demo_0",
           lambda i: f"data/demo_{i}"),
    Reader("maniskill trajectory", lambda folder: trajectory_file(folder, 1),
           lambda p: read_trajectory_file(p, "stack_cube"), "traj_0", lambda i: f"traj_{i}"),
    Reader("robomimic training data", _robomimic, robomimic_source.check_training_file,
           "data/demo_0", lambda i: f"data/demo_{i}"),
]  # fmt: skip
HDF5_READERS = pytest.mark.parametrize("reader", READERS, ids=[r.name for r in READERS])


def refused(reader: Reader, path: Path, names: Path | None = None) -> str:
    """The one line ``reader`` refuses ``path`` with; it names ``names`` (default: path)."""
    with pytest.raises(InputError) as exc:
        reader.read(path)
    line = one_line(exc)
    assert str(names or path) in line, line
    return line


def replace(path: Path, key: str, make: Callable[[h5py.File, str], None]) -> None:
    """Dataset ``key`` of the HDF5 file ``path`` replaced by what ``make(f, key)`` puts there."""
    with h5py.File(path, "a") as f:
        del f[key]
        make(f, key)


def test_the_crafted_files_are_valid(tmp_path):
    for i, reader in enumerate(READERS):
        reader.read(reader.make(tmp_path / str(i)))


# -- 1. an HDF5 file that reads other files -------------------------------------------------


def _passwd(folder: Path) -> Path:
    """A stand-in for /etc/passwd: bytes that read as finite float32 actions."""
    path = folder / "passwd"
    path.write_bytes(np.full((STEPS, 7), 0.25, np.float32).tobytes())
    return path


def _other_file(folder: Path) -> Path:
    """Another HDF5 file with a dataset ``x`` of valid actions."""
    path = folder / "other.h5"
    with h5py.File(path, "w") as f:
        f["x"] = np.full((STEPS, 7), 0.25, np.float32)
    return path


def _external_storage(f: h5py.File, key: str) -> None:
    passwd = _passwd(Path(f.filename).parent)
    f.create_dataset(key, (STEPS, 7), "<f4", external=[(str(passwd), 0, STEPS * 28)])


def _external_link(f: h5py.File, key: str) -> None:
    f[key] = h5py.ExternalLink(str(_other_file(Path(f.filename).parent)), "x")


def _virtual_dataset(f: h5py.File, key: str) -> None:
    layout = h5py.VirtualLayout((STEPS, 7), np.float32)
    layout[:] = h5py.VirtualSource(str(_other_file(Path(f.filename).parent)), "x", (STEPS, 7))
    f.create_virtual_dataset(key, layout)


def _soft_link(f: h5py.File, key: str) -> None:
    f[key + "_data"] = np.zeros((STEPS, 7), np.float32)
    f[key] = h5py.SoftLink("/" + key + "_data")


@HDF5_READERS
@pytest.mark.parametrize(
    ("make", "expected"),
    [
        (_external_storage, "stores its data in another file"),
        (_external_link, "is an external link to"),
        (_virtual_dataset, "is a virtual dataset over"),
        (_soft_link, "is a soft link to"),
    ],
    ids=["external storage", "external link", "virtual dataset", "soft link"],
)
def test_an_hdf5_file_that_reads_another_file_is_refused(tmp_path, reader, make, expected):
    path = reader.make(tmp_path)
    replace(path, reader.actions(), make)
    line = refused(reader, path)
    assert f"{reader.actions()} {expected}" in line, line


@HDF5_READERS
def test_a_virtual_dataset_over_the_file_itself_is_read(tmp_path, reader):
    """As the robomimic export writes an image's next_obs: its data lie in the file."""
    path = reader.make(tmp_path)
    with h5py.File(path, "a") as f:
        layout = h5py.VirtualLayout((STEPS, 7), np.float32)
        layout[:] = h5py.VirtualSource(f[reader.actions()])
        f.create_virtual_dataset(f"{reader.demo}/next_obs/same", layout)
    reader.read(path)


def test_train_robomimic_refuses_such_a_dataset_before_robomimic_starts(tmp_path, monkeypatch):
    from mimicgen_pipe.stages import train_robomimic

    def no_robomimic(*args, **kwargs):
        raise AssertionError("robomimic was started")

    monkeypatch.setattr(train_robomimic, "train_robomimic", no_robomimic)
    monkeypatch.setattr(train_robomimic, "check_python", lambda python: python)
    path = _robomimic(tmp_path)
    replace(path, "data/demo_0/actions", _external_storage)
    (tmp_path / "params.yaml").write_text("task: stack\nbackend: pybullet\ntrain: {}\n")
    parser = argparse.ArgumentParser()
    train_robomimic.add_arguments(parser)
    args = parser.parse_args(["--params", str(tmp_path / "params.yaml"), "--dataset", str(path),
                              "--out", str(tmp_path / "run"), "--metrics", str(tmp_path / "m.json"),
                              "--plot", str(tmp_path / "p.csv")])  # fmt: skip
    with pytest.raises(InputError) as exc:
        train_robomimic.run(train_robomimic.resolve(args))
    assert f"{path}: data/demo_0/actions stores its data in another file" in one_line(exc)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.hdf5", "params.yaml", "passwd"]


# -- 2. not a regular file ------------------------------------------------------------------


@HDF5_READERS
def test_a_fifo_is_refused_without_blocking(tmp_path, reader):
    path = reader.make(tmp_path)
    path.unlink()
    os.mkfifo(path)
    assert "a FIFO, not a regular file" in refused(reader, path)


@pytest.mark.parametrize("special", ["fifo", "device", "too large"])
def test_a_trajectory_json_that_is_no_plain_file_is_refused(tmp_path, special):
    reader = READERS[1]
    path = reader.make(tmp_path)
    meta = path.with_suffix(".json")
    if special == "device":
        meta.unlink()
        meta.symlink_to("/dev/zero")
        expected = "a device, not a regular file"
    elif special == "fifo":
        meta.unlink()
        os.mkfifo(meta)
        expected = "a FIFO, not a regular file"
    else:  # a sparse file: no disk used
        with open(meta, "r+b") as f:
            f.truncate(plain_files.JSON_LIMIT + 1)
        expected = f"more than the {plain_files.JSON_LIMIT} a trajectory .json may have"
    assert expected in refused(reader, path, meta)


# -- 3. demo names --------------------------------------------------------------------------


@HDF5_READERS
@pytest.mark.parametrize("name", ["01", "1.0", "x", "-1", " 1"])
def test_a_demo_named_loosely_is_refused(tmp_path, reader, name):
    """demo_01 beside demo_1 was read as demo 1 twice."""
    path = reader.make(tmp_path)
    odd = reader.sibling(0).rsplit("_", 1)[0] + "_" + name
    with h5py.File(path, "a") as f:
        f.copy(f[reader.demo], reader.sibling(1))
        f.copy(f[reader.demo], odd)
    if reader.name == "maniskill trajectory":  # the .json lists traj_1 too
        meta = json.loads(path.with_suffix(".json").read_text())
        meta["episodes"].append({"episode_id": 1, "episode_seed": 11})
        path.with_suffix(".json").write_text(json.dumps(meta))
    line = refused(reader, path)
    assert f"{odd.rsplit('/', 1)[-1]}: not a " in line, line


# -- 4. wrong data --------------------------------------------------------------------------


@HDF5_READERS
@pytest.mark.parametrize(
    ("data", "expected"),
    [
        (np.ones((STEPS, 7), bool), "has dtype bool, expected little-endian floats"),
        (np.ones((STEPS, 7), np.int64), "has dtype int64, expected little-endian floats"),
        # the bytes of float32 actions relabelled big-endian: other, finite numbers
        (np.ones((STEPS, 7), np.float32).view(">f4"), "has big-endian dtype >f4"),
    ],
    ids=["bool", "int", "big-endian"],
)
def test_actions_of_the_wrong_dtype_are_refused(tmp_path, reader, data, expected):
    path = reader.make(tmp_path)
    replace(path, reader.actions(), lambda f, key: f.create_dataset(key, data=data))
    line = refused(reader, path)
    assert f"{reader.actions()} {expected}" in line, line


def _seed_in_file(reader: Reader, path: Path, seed: int) -> Path:
    """The file ``path`` with ``seed`` as its first demo's reset seed; the file that says it."""
    if reader.name == "maniskill trajectory":
        meta_path = path.with_suffix(".json")
        meta = json.loads(meta_path.read_text())
        meta["episodes"][0]["episode_seed"] = seed
        meta_path.write_text(json.dumps(meta))
        return meta_path
    with h5py.File(path, "a") as f:
        f[reader.demo].attrs["seed"] = np.int64(seed)
    return path


@pytest.mark.parametrize("reader", READERS[:2], ids=[r.name for r in READERS[:2]])
@pytest.mark.parametrize("seed", [2**40, 2**31, -2])
def test_a_seed_out_of_range_is_refused(tmp_path, reader, seed):
    path = reader.make(tmp_path)
    named = _seed_in_file(reader, path, seed)
    line = refused(reader, path, named)
    assert f"is {seed}, expected a reset seed in [0, {2**31 - 1}] or -1" in line, line


@pytest.mark.parametrize("reader", READERS[:2], ids=[r.name for r in READERS[:2]])
def test_the_largest_seed_and_none_are_read(tmp_path, reader):
    path = reader.make(tmp_path)
    _seed_in_file(reader, path, 2**31 - 1)
    assert reader.read(path)[0].seed == 2**31 - 1
    _seed_in_file(reader, path, -1)
    assert reader.read(path)[0].seed == -1


def test_a_source_store_of_an_unknown_robot_is_refused():
    """Its robot attribute would be recorded as the generated stores' source_robot."""
    from mimicgen_pipe import backends
    from mimicgen_pipe.stages.generate import check_source_attrs

    spec, control = (
        backends.task_spec("pybullet", "stack"),
        backends.backend_package("pybullet").CONTROL,
    )
    attrs = {"backend": "pybullet", "control_mode": control[0], "control_freq": control[1],
             "objects": list(spec.objects), "robot": "panda"}  # fmt: skip
    check_source_attrs(attrs, Path("p.zarr"), "pybullet", spec, control)
    for robot in ("ur5; rm -rf /", ["panda"], None):
        with pytest.raises(InputError) as exc:
            check_source_attrs(attrs | {"robot": robot}, Path("p.zarr"), "pybullet", spec, control)
        assert one_line(exc).startswith(f"p.zarr: attrs.robot is {robot!r}, expected a robot of")


# -- 5. a trajectory's state that is not the scene's ----------------------------------------


def fake_env() -> SimpleNamespace:
    """What backends.maniskill.source.state_for_env reads of an env: its state dict's layout
    (as ManiSkill's StackCube with the Panda has it), robot and task."""
    layout = {"actors": {"table-workspace": np.zeros((1, 13)), "cubeA": np.zeros((1, 13)),
                         "cubeB": np.zeros((1, 13))},
              "articulations": {"panda": np.zeros((1, 31))}}  # fmt: skip
    unwrapped = SimpleNamespace(
        get_state_dict=lambda: layout, agent=SimpleNamespace(robot=SimpleNamespace(name="panda"))
    )
    return SimpleNamespace(unwrapped=unwrapped, spec=SimpleNamespace(name="stack_cube"))


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (lambda s: s["actors"].update(cubeZ=np.zeros((1, 13))),
         "traj_0/env_states/actors/cubeZ: the stack_cube scene with 'panda' has no such actor"),
        (lambda s: s["articulations"].update(other=np.zeros((1, 3))),
         "traj_0/env_states/articulations/other: the stack_cube scene with 'panda' has no such "
         "articulation"),
        (lambda s: s["actors"].update(cubeA=np.zeros((1, 12))),
         "traj_0/env_states/actors/cubeA: 12 values per step, expected 13"),
        (lambda s: s.update(articulations={"panda_wristcam": np.zeros((1, 30))}),
         "traj_0/env_states/articulations/panda_wristcam: 30 values per step, expected 31"),
    ],
    ids=["unknown actor", "extra articulation", "actor width", "robot width"],
)  # fmt: skip
def test_a_trajectory_state_the_scene_lacks_is_refused(tmp_path, edit, expected):
    path = trajectory_file(tmp_path, 1)
    (episode,) = read_trajectory_file(path, "stack_cube")
    state = {k: dict(v) for k, v in episode.initial_state.items()}
    edit(state)
    bad = TrajectoryFileEpisode(episode.name, episode.seed, episode.actions, state)
    with pytest.raises(InputError) as exc:
        state_for_env(fake_env(), bad, path)
    assert one_line(exc).startswith(f"{path}: {expected}"), exc.value


def test_a_trajectory_state_of_another_panda_variant_is_mapped(tmp_path):
    (episode,) = read_trajectory_file(trajectory_file(tmp_path, 1), "stack_cube")
    state = {"actors": episode.initial_state["actors"],
             "articulations": {"panda_wristcam": np.ones((1, 31), np.float32)}}  # fmt: skip
    mapped = state_for_env(fake_env(), TrajectoryFileEpisode("traj_0", 1, None, state), "x.h5")
    assert list(mapped["articulations"]) == ["panda"]
    assert list(mapped["actors"]) == ["cubeA"]


# -- 6. a huge declared shape ---------------------------------------------------------------


@HDF5_READERS
@pytest.mark.parametrize(
    ("rows", "expected"),
    [
        (10**12, "declares shape (1000000000000, 7) (28000000000000 bytes), more than the"),
        (plain_files.MAX_STEPS + 1, f"has shape ({plain_files.MAX_STEPS + 1}, 7), expected (T, "),
    ],
    ids=["10**12 rows", "MAX_STEPS + 1 rows"],
)
def test_a_huge_declared_shape_is_refused_before_reading(tmp_path, reader, rows, expected):
    """The file declares the rows and stores none: reading them would take terabytes."""
    path = reader.make(tmp_path)
    replace(path, reader.actions(), lambda f, key: f.create_dataset(key, (rows, 7), "<f4"))
    line = refused(reader, path)
    assert f"{reader.actions()} {expected}" in line, line


def test_a_robomimic_export_with_images_is_plain(tmp_path):
    """The export's own file (gzip images, next_obs images as virtual datasets over the
    file's own rows) passes every check and reads back whole."""
    from mimicgen_pipe.formats import exporters
    from tests.test_export import CAMERAS, export_info, synthetic_store

    store = synthetic_store(tmp_path / "g.zarr", cameras=CAMERAS)
    path, _ = exporters.write(store, "robomimic", tmp_path, export_info(store))
    with h5py.File(path) as f:
        assert f["data/demo_0/next_obs/agentview_image"].is_virtual
    assert robomimic_source.check_training_file(path) == 3
    assert len(robomimic_source.read(path, "maniskill", "stack_cube")) == 3
