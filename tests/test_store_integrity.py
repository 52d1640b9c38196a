"""Stores cannot be silently corrupted: checksums, every chunk present, the store's kind,
episode bookkeeping and finite values are checked when read, before any work; and a store's
bytes depend only on the data and the params that shape it."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from mimicgen_pipe.core import poses
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data.params import load_params
from mimicgen_pipe.data.store import read_store, write_store
from tests.conftest import SMALL_PARAMS, cli


def small_store(path: Path, kind: str = "parsed") -> Path:
    """Two episodes (3 and 5 steps) with poses, actions, an all-zero array and subtask ends."""
    rng = np.random.default_rng(0)
    eps = [
        {
            "actions": rng.standard_normal((t, 7)).astype(np.float32),
            "gripper": np.zeros(t, np.float32),  # all zeros: a fill-value chunk, still written
            "object_poses/cube": poses.pose_from_pq(
                rng.standard_normal((t, 3)), rng.standard_normal((t, 4))
            ),
        }
        for t in (3, 5)
    ]
    episodes = {"subtask_term_index": np.array([[1], [2]]), "seed": np.array([4, 5])}
    return write_store(path, kind, eps, episodes, {"task": "t"})


def chunk(store: Path, array: str) -> Path:
    files = [p for p in (store / array).rglob("*") if p.is_file() and p.name != "zarr.json"]
    assert len(files) == 1, files
    return files[0]


def test_every_chunk_is_written_and_checksummed(tmp_path):
    store = small_store(tmp_path / "s.zarr")
    meta = yaml.safe_load((store / "data/gripper/zarr.json").read_text())
    assert [c["name"] for c in meta["codecs"]][-1] == "crc32c"
    assert chunk(store, "data/gripper").stat().st_size > 0  # zeros, yet on disk
    s = read_store(store, required=["actions"], kind="parsed")
    assert s.attrs["kind"] == "parsed" and s.episode_ends.tolist() == [3, 8]


@pytest.mark.parametrize("array", ["data/gripper", "data/actions", "meta/episodes/seed"])
def test_a_missing_chunk_is_an_error_not_zeros(tmp_path, array):
    store = small_store(tmp_path / "s.zarr")
    chunk(store, array).unlink()
    with pytest.raises(InputError, match=f"s.zarr: {array}: 1 of 1 chunk\\(s\\) missing"):
        read_store(store)


def test_a_truncated_chunk_is_one_clear_error(tmp_path):
    store = small_store(tmp_path / "s.zarr")
    c = chunk(store, "data/actions")
    c.write_bytes(c.read_bytes()[:-5])
    with pytest.raises(InputError, match="data/actions: a chunk cannot be decoded"):
        read_store(store)


def test_a_flipped_byte_fails_the_checksum(tmp_path):
    store = small_store(tmp_path / "s.zarr")
    c = chunk(store, "data/actions")
    raw = bytearray(c.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    c.write_bytes(bytes(raw))
    with pytest.raises(InputError, match="data/actions: a chunk cannot be decoded"):
        read_store(store)


def test_the_wrong_kind_of_store_is_refused(tmp_path):
    store = small_store(tmp_path / "s.zarr", kind="generated")
    with pytest.raises(InputError, match="a 'generated' store, expected 'source'"):
        read_store(store, kind="source")
    assert read_store(store, kind=["generated", "failed"]).n_episodes == 2
    with pytest.raises(ValueError, match="store kind 'demo'"):
        small_store(tmp_path / "t.zarr", kind="demo")


@pytest.mark.parametrize(
    "array,where",
    [
        ("object_poses/cube", "data/object_poses/cube: NaN or infinite value at episode 1, step 2"),
        ("actions", "data/actions: NaN or infinite value at episode 1, step 2"),
    ],
)
def test_nan_is_named_by_array_episode_and_step(tmp_path, array, where):
    s = read_store(small_store(tmp_path / "s.zarr"))
    steps = [s.episode(i) for i in range(2)]
    steps[1][array] = steps[1][array].copy()
    steps[1][array][2, 0] = np.nan
    bad = write_store(tmp_path / "bad.zarr", "parsed", steps, s.episodes, s.attrs)
    with pytest.raises(InputError, match=where):
        read_store(bad)


def test_episode_bookkeeping_is_checked(tmp_path):
    s = read_store(small_store(tmp_path / "s.zarr"))
    steps = [s.episode(i) for i in range(2)]
    bad = write_store(
        tmp_path / "a.zarr", "parsed", steps, {**s.episodes, "seed": np.array([1])}, s.attrs
    )
    with pytest.raises(InputError, match="meta/episodes/seed: 1 rows, expected one per episode"):
        read_store(bad)
    term = {**s.episodes, "subtask_term_index": np.array([[1], [9]])}
    bad = write_store(tmp_path / "b.zarr", "parsed", steps, term, s.attrs)
    with pytest.raises(InputError, match="episode 1: subtask ends \\[9\\]"):
        read_store(bad)


def test_an_older_schema_is_refused(tmp_path):
    import zarr

    store = small_store(tmp_path / "s.zarr")
    zarr.open_group(str(store), mode="r+").attrs["schema_version"] = 1
    with pytest.raises(InputError, match="schema_version 1, expected 2"):
        read_store(store)


def edit_metadata(store: Path, array: str, edit) -> Path:
    """``edit`` applied to the parsed zarr.json of ``array``; the file's path."""
    import json

    meta = store / array / "zarr.json"
    doc = json.loads(meta.read_text())
    edit(doc)
    meta.write_text(json.dumps(doc))
    return meta


@pytest.mark.parametrize(
    ("array", "dtype", "expected"),
    [("data/actions", "int32", "floating-point"), ("meta/episodes/seed", "float64", "integer"),
     ("data/gripper", "bool", "floating-point")],
)  # fmt: skip
def test_an_array_relabelled_with_another_dtype_is_refused_before_reading(
    tmp_path, array, dtype, expected
):
    from mimicgen_pipe.data.store import open_store

    store = small_store(tmp_path / "s.zarr")
    meta = edit_metadata(store, array, lambda d: d.update(data_type=dtype))
    for opener in (read_store, open_store):
        with pytest.raises(InputError, match=rf"{array}: dtype {dtype}, expected {expected} "
                           rf"\({meta}"):  # fmt: skip
            opener(store)


@pytest.mark.parametrize(
    "damage",
    [lambda m: m.write_text("{bad"), lambda m: edit_metadata(m.parent.parent.parent,
     "data/actions", lambda d: d.pop("shape")), lambda m: m.write_text("[1]")],
)  # fmt: skip
def test_a_damaged_zarr_json_is_one_error_naming_the_file(tmp_path, damage):
    from mimicgen_pipe.data.store import open_store

    store = small_store(tmp_path / "s.zarr")
    meta = store / "data/actions/zarr.json"
    damage(meta)
    for opener in (read_store, open_store):
        with pytest.raises(InputError, match=rf"^{meta}: damaged store metadata \("):
            opener(store)


# ---- the same cases through the stages (real CLI runs, exit 2, nothing written) ----


def run_refused(work: Path, *args: str) -> str:
    res = cli(*args, cwd=work, check=False)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    return lines[0]


@pytest.fixture
def work(pipeline, tmp_path):
    """A scratch copy of the small pipeline's stores and params."""
    for name in ("params.yaml", "data/parsed", "data/pose_noise", "data/source", "data/generated"):
        src = pipeline / name
        (shutil.copytree if src.is_dir() else shutil.copy)(src, tmp_path / name)
    return tmp_path


@pytest.mark.sim
def test_generate_refuses_a_parsed_store_missing_a_chunk(work):
    chunk(work / "data/pose_noise/stack_cube.zarr", "meta/episodes/subtask_term_index").unlink()
    msg = run_refused(work, "generate", "--variant", "D0", "--out", "data/out/g.zarr")
    assert "meta/episodes/subtask_term_index: 1 of 1 chunk(s) missing" in msg
    assert not [p for p in (work / "data/out").rglob("*") if p.is_file()]


@pytest.mark.sim
def test_parse_refuses_a_source_store_missing_a_chunk(work):
    chunk(work / "data/source/stack_cube.zarr", "data/actions").unlink()
    msg = run_refused(work, "parse", "--out", "data/out/p.zarr")
    assert "data/actions: 1 of 1 chunk(s) missing" in msg


@pytest.mark.sim
def test_train_refuses_a_store_missing_an_obs_chunk(work):
    chunk(work / "data/generated/stack_cube_D1.zarr", "data/obs/eef_pos").unlink()
    msg = run_refused(work, "train", "--data", "D1", "--out", "data/out/policy")
    assert "data/obs/eef_pos: 1 of 1 chunk(s) missing" in msg


@pytest.mark.sim
def test_a_truncated_chunk_stops_generate_in_one_line(work):
    c = chunk(work / "data/pose_noise/stack_cube.zarr", "data/target_pose")
    c.write_bytes(c.read_bytes()[:-3])
    msg = run_refused(work, "generate", "--variant", "D0", "--out", "data/out/g.zarr")
    assert "data/target_pose: a chunk cannot be decoded" in msg


@pytest.mark.sim
@pytest.mark.parametrize("stage", ["generate", "pose_noise"])
def test_a_nan_pose_inside_a_segment_is_refused(work, stage):
    path = work / "data/parsed/stack_cube.zarr"
    s = read_store(path)
    steps = [s.episode(i) for i in range(s.n_episodes)]
    steps[1]["object_poses/cubeB"] = steps[1]["object_poses/cubeB"].copy()
    steps[1]["object_poses/cubeB"][11, 2] = np.nan
    write_store(path, "parsed", steps, s.episodes, s.attrs)
    args = ["--variant", "D0", "--parsed", str(path)] if stage == "generate" else []
    msg = run_refused(work, stage, *args, "--out", "data/out/x.zarr")
    assert "data/object_poses/cubeB: NaN or infinite value at episode 1, step 11" in msg


@pytest.mark.sim
def test_parse_refuses_a_generated_store(work):
    msg = run_refused(
        work, "parse", "--source", "data/generated/stack_cube_D1.zarr", "--out", "data/out/p.zarr"
    )
    assert "a 'generated' store, expected 'source'" in msg


# ---- bytes depend only on the data and the params that shape it ----


def tree_digest(path: Path) -> str:
    """One hash over every file's relative path and bytes, as DVC hashes a directory."""
    h = hashlib.sha256()
    for f in sorted(p for p in path.rglob("*") if p.is_file()):
        h.update(str(f.relative_to(path)).encode() + b"\0" + f.read_bytes())
    return h.hexdigest()


@pytest.mark.sim
def test_a_second_directory_reproduces_every_store_byte_for_byte(pipeline, tmp_path):
    """The source -> parse -> pose_noise -> generate chain run again elsewhere, with other
    worker counts and other values of params the chain does not read (train, evaluate,
    transfer.attempts), gives the same bytes in every store: what a fresh clone's `dvc repro`
    relies on to match dvc.lock."""
    other = yaml.safe_load(SMALL_PARAMS)
    other["generate"]["workers"] = 2
    other["train"] = {"num_demos": 7, "cpu": {"epochs": 3}}
    other["evaluate"] = {"episodes": 3, "workers": 1}
    other["transfer"] = {"attempts": 11}
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(other))
    load_params(tmp_path / "params.yaml")
    for args in (["source"], ["parse"], ["pose_noise"], ["generate", "--variant", "D1"]):
        cli(*args, cwd=tmp_path)
    stores = [
        "data/source/stack_cube.zarr",
        "data/parsed/stack_cube.zarr",
        "data/pose_noise/stack_cube.zarr",
        "data/generated/stack_cube_D1.zarr",
        "data/generated/stack_cube_D1_failed.zarr",
    ]
    for store in stores:
        assert tree_digest(tmp_path / store) == tree_digest(pipeline / store), store


@pytest.mark.sim
def test_worker_count_does_not_change_a_generated_stores_bytes(pipeline):
    """conftest's pipeline generates D1 with 1 and with 2 workers."""
    a, b = (
        pipeline / "data/generated/stack_cube_D1.zarr",
        pipeline / "data/again/stack_cube_D1.zarr",
    )
    assert tree_digest(a) == tree_digest(b)


@pytest.mark.sim
def test_export_and_coverage_refuse_arrays_relabelled_with_another_dtype(work):
    store = work / "data/generated/stack_cube_D1.zarr"
    edit_metadata(store, "data/obs/cubeA_pos", lambda d: d.update(data_type="int32"))
    out = work / "export"
    line = run_refused(work, "export", "--variant", "D1", "--formats", "robomimic", "--out",
                       str(out), "--metrics", str(work / "x.json"))  # fmt: skip
    assert "data/obs/cubeA_pos: dtype int32, expected floating-point" in line
    assert not out.exists() and not (work / "x.json").exists()
    edit_metadata(store, "data/obs/cubeA_pos", lambda d: d.update(data_type="float32"))
    edit_metadata(store, "meta/episodes/initial_object_poses",
                  lambda d: d.update(data_type="int64"))  # fmt: skip
    line = run_refused(work, "coverage", "--variant", "D1", "--metrics", str(work / "c.json"))
    assert "meta/episodes/initial_object_poses: dtype int64, expected floating-point" in line


@pytest.mark.sim
@pytest.mark.parametrize(
    ("attr", "value"), [("backend", "pybullet"), ("control_freq", 7), ("objects", ["cubeA"])]
)
def test_generate_refuses_source_demos_recorded_elsewhere(work, attr, value):
    import zarr

    store = work / "data/pose_noise/stack_cube.zarr"
    zarr.open_group(str(store), mode="r+").attrs[attr] = value
    out = work / "data/generated/again.zarr"
    line = run_refused(work, "generate", "--variant", "D1", "--out", str(out), "--metrics",
                       str(work / "g.json"))  # fmt: skip
    assert f"data/pose_noise/stack_cube.zarr: attrs.{attr} is {value!r}, expected" in line
    assert not out.exists() and not (work / "g.json").exists()


def test_a_store_with_no_episodes_says_so_and_what_to_do(tmp_path):
    store = tmp_path / "data/generated/stack_cube_D0.zarr"
    attrs = {"task": "stack_cube", "variant": "D0", "backend": "maniskill", "robot": "panda",
             "control_mode": "pd_ee_delta_pose", "control_freq": 20,
             "objects": ["cubeA", "cubeB"]}  # fmt: skip
    write_store(store, "generated", [], {}, attrs)
    (tmp_path / "params.yaml").write_text(SMALL_PARAMS)
    for args in (["train", "--data", "D0"], ["export", "--variant", "D0"],
                 ["observe", "--variant", "D0"]):  # fmt: skip
        line = run_refused(tmp_path, *args)
        assert line.endswith("data/generated/stack_cube_D0.zarr: 0 episodes (generate kept "
                             "none of its attempts: raise generate.max_attempts, or check the "
                             "source demos and the failed store beside it)"), line  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data", "params.yaml"]


@pytest.mark.sim
def test_guarantee_mode_at_its_cap_is_one_line_and_leaves_nothing(work):
    out = work / "data/generated/capped.zarr"
    res = cli("generate", "--variant", "D1", "--num-demos", "50", "--max-attempts", "6",
              "--out", str(out), "--metrics", str(work / "g.json"), cwd=work,
              check=False)  # fmt: skip
    assert res.returncode == 2, res.stderr[-2000:]
    line = res.stderr.strip().splitlines()[-1]  # after the progress bar's
    assert "Traceback" not in res.stderr
    assert "of 50 demos after generate.max_attempts=6 attempts" in line
    assert line.endswith("raise generate.max_attempts (--max-attempts) or check the source "
                         "demos; nothing was written")  # fmt: skip
    assert sorted(p.name for p in out.parent.iterdir() if "capped" in p.name) == []
    assert not (work / "g.json").exists()


def test_arrays_come_in_name_order_whatever_order_zarr_lists_them(tmp_path, monkeypatch):
    import zarr

    from mimicgen_pipe.data.store import open_store

    store = small_store(tmp_path / "s.zarr")
    listed = zarr.Group.members

    def shuffled(self, *args, **kwargs):  # zarr lists concurrently: any order may come
        return tuple(reversed(tuple(listed(self, *args, **kwargs))))

    monkeypatch.setattr(zarr.Group, "members", shuffled)
    expected = ["actions", "gripper", "object_poses/cube"]
    assert list(read_store(store).data) == expected
    assert open_store(store).data_keys == expected
    assert list(read_store(store).episodes) == ["seed", "subtask_term_index"]
