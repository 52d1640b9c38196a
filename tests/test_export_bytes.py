"""Two exports of one store are the same bytes, file for file, in every format: nothing
of the moment they were written (HDF5's object times) goes into them."""

from __future__ import annotations

import time
from pathlib import Path

import h5py

from mimicgen_pipe.formats import exporters
from tests.test_export import CAMERAS, export_info, fake_replays, synthetic_store

FORMATS = ("robomimic", "lerobot", "maniskill")


def export_all(store, out: Path) -> dict[Path, bytes]:
    """Every format's export of ``store`` under ``out``: relative path -> bytes."""
    info = export_info(store)
    for fmt in FORMATS:
        (out / fmt).mkdir(parents=True)
        extra = fake_replays(store) if fmt == "maniskill" else {}
        exporters.write(store, fmt, out / fmt, info, **extra)
    return {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


def timed_objects(path: Path) -> list[str]:
    """The objects of an HDF5 file (the root group included) that carry a time."""
    timed = []
    with h5py.File(path, "r") as f:
        for name, obj in [("/", f), *_objects(f)]:
            info = h5py.h5o.get_info(obj.id)
            if info.ctime or info.mtime or info.atime or info.btime:
                timed.append(name)
    return timed


def _objects(f: h5py.File) -> list[tuple[str, h5py.HLObject]]:
    found: list[tuple[str, h5py.HLObject]] = []
    f.visititems(lambda name, obj: found.append((name, obj)))
    return found


def test_two_exports_of_one_store_are_the_same_bytes(tmp_path):
    """An observed store (camera images: the robomimic export's virtual next_obs images,
    LeRobot's videos) exported twice, a second apart (HDF5 keeps times in whole seconds:
    the clock has moved between the two, which must change nothing)."""
    store = synthetic_store(tmp_path / "observed.zarr", cameras=CAMERAS)
    first = export_all(store, tmp_path / "a")
    time.sleep(1.1)
    second = export_all(store, tmp_path / "b")
    assert first.keys() == second.keys()
    assert {p.parts[0] for p in first} == set(FORMATS)
    assert [p for p in first if first[p] != second[p]] == []
    hdf5_files = [p for p in first if p.suffix in (".hdf5", ".h5")]
    assert len(hdf5_files) == 3  # robomimic's, ManiSkill's two control modes'
    for p in hdf5_files:
        assert timed_objects(tmp_path / "a" / p) == [], p
