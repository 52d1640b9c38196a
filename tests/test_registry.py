"""Registries (mimicgen_pipe.core.registry): a set of choices is the files of a package, listed
without importing them and loaded by name; params validation reads its valid values from
them. And the one reset-variant sampler (mimicgen_pipe.core.reset_variants) every back end draws
its scenes with."""

from __future__ import annotations

import math
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.registry import choices, load
from mimicgen_pipe.core.reset_variants import _distance, sample_planar_poses
from mimicgen_pipe.core.taskspec import ObjectBounds, ResetVariant
from mimicgen_pipe.data.params import load_params

PROBE = "registry_probe_choices"  # a package made for these tests, nowhere else


@pytest.fixture
def probe_package(tmp_path, monkeypatch):
    """A package on sys.path: two modules (one that fails when imported), a sub-package, a
    private module, a folder that is no package and a file that is no module."""
    pkg = tmp_path / PROBE
    (pkg / "sub").mkdir(parents=True)
    (pkg / "data").mkdir()
    (pkg / "__init__.py").write_text("raise RuntimeError('the package was imported')\n")
    (pkg / "good.py").write_text("VALUE = 42\n")
    (pkg / "broken.py").write_text("raise RuntimeError('broken was imported')\n")
    (pkg / "_private.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "notes.txt").write_text("")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield PROBE
    for name in [m for m in sys.modules if m == PROBE or m.startswith(PROBE + ".")]:
        del sys.modules[name]


def test_choices_lists_modules_and_packages_without_importing_them(probe_package):
    assert choices(probe_package) == ("broken", "good", "sub")
    assert not any(m == PROBE or m.startswith(PROBE + ".") for m in sys.modules)


def test_load_of_an_unknown_name_is_one_error_naming_the_choices(probe_package, tmp_path):
    (tmp_path / PROBE / "__init__.py").write_text("")  # loading imports the package
    assert load(probe_package, "good").VALUE == 42
    for name in ("nope", "_private", "data", "notes"):
        with pytest.raises(InputError) as err:
            load(probe_package, name)
        assert str(err.value) == f"{name!r}: unknown in {PROBE} (known: broken, good, sub)"


def test_the_project_registries():
    assert choices("mimicgen_pipe.method.selection") == (
        "nearest_neighbor", "nearest_neighbor_robot_distance", "random"
    )  # fmt: skip
    assert choices("mimicgen_pipe.run.executors") == ("local", "ray")
    assert choices("mimicgen_pipe.formats.exporters") == ("lerobot", "maniskill", "robomimic")
    assert choices("mimicgen_pipe.backends") == ("maniskill", "pybullet")
    assert "stack_cube" in choices("mimicgen_pipe.tasks.maniskill")
    assert "stack" in choices("mimicgen_pipe.tasks.pybullet")


def test_an_unknown_executor_is_refused_when_it_is_made():
    from mimicgen_pipe.run.executors import Executor

    with pytest.raises(
        InputError, match=r"'dask': unknown in mimicgen_pipe.run.executors \(known: local, ray\)"
    ):
        Executor("dask")


def test_params_take_an_exporter_dropped_into_the_package(tmp_path, monkeypatch):
    """An exporter is one file: params validation knows it once the file is there."""
    import mimicgen_pipe.formats.exporters as exporters

    folder = tmp_path / "exporters"
    shutil.copytree(Path(exporters.__file__).parent, folder)
    monkeypatch.setattr(exporters, "__path__", [str(folder)])
    params = tmp_path / "params.yaml"
    params.write_text("export:\n  formats: [robomimic, csv_table]\n")
    with pytest.raises(InputError) as err:
        load_params(params)
    assert str(err.value) == (
        f"{params}: export.formats: expected entries among 'lerobot', 'maniskill', "
        "'robomimic', got 'csv_table'"
    )
    (folder / "csv_table.py").write_text('"""A format that exists in this test only."""\n')
    assert load_params(params).export.formats == ["robomimic", "csv_table"]


def test_an_export_directory_is_what_the_exporters_write(tmp_path):
    """Every path a format writes, ManiSkill's joint-position copy included; nothing else."""
    from mimicgen_pipe.formats.exporters import export_dir_kind

    out = tmp_path / "export"
    (out / "lerobot" / "meta").mkdir(parents=True)
    written = ["demos.hdf5", "lerobot/meta/info.json", "trajectory.h5", "trajectory.json"]
    written += ["trajectory.pd_joint_pos.h5", "trajectory.pd_joint_pos.json"]
    for name in written:
        (out / name).write_text("")
    kind = export_dir_kind()
    assert kind.why_not(out) is None
    (out / "notes.txt").write_text("")
    assert "notes.txt" in kind.why_not(out)


FULL_YAW = (0.0, 2 * math.pi)
BASE_XY = (-0.5, 0.0)  # the PyBullet back end's robot base


def _pybullet_like(max_reach: float | None) -> ResetVariant:
    """Three objects in a box that reaches past 0.6 m from the base: the reach cut binds."""
    box = ObjectBounds((-0.3, 0.3), (-0.5, 0.5), FULL_YAW)
    return ResetVariant({o: box for o in "abc"}, min_distance=0.07, max_reach=max_reach)


def _draw(variant: ResetVariant, seed: int):
    rng = np.random.default_rng(seed)  # as PyBulletEnv.reset draws
    return sample_planar_poses(
        variant, tuple("abc"), BASE_XY, rng.random, draw_order="object_by_object"
    )


def test_the_reset_sampler_honours_max_reach_and_is_reproducible_per_seed():
    reach = []
    for seed in range(300):
        xys, yaws = _draw(_pybullet_like(0.6), seed)
        again = _draw(_pybullet_like(0.6), seed)
        for a, b in zip(xys + yaws, again[0] + again[1], strict=True):
            assert a.dtype == np.float64 and np.array_equal(a, b)
        reach += [float(np.linalg.norm(xy[0] - BASE_XY)) for xy in xys]
        gaps = [np.linalg.norm(xys[i] - xys[j]) for i in range(3) for j in range(i)]
        assert min(gaps) >= 0.07
        assert all(0.0 <= y[0] < 2 * math.pi for y in yaws)
    assert max(reach) <= 0.6
    uncut = [
        np.linalg.norm(xy[0] - BASE_XY)
        for s in range(300)
        for xy in _draw(_pybullet_like(None), s)[0]
    ]
    assert max(uncut) > 0.6, "the box reaches past the cut, so the cut is what keeps draws in"
    assert not np.array_equal(
        _draw(_pybullet_like(0.6), 0)[0][0], _draw(_pybullet_like(0.6), 1)[0][0]
    )


def test_a_native_variant_has_nothing_to_draw():
    variant = ResetVariant(_pybullet_like(None).bounds, native=True)
    with pytest.raises(ValueError, match="native"):
        _draw(variant, 0)


def test_a_pybullet_task_cannot_mark_a_variant_native():
    """PyBullet has no reset of its own: a task file that says so is refused when made."""
    import dataclasses

    from mimicgen_pipe import backends

    task = backends.load_task("pybullet", "stack")
    d0 = dataclasses.replace(task.spec.reset_variants["D0"], native=True)
    spec = dataclasses.replace(task.spec, reset_variants={"D0": d0})
    with pytest.raises(ValueError, match="PyBullet has no reset of its own"):
        dataclasses.replace(task, spec=spec)


def test_reset_distances_round_as_the_back_ends_norms():
    """The reach and distance cuts compare norms rounded as torch's (float32, ManiSkill's
    draws) and numpy's BLAS vector norm (float64, PyBullet's) round them, bit for bit."""
    torch = pytest.importorskip("torch")
    gen = torch.Generator().manual_seed(0)
    d32 = torch.rand(100_000, 2, generator=gen) * 1.6 - 0.8
    assert np.array_equal(_distance(d32.numpy()), torch.linalg.norm(d32, dim=1).numpy())
    d64 = np.random.default_rng(0).random((20_000, 2)) * 1.6 - 0.8
    assert np.array_equal(_distance(d64), np.array([np.linalg.norm(d) for d in d64]))
