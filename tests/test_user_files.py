"""Files a user gives (trajectory and robomimic files, boundaries files, YAML): every broken
one is one InputError naming the file and what was expected, read before any simulator
starts (no simulator here)."""

from __future__ import annotations

import argparse
import hashlib
import json
import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from mimicgen_pipe.backends.maniskill.source import read_trajectory_file
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.taskspec import SubtaskSpec
from mimicgen_pipe.core.yamlfile import load_yaml
from mimicgen_pipe.method.segments import read_boundaries
from mimicgen_pipe.sources import robomimic_source


def one_line(exc: pytest.ExceptionInfo) -> str:
    msg = str(exc.value)
    assert "\n" not in msg, msg
    return msg


# -- ManiSkill trajectory files (.h5 + .json) -----------------------------------------------


def trajectory_file(folder: Path, episodes: int = 1) -> Path:
    """A valid pd_ee_delta_pose StackCube trajectory file of ``episodes`` 5-step episodes."""
    folder.mkdir(parents=True, exist_ok=True)
    h5 = folder / "demo.h5"
    with h5py.File(h5, "w") as f:
        for i in range(episodes):
            g = f.create_group(f"traj_{i}")
            g["actions"] = np.zeros((5, 7), np.float32)
            g["env_states/actors/cubeA"] = np.zeros((6, 13), np.float32)
            g["env_states/articulations/panda"] = np.zeros((6, 31), np.float32)
    meta = {
        "env_info": {"env_id": "StackCube-v1", "env_kwargs": {"control_mode": "pd_ee_delta_pose"}},
        "episodes": [{"episode_id": i, "episode_seed": 10 + i} for i in range(episodes)],
    }
    h5.with_suffix(".json").write_text(json.dumps(meta))
    return h5


def test_a_valid_trajectory_file_reads(tmp_path):
    eps = read_trajectory_file(trajectory_file(tmp_path, 3), "stack_cube")
    assert [(e.name, e.seed, e.actions.shape) for e in eps] == [
        ("traj_0", 10, (5, 7)), ("traj_1", 11, (5, 7)), ("traj_2", 12, (5, 7))]  # fmt: skip


def _truncate(h5: Path) -> None:
    data = h5.read_bytes()
    h5.write_bytes(data[: len(data) // 2])


def _meta(edit):
    def change(h5: Path) -> None:
        meta_path = h5.with_suffix(".json")
        meta = json.loads(meta_path.read_text())
        edit(meta)
        meta_path.write_text(json.dumps(meta))

    return change


@pytest.mark.parametrize(
    ("damage", "expected"),
    [
        (_truncate, r"demo\.h5: not a readable HDF5 trajectory file \(.*truncated file"),
        (
            lambda h5: h5.write_text("episode 0: 5 steps\n"),
            r"demo\.h5: not a readable HDF5 trajectory file \(.*file signature not found",
        ),
        (
            lambda h5: h5.with_suffix(".json").write_text('{"env_info": {'),
            r"demo\.json: not valid JSON \(line 1, column 15: ",
        ),
        (
            lambda h5: h5.with_suffix(".json").write_text("[1, 2]"),
            r"demo\.json: top level: expected a JSON object, got \[1, 2\]",
        ),
        (
            lambda h5: h5.with_suffix(".json").write_bytes(b"\xff\xfe{}"),
            r"demo\.json: not UTF-8 text \(byte 0xff at offset 0\)",
        ),
        (
            _meta(lambda m: m["episodes"][0].pop("episode_id")),
            r"demo\.json: episodes\[0\]: no episode_id",
        ),
        (
            _meta(lambda m: m["episodes"][0].update(episode_id=True)),
            r"episodes\[0\]\.episode_id: expected an integer >= 0, got True",
        ),
        (
            _meta(lambda m: m["episodes"][0].update(episode_id="0")),
            r"episodes\[0\]\.episode_id: expected an integer >= 0, got \"0\"",
        ),
        (
            _meta(lambda m: m["episodes"].append(dict(m["episodes"][0]))),
            r"episodes\[1\]\.episode_id: 0 listed twice",
        ),
        (
            _meta(lambda m: m["episodes"][0].update(episode_seed="ten")),
            r"episodes\[0\]\.episode_seed: expected an integer, got \"ten\"",
        ),
        (_meta(lambda m: m.update(episodes={"0": 1})), r"episodes: expected a JSON list"),
        (_meta(lambda m: m.update(env_info=[])), r"env_info: expected a JSON object, got \[\]"),
        (_meta(lambda m: m["episodes"].append(7)), r"episodes\[1\]: expected a JSON object"),
        (
            _meta(lambda m: m["episodes"][0].update(episode_id=4)),
            r"demo\.h5: traj_4 listed in the \.json but missing",
        ),
    ],
)
def test_a_broken_trajectory_file_is_one_error(tmp_path, damage, expected):
    h5 = trajectory_file(tmp_path)
    damage(h5)
    with pytest.raises(InputError) as exc:
        read_trajectory_file(h5, "stack_cube")
    assert re.search(expected, one_line(exc)), exc.value


def test_a_trajectory_dataset_of_strings_is_one_error(tmp_path):
    h5 = trajectory_file(tmp_path)
    with h5py.File(h5, "a") as f:
        del f["traj_0/env_states/actors/cubeA"]
        f["traj_0/env_states/actors/cubeA"] = np.array([[b"x"] * 13] * 6)
    expected = r"demo\.h5: traj_0/env_states/actors/cubeA has dtype \|S1, expected little-endian"
    with pytest.raises(InputError, match=expected) as exc:
        read_trajectory_file(h5, "stack_cube")
    one_line(exc)


# -- robomimic .hdf5 given as source demos --------------------------------------------------


def robomimic_file(path: Path, demos: int = 2) -> Path:
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        data.attrs["env_args"] = json.dumps(
            {"env_kwargs": {"backend": "pybullet", "task": "stack"}}
        )
        for i in range(demos):
            g = data.create_group(f"demo_{i}")
            g.attrs["seed"] = np.int64(i)
            g["actions"] = np.zeros((4, 7), np.float32)
            g["states"] = np.zeros((4, 9), np.float32)
    return path


def test_a_valid_robomimic_file_reads(tmp_path):
    demos = robomimic_source.read(robomimic_file(tmp_path / "d.hdf5", 3), "pybullet", "stack")
    assert [(d.name, d.seed) for d in demos] == [("demo_0", 0), ("demo_1", 1), ("demo_2", 2)]


def _robomimic_edit(edit):
    def change(path: Path) -> None:
        with h5py.File(path, "a") as f:
            edit(f)

    return change


def _replace_demo_with_dataset(f: h5py.File) -> None:
    del f["data/demo_1"]
    f["data/demo_1"] = np.zeros(3)


@pytest.mark.parametrize(
    ("damage", "expected"),
    [
        (_truncate, r"d\.hdf5: not a readable HDF5 robomimic file \(.*truncated file"),
        (lambda p: p.write_text("demo_0,1,2\n"), r"d\.hdf5: not a readable HDF5 robomimic file"),
        (
            _robomimic_edit(lambda f: f["data/demo_1"].attrs.__setitem__("seed", "one")),
            r"data/demo_1\.attrs\['seed'\] is 'one', expected an integer",
        ),
        (
            _robomimic_edit(lambda f: f["data/demo_1"].attrs.__setitem__("seed", True)),
            r"data/demo_1\.attrs\['seed'\] is .*True, expected an integer",
        ),
        (_robomimic_edit(_replace_demo_with_dataset), r"data/demo_1 is not a demo group"),
        (
            _robomimic_edit(lambda f: f["data"].attrs.modify("env_args", '["pybullet"]')),
            r"data\.attrs\['env_args'\] missing or not JSON",
        ),
    ],
)
def test_a_broken_robomimic_file_is_one_error(tmp_path, damage, expected):
    path = robomimic_file(tmp_path / "d.hdf5")
    damage(path)
    with pytest.raises(InputError) as exc:
        robomimic_source.read(path, "pybullet", "stack")
    assert re.search(expected, one_line(exc)), exc.value


# -- the source stage: the file is read whole before the simulator starts -------------------


def run_source(tmp_path: Path, monkeypatch, params: str) -> None:
    """mimicgen_pipe.stages.source.run with a simulator that fails the test if it is started."""
    from mimicgen_pipe import backends
    from mimicgen_pipe.stages import source

    def no_simulator(*args, **kwargs):
        raise AssertionError("the simulator was started")

    monkeypatch.setattr(backends, "make_env", no_simulator)
    (tmp_path / "params.yaml").write_text(params)
    parser = argparse.ArgumentParser()
    source.add_arguments(parser)
    args = parser.parse_args(["--params", str(tmp_path / "params.yaml"),
                              "--out", str(tmp_path / "s.zarr"),
                              "--metrics", str(tmp_path / "s.json")])  # fmt: skip
    source.run(source.resolve(args))


def test_a_short_trajectory_file_stops_the_source_stage_before_the_simulator(tmp_path, monkeypatch):
    h5 = trajectory_file(tmp_path / "input", 3)
    params = f"task: stack_cube\nsource: {{num_demos: 5, from_file: {h5}}}\n"
    with pytest.raises(InputError) as exc:
        run_source(tmp_path, monkeypatch, params)
    assert one_line(exc) == (
        f"{h5}: 3 episodes, fewer than source.num_demos = 5 in {tmp_path / 'params.yaml'}; "
        "ask for 3 or fewer, or give a file with more"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["input", "params.yaml"]


def test_a_long_enough_trajectory_file_reaches_the_simulator(tmp_path, monkeypatch):
    """At least num_demos episodes: the checks pass and the stage goes on (the first
    num_demos are replayed, as before)."""
    h5 = trajectory_file(tmp_path / "input", 3)
    params = f"task: stack_cube\nsource: {{num_demos: 3, from_file: {h5}}}\n"
    with pytest.raises(AssertionError, match="the simulator was started"):
        run_source(tmp_path, monkeypatch, params)


def test_a_broken_robomimic_file_stops_the_source_stage_before_the_simulator(tmp_path, monkeypatch):
    path = robomimic_file(tmp_path / "d.hdf5")
    _truncate(path)
    params = f"task: stack\nbackend: pybullet\nsource: {{num_demos: 2, from_file: {path}}}\n"
    with pytest.raises(InputError, match="not a readable HDF5 robomimic file"):
        run_source(tmp_path, monkeypatch, params)


def test_a_short_robomimic_file_stops_the_source_stage(tmp_path, monkeypatch):
    path = robomimic_file(tmp_path / "d.hdf5", 2)
    params = f"task: stack\nbackend: pybullet\nsource: {{num_demos: 3, from_file: {path}}}\n"
    with pytest.raises(InputError, match=r"d\.hdf5: 2 episodes, fewer than source\.num_demos = 3"):
        run_source(tmp_path, monkeypatch, params)


def test_a_robomimic_file_of_other_states_is_refused_before_any_output(tmp_path):
    """Its states are held to an env's by the source stage's resolve, before any output is
    claimed (the file's 9 values a step are no PyBullet stack state)."""
    from tests.test_cli_errors import refused_by_resolve

    path = robomimic_file(tmp_path / "d.hdf5", 2)
    (tmp_path / "params.yaml").write_text(
        f"task: stack\nbackend: pybullet\nsource: {{num_demos: 2, from_file: {path}}}\n"
    )
    out = tmp_path / "out"
    msg = refused_by_resolve(
        "source", tmp_path, "--out", out / "s.zarr", "--metrics", out / "s.json"
    )
    assert re.fullmatch(
        rf"{re.escape(str(path))}: data/demo_0/states has 9 values per step, expected \d+ "
        r"\(the pybullet stack state with panda\)",
        msg,
    ), msg
    assert not out.exists()


def test_a_maniskill_file_on_pybullet_stops_the_source_stage(tmp_path, monkeypatch):
    h5 = trajectory_file(tmp_path / "input")
    params = f"task: stack\nbackend: pybullet\nsource: {{num_demos: 1, from_file: {h5}}}\n"
    own = r"source\.from_file: .*demo\.h5: backend pybullet reads no source file format of its own"
    with pytest.raises(InputError, match=own):
        run_source(tmp_path, monkeypatch, params)


# -- the source stage names the file it read ------------------------------------------------

REPO = Path(__file__).resolve().parents[1]
# a committed run of the demonstrator's demos (source.from_file null)
COMMITTED = REPO / "quickstart/metrics/source_stack_cube.json"


def run_source_recorded(tmp_path: Path, monkeypatch, section: str, *argv: str) -> bytes:
    """mimicgen_pipe.stages.source.run (params' source: ``section``) with its recording replaced by
    the committed run's numbers (no simulator, no store written): the metrics file's bytes."""
    from mimicgen_pipe import backends
    from mimicgen_pipe.stages import source

    numbers = json.loads(COMMITTED.read_text())
    recording = argparse.Namespace(
        steps=[{}] * numbers["demos"], demonstrator_failures=0, replay_failures=0,
        episode_fields=dict, metrics=lambda: {k: numbers[k] for k in (
            "demos", "dropped_planner", "dropped_replay", "mean_length", "demonstrator_seeds")},
    )  # fmt: skip
    env = argparse.Namespace(control_mode="pd_ee_delta_pose", control_freq=20)
    monkeypatch.setattr(backends, "make_env", lambda *args: env)
    monkeypatch.setattr(source, "record_source_demos", lambda *args: recording)
    monkeypatch.setattr("mimicgen_pipe.data.store.write_store", lambda path, *args: path.mkdir())
    (tmp_path / "params.yaml").write_text(f"task: stack_cube\nsource: {section}\n")
    parser = argparse.ArgumentParser()
    source.add_arguments(parser)
    args = parser.parse_args(["--params", str(tmp_path / "params.yaml"),
                              "--out", str(tmp_path / "s.zarr"),
                              "--metrics", str(tmp_path / "s.json"), *argv])  # fmt: skip
    source.run(source.resolve(args))
    return (tmp_path / "s.json").read_bytes()


def test_source_metrics_without_a_file_keep_their_bytes(tmp_path, monkeypatch, capsys):
    assert run_source_recorded(tmp_path, monkeypatch, "{num_demos: 10}") == COMMITTED.read_bytes()
    assert capsys.readouterr().out.startswith("source: 10 demos of stack_cube on maniskill (D0)\n")


@pytest.mark.parametrize("how", ["params", "--from-file"])
def test_the_source_stage_names_the_file_it_read(tmp_path, monkeypatch, capsys, how):
    """Its path as given and its sha256 (and its .json's) in the log line, the metrics and
    the report, so that a reader can tell which version of the file a run used."""
    from mimicgen_pipe.report.inputs import read_metrics_folder
    from mimicgen_pipe.report.method import source_file_blocks

    h5 = trajectory_file(tmp_path / "input", 10)
    sha = hashlib.sha256(h5.read_bytes()).hexdigest()
    if how == "params":
        got = run_source_recorded(tmp_path, monkeypatch, f"{{num_demos: 10, from_file: {h5}}}")
    else:
        got = run_source_recorded(tmp_path, monkeypatch, "{num_demos: 10}", "--from-file", str(h5))
    assert json.loads(got) == json.loads(COMMITTED.read_text()) | {
        "source_file": str(h5),
        "source_file_sha256": sha,
        "source_file_json_sha256": hashlib.sha256(h5.with_suffix(".json").read_bytes()).hexdigest(),
    }
    assert f"source: 10 demos of stack_cube on maniskill (D0) from {h5} (sha256 {sha})\n" in (
        capsys.readouterr().out
    )
    params = argparse.Namespace(task="stack_cube", backend="maniskill")
    (text,) = source_file_blocks(params, read_metrics_folder(tmp_path))
    assert text.text == f"Source demos brought in from `{h5}` (sha256 `{sha}`)."


def test_the_source_stage_refuses_a_params_file_its_pipeline_does_not_track(tmp_path, monkeypatch):
    """The check stage's rule (source_inputs.check_place), also where the source stage runs
    alone (dvc repro -s source); --from-file, a hand run's choice, may name any file."""
    from mimicgen_pipe.data import pipelines

    monkeypatch.setattr(pipelines, "_current", None)  # restored: stage_params sets it
    (tmp_path / ".dvc").mkdir()
    (tmp_path / "dvc.yaml").write_text((REPO / "dvc.yaml").read_text())
    h5 = trajectory_file(tmp_path / "input", 10)
    with pytest.raises(InputError) as exc:
        run_source_recorded(tmp_path, monkeypatch, f"{{num_demos: 10, from_file: {h5}}}")
    assert re.fullmatch(
        r".*params\.yaml: source\.from_file: .*demo\.h5: expected a file in \S*inputs/, the "
        r"folder that the source stage of \S*dvc\.yaml tracks .*",
        one_line(exc),
    )
    assert not (tmp_path / "s.json").exists()
    run_source_recorded(tmp_path, monkeypatch, "{num_demos: 10}", "--from-file", str(h5))
    assert json.loads((tmp_path / "s.json").read_text())["source_file"] == str(h5)


def test_source_from_file_must_be_a_regular_file(tmp_path, monkeypatch):
    (tmp_path / "input").mkdir()
    with pytest.raises(InputError) as exc:
        run_source_recorded(tmp_path, monkeypatch, "{}", "--from-file", str(tmp_path / "input"))
    assert one_line(exc) == (
        f"--from-file {tmp_path / 'input'}: cannot read the file (it is a folder, not a "
        "regular file)"
    )


# -- boundaries files -----------------------------------------------------------------------

SUBTASKS = (SubtaskSpec("grasp", "a", "g", (0, 0)), SubtaskSpec("lift", "a", "l", (0, 0)),
            SubtaskSpec("place", "b", None))  # fmt: skip


@pytest.mark.parametrize(
    ("name", "content", "expected"),
    [
        ("b.yaml", "0: [true, 7]\n1: [2, 5]\n", "demo 0: subtask 'grasp' ends at True, expected"),
        ("b.yaml", "0: [3, 7]\n1: [2, false]\n", "demo 1: subtask 'lift' ends at False, expected"),
        ("b.yaml", "0: [3.0, 7]\n1: [2, 5]\n", "demo 0: subtask 'grasp' ends at 3.0, expected"),
        ("b.yaml", "0: [3, 7]\n1: [-2, 5]\n", "demo 1: subtask 'grasp' ends at -2, expected"),
        ("b.yaml", "0: [3, '7']\n1: [2, 5]\n", "demo 0: subtask 'lift' ends at '7', expected"),
        (
            "b.yaml",
            "0: [3, 7]\n1: [2, 5]\n0: [4, 8]\n",
            "b.yaml: not valid YAML: key 0 appears twice in one mapping (lines 1 and 3)",
        ),
        (
            "b.yaml",
            "0: [3, 7]\n1: [2, 5]\n1.0: [4, 6]\n",
            "key 1 / 1.0 appears twice in one mapping (lines 2 and 3)",
        ),
        ("b.yaml", "0: [3, 7]\ntrue: [2, 5]\n", "b.yaml: key True: expected a demo index"),
        ("b.yaml", "0: [3, 7]\n-1: [2, 5]\n", "b.yaml: key -1: expected a demo index"),
        ("b.yaml", "demo_0: [3, 7]\n", "b.yaml: key 'demo_0': expected a demo index"),
        ("b.yaml", "- [3, 7]\n- [2, 5]\n", "b.yaml: expected a mapping of demo index"),
        ("b.yaml", "0: [3, 7\n", "b.yaml: not valid YAML: line 2, column 1: "),
        ("b.yaml", b"\x00\x01PK\x03\x04", "b.yaml: not valid YAML: character U+0000 at offset 0"),
        ("b.csv", b"PK\x03\x04\xff\x00", "b.csv: not UTF-8 text (byte 0xff at offset 4)"),
        ("b.csv", b"demo,grasp,lift\n0,3\x00,7\n", "b.csv: line 2: expected integers"),
        ("b.csv", "demo,grasp,lift\n0,3,7\n1,2,5\n0,4,8\n", "demo 0 given twice (lines 2 and 4)"),
        ("b.csv", "demo,grasp,lift\n0,3,7\n1,2,true\n", "line 3: expected integers"),
        ("b.csv", "demo,grasp,lift\n0,3,7\n1,2,5.0\n", "line 3: expected integers"),
        ("b.csv", "demo,grasp,lift\n0,3,7\n1,-2,5\n", "demo 1: subtask 'grasp' ends at -2"),
    ],
)
def test_a_bad_boundaries_file_is_one_error(tmp_path, name, content, expected):
    path = tmp_path / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    with pytest.raises(InputError) as exc:
        read_boundaries(path, [10, 8], SUBTASKS)
    assert expected in one_line(exc)


def test_boundaries_in_a_folder_or_missing_are_one_error(tmp_path):
    with pytest.raises(InputError, match="cannot read the boundaries file"):
        read_boundaries(tmp_path, [10, 8], SUBTASKS)
    with pytest.raises(InputError, match=r"b\.csv: boundaries file \(CSV\) not found"):
        read_boundaries(tmp_path / "b.csv", [10, 8], SUBTASKS)


def test_blank_csv_lines_are_skipped(tmp_path):
    (tmp_path / "b.csv").write_text("demo,grasp,lift\n\n0,3,7\n\n1,2,5\n\n")
    np.testing.assert_array_equal(read_boundaries(tmp_path / "b.csv", [10, 8], SUBTASKS),
                                  [[3, 7], [2, 5]])  # fmt: skip


# -- the strict YAML loader -----------------------------------------------------------------


def test_yaml_merge_keys_may_still_be_overridden(tmp_path):
    (tmp_path / "a.yaml").write_text("base: &b {x: 1, y: 2}\nother:\n  <<: *b\n  x: 5\n")
    assert load_yaml(tmp_path / "a.yaml", "file") == {
        "base": {"x": 1, "y": 2}, "other": {"x": 5, "y": 2}}  # fmt: skip


def test_yaml_never_builds_python_objects(tmp_path):
    (tmp_path / "a.yaml").write_text("a: !!python/object/apply:os.system ['true']\n")
    with pytest.raises(InputError, match="could not determine a constructor"):
        load_yaml(tmp_path / "a.yaml", "file")
