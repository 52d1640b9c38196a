"""Export (robomimic HDF5, LeRobot, ManiSkill trajectories), each read back by the format's
own library or tool; robomimic import as source demos; manual subtask annotation."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import h5py
import numpy as np
import pytest

from mimicgen_pipe import exporters
from mimicgen_pipe.errors import InputError
from mimicgen_pipe.segments import gripper_events, read_boundaries
from mimicgen_pipe.store import read_store, write_store
from mimicgen_pipe.taskspec import SubtaskSpec
from tests.conftest import REPO, cli

LENGTHS = (12, 7, 5)
OBS = {"eef_pos": 3, "cubeA_pos": 3, "gripper_qpos": 2}


def _pose_rows(rng, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return np.concatenate(
        [rng.normal(size=(n, 3)), q / np.linalg.norm(q, axis=1, keepdims=True)], 1
    )


def synthetic_store(
    path, backend: str = "maniskill", drop: tuple[str, ...] = (), task="stack_cube"
):
    """A small generated store of stack_cube with random (but well-formed) values."""
    rng = np.random.default_rng(0)
    steps = []
    for t in LENGTHS:
        ep = {
            "actions": rng.uniform(-1, 1, (t, 7)).astype(np.float32),
            "env_state": rng.normal(size=(t, 20)).astype(np.float32),
            "eef_pose": _pose_rows(rng, t),
            "target_pose": _pose_rows(rng, t),
            "object_poses/cubeA": _pose_rows(rng, t),
            "object_poses/cubeB": _pose_rows(rng, t),
            "gripper": np.where(np.arange(t) < t // 2, 1.0, -1.0).astype(np.float32),
            "subtask_signals/grasp_cubeA": np.arange(t) >= t // 2,
        }
        ep |= {f"obs/{k}": rng.normal(size=(t, d)).astype(np.float32) for k, d in OBS.items()}
        steps.append({k: v for k, v in ep.items() if k not in drop})
    n = len(LENGTHS)
    episodes = {
        "seed": np.arange(n, dtype=np.int64) + 100,
        "success": np.ones(n, bool),
        "source_demo": rng.integers(0, 10, (n, 2)),
    }
    attrs = {"task": task, "variant": "D1", "backend": backend, "robot": "panda",
             "control_mode": "pd_ee_delta_pose", "control_freq": 20}  # fmt: skip
    write_store(path, "generated", steps, episodes, attrs)
    return read_store(path)


def export_info(store):
    import envs

    spec = envs.task_spec("maniskill", "stack_cube")
    return exporters.export_info(store.attrs, spec, list(OBS), 0.34)


def test_robomimic_export_reads_back_with_robomimics_dataset_class(tmp_path):
    """robomimic's SequenceDataset gives back our actions, states and observations for every
    step of the train and valid splits; datagen_info keeps the poses as 4x4 matrices."""
    import robomimic.utils.obs_utils as obs_utils
    from robomimic.utils.dataset import SequenceDataset

    store = synthetic_store(tmp_path / "g.zarr")
    path = exporters.write(store, "robomimic", tmp_path, export_info(store))
    obs_utils.initialize_obs_utils_with_obs_specs({"obs": {"low_dim": [f"{k}" for k in OBS]}})
    seen = 0
    for split, demos in (("train", [0, 1]), ("valid", [2])):
        ds = SequenceDataset(
            hdf5_path=str(path), obs_keys=list(OBS), dataset_keys=["actions", "states"],
            seq_length=1, hdf5_cache_mode="all", filter_by_attribute=split,
        )  # fmt: skip
        assert len(ds) == sum(LENGTHS[i] for i in demos)
        k = 0
        for i in demos:
            ep = store.episode(i)
            for t in range(LENGTHS[i]):
                sample = ds[k]
                np.testing.assert_array_equal(sample["actions"][0], ep["actions"][t])
                np.testing.assert_array_equal(sample["states"][0], ep["env_state"][t])
                for key in OBS:
                    np.testing.assert_array_equal(sample["obs"][key][0], ep[f"obs/{key}"][t])
                k += 1
        seen += k
    assert seen == sum(LENGTHS)
    with h5py.File(path, "r") as f:
        assert f["data"].attrs["total"] == sum(LENGTHS)
        env_args = json.loads(f["data"].attrs["env_args"])
        assert env_args["env_kwargs"] == {"backend": "maniskill", "task": "stack_cube",
                                          "robot": "panda"}  # fmt: skip
        info = f["data/demo_1/datagen_info"]
        np.testing.assert_allclose(info["eef_pose"][:], store.poses("eef_pose")[12:19])
        np.testing.assert_allclose(
            info["object_poses/cubeB"][3], store.poses("object_poses/cubeB")[15]
        )
        np.testing.assert_array_equal(
            info["subtask_term_signals/grasp_cubeA"][:], [0, 0, 0, 1, 1, 1, 1]
        )
        np.testing.assert_array_equal(info["gripper_action"][:, 0], store.episode(1)["gripper"])
        np.testing.assert_array_equal(
            f["data/demo_2/src_demo_inds"][:], store.episodes["source_demo"][2]
        )
        assert f["data/demo_0"].attrs["num_samples"] == 12


LEROBOT = REPO / "tests/lerobot"


def test_lerobot_export_loads_with_lerobots_dataset_class(tmp_path):
    """lerobot 0.4.4's LeRobotDataset (in its own venv, offline) reads every frame back:
    action and observation.state equal ours, episode lengths, names, fps and task string."""
    python = REPO / ".venv-lerobot/bin/python"
    assert python.exists(), "the LeRobot check venv is missing: run scripts/setup.sh"
    store = synthetic_store(tmp_path / "g.zarr")
    info = export_info(store)
    path = exporters.write(store, "lerobot", tmp_path, info)
    state = np.concatenate([store.data[f"obs/{k}"] for k in OBS], axis=1)
    lengths = store.lengths
    np.savez(tmp_path / "expected.npz", action=store.data["actions"], state=state,
             lengths=lengths, episode_index=np.repeat(np.arange(len(LENGTHS)), lengths),
             fps=20, task=info.task_description, action_names=exporters.lerobot.ACTION_NAMES,
             state_names=exporters.lerobot.state_names(store, list(OBS)))  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env |= {"PYTHONPATH": str(LEROBOT / "stubs"), "HF_HOME": str(tmp_path / "hf")}
    res = subprocess.run(
        [str(python), str(LEROBOT / "check_dataset.py"), str(path), str(tmp_path / "expected.npz")],
        capture_output=True, text=True, env=env,
    )  # fmt: skip
    assert res.returncode == 0 and res.stdout.strip().endswith("ok"), res.stderr[-3000:]
    assert info.task_description == "stack_cube: grasp cubeA, then place on cubeB"


def test_robomimic_file_reads_back_as_source_demos(tmp_path):
    store = synthetic_store(tmp_path / "g.zarr")
    path = exporters.write(store, "robomimic", tmp_path, export_info(store))
    demos = exporters.robomimic.read(path, "maniskill", "stack_cube")
    assert [d.seed for d in demos] == [100, 101, 102]
    for i, d in enumerate(demos):
        np.testing.assert_array_equal(d.actions, store.episode(i)["actions"])
        np.testing.assert_array_equal(d.initial_state, store.episode(i)["env_state"][0])
    with pytest.raises(InputError, match="expected 'pybullet'/'stack_cube'"):
        exporters.robomimic.read(path, "pybullet", "stack_cube")


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--formats", "robomimic,hdf6"], "export format 'hdf6': unknown (known: lerobot"),
        (
            [
                "--formats",
                "maniskill",
                "--store",
                "pb.zarr",
                "--backend",
                "pybullet",
                "--task",
                "stack",
            ],  # fmt: skip
            "cannot export as maniskill: a pybullet",
        ),
        (["--formats", "robomimic", "--store", "nostate.zarr"], "no data/env_state"),
        (["--formats", "robomimic"], "give either --variant"),
    ],
)
def test_export_bad_input_is_one_error_before_anything_is_written(tmp_path, args, expected):
    (tmp_path / "params.yaml").write_text("task: stack_cube\nexport: {workers: 1}\n")
    synthetic_store(tmp_path / "input" / "g.zarr")
    synthetic_store(tmp_path / "pb.zarr", backend="pybullet", task="stack")
    synthetic_store(tmp_path / "nostate.zarr", drop=("env_state",))
    if "--store" not in args and "give either" not in expected:
        args = [*args, "--store", "input/g.zarr"]
    res = cli("export", *args, "--out", "out", cwd=tmp_path, check=False)
    assert res.returncode == 2, res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and expected in lines[0], res.stderr
    assert not (tmp_path / "out").exists() and not (tmp_path / "metrics").exists()


def test_unknown_format_in_params_is_rejected_at_load(tmp_path):
    (tmp_path / "params.yaml").write_text(
        "task: stack_cube\nexport: {formats: [robomimic, rlds]}\n"
    )
    res = cli("export", "--variant", "D0", cwd=tmp_path, check=False)
    assert res.returncode == 2 and "export.formats" in res.stderr and "rlds" in res.stderr


# -- manual subtask annotation ------------------------------------------------------------

SUBTASKS = (SubtaskSpec("grasp", "a", "g", (0, 0)), SubtaskSpec("lift", "a", "l", (0, 0)),
            SubtaskSpec("place", "b", None))  # fmt: skip


def test_gripper_events_are_the_steps_where_the_gripper_action_changes_sign():
    assert gripper_events(np.array([1, 1, -1, -1, -1, 1, 1, -1])) == [
        (2, "close"), (5, "open"), (7, "close")]  # fmt: skip


def test_boundaries_from_yaml_and_csv_agree(tmp_path):
    (tmp_path / "b.yaml").write_text("0: [3, 7]\n1: [2, 5]\n")
    (tmp_path / "b.csv").write_text("demo,grasp,lift\n1,2,5\n0,3,7\n")
    a = read_boundaries(tmp_path / "b.yaml", [10, 8], SUBTASKS)
    b = read_boundaries(tmp_path / "b.csv", [10, 8], SUBTASKS)
    np.testing.assert_array_equal(a, [[3, 7], [2, 5]])
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("0: [3, 7]\n", "demo 1: no boundaries"),
        ("0: [3, 7]\n1: [2]\n", "demo 1: no end for subtask 'lift'"),
        ("0: [3, 7]\n1: [2, 8]\n", "demo 1: subtask 'lift' ends at 8, expected a step in 1..7"),
        (
            "0: [3, 7]\n1: [5, 4]\n",
            "demo 1: subtask 'lift' ends at 4, not after the previous end 5",
        ),
        ("0: [3, 7]\n1: [2, 5]\n4: [1, 2]\n", "demos [4] are not in the store"),
        ("0: [3, 7, 9]\n1: [2, 5]\n", "demo 0: 3 ends, expected 2"),
    ],
)
def test_bad_boundaries_name_the_demo_and_subtask(tmp_path, text, expected):
    (tmp_path / "b.yaml").write_text(text)
    with pytest.raises(InputError, match=re.escape(expected)):
        read_boundaries(tmp_path / "b.yaml", [10, 8], SUBTASKS)


@pytest.mark.sim
def test_annotated_parse_equals_the_signal_parse(pipeline, tmp_path):
    """Source demos with their term signals removed, plus a boundaries file with the ends
    the signals give, parse into the same store (less the signals); a boundary past a demo's
    end is one error and writes nothing."""
    source = read_store(pipeline / "data/source/stack_cube.zarr")
    parsed = read_store(pipeline / "data/parsed/stack_cube.zarr")
    steps = [{k: v for k, v in source.episode(i).items() if not k.startswith("subtask_signals/")}
             for i in range(source.n_episodes)]  # fmt: skip
    write_store(tmp_path / "bare.zarr", "source", steps, source.episodes, source.attrs)
    ends = parsed.episodes["subtask_term_index"]
    (tmp_path / "ends.yaml").write_text("".join(f"{i}: {e.tolist()}\n" for i, e in enumerate(ends)))
    (tmp_path / "params.yaml").write_text("task: stack_cube\nexport: {workers: 1}\n")
    cli(
        "parse",
        "--source",
        "bare.zarr",
        "--boundaries",
        "ends.yaml",
        "--out",
        "p.zarr",
        cwd=tmp_path,
    )
    got = read_store(tmp_path / "p.zarr", kind="parsed")
    assert set(got.data) == {k for k in parsed.data if not k.startswith("subtask_signals/")}
    for key, value in got.data.items():
        np.testing.assert_array_equal(value, parsed.data[key], err_msg=key)
    for key, value in parsed.episodes.items():
        np.testing.assert_array_equal(got.episodes[key], value, err_msg=key)
    assert got.attrs["subtasks"] == parsed.attrs["subtasks"]
    length0 = int(source.episode_ends[0])
    (tmp_path / "bad.yaml").write_text(f"0: [{length0}]\n1: [40]\n2: [40]\n")
    res = cli("parse", "--source", "bare.zarr", "--boundaries", "bad.yaml", "--out", "q.zarr",
              cwd=tmp_path, check=False)  # fmt: skip
    assert res.returncode == 2 and "demo 0: subtask 'grasp_cubeA' ends at" in res.stderr
    assert not (tmp_path / "q.zarr").exists()


# -- on the simulator ---------------------------------------------------------------------


def maniskill_replay(traj, *extra):
    """ManiSkill's own replay tool on ``traj``; returns (replayed, successful)."""
    env = dict(os.environ, MS_SKIP_ASSET_DOWNLOAD_PROMPT="1")
    res = subprocess.run(
        [sys.executable, "-m", "mani_skill.trajectory.replay_trajectory", "--traj-path",
         str(traj), "--use-first-env-state", "-b", "physx_cpu", *extra],
        capture_output=True, text=True, env=env, cwd=traj.parent,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    m = re.search(r"Replayed (\d+) episodes, (\d+)/", res.stdout + res.stderr)
    assert m, res.stdout[-2000:]
    return int(m.group(1)), int(m.group(2))


@pytest.mark.sim
def test_maniskill_export_replays_in_maniskills_own_tool(pipeline):
    """Every exported episode replays to success with ManiSkill's replay_trajectory, both the
    delta-pose file and its pd_joint_pos copy, and the pd_joint_pos copy converts with -c;
    actions and first states are ours."""
    cli("export", "--variant", "D1", "--formats", "maniskill,robomimic", cwd=pipeline)
    out = pipeline / "data/export/stack_cube_D1"
    store = read_store(pipeline / "data/generated/stack_cube_D1.zarr")
    n = store.n_episodes
    metrics = json.loads((pipeline / "metrics/export_stack_cube_D1.json").read_text())
    assert metrics["episodes"] == n and metrics["maniskill_replay_success"] == 1.0
    with h5py.File(out / "trajectory.h5", "r") as f:
        assert sorted(f) == [f"traj_{i}" for i in range(n)]
        for i in range(n):
            np.testing.assert_array_equal(f[f"traj_{i}/actions"][:], store.episode(i)["actions"])
            robot = f[f"traj_{i}/env_states/articulations/panda"]
            assert robot.shape[0] == len(store.episode(i)["actions"]) + 1
            np.testing.assert_array_equal(robot[0], store.episode(i)["env_state"][0][-31:])
    meta = json.loads((out / "trajectory.json").read_text())
    assert meta["env_info"]["env_id"] == "StackCube-v1"
    assert [e["elapsed_steps"] for e in meta["episodes"]] == np.diff(
        np.concatenate([[0], store.episode_ends])).tolist()  # fmt: skip
    assert maniskill_replay(out / "trajectory.h5") == (n, n)
    assert maniskill_replay(out / "trajectory.pd_joint_pos.h5") == (n, n)
    replayed, ok = maniskill_replay(
        out / "trajectory.pd_joint_pos.h5", "-c", "pd_ee_delta_pose", "--save-traj", "-o", "none"
    )
    assert replayed == n and ok >= 1
    assert list(out.glob("trajectory*.none.pd_ee_delta_pose.*.h5"))  # the tool names it


@pytest.mark.sim
def test_robomimic_round_trip_generates_the_same_dataset(pipeline, tmp_path):
    """export robomimic of the source demos -> source.from_file -> parse -> generate: the
    same source actions and the same DGR as from the original source store."""
    cli("export", "--store", "data/source/stack_cube.zarr", "--formats", "robomimic",
        "--out", "data/export/source", "--metrics", "metrics/export_source.json",
        cwd=pipeline)  # fmt: skip
    params = (
        (pipeline / "params.yaml")
        .read_text()
        .replace("seed: 0}", f"seed: 0, from_file: {pipeline}/data/export/source/demos.hdf5}}")
    )
    (tmp_path / "params.yaml").write_text(params)
    for stage in ("source", "parse", "pose_noise"):
        cli(stage, cwd=tmp_path)
    cli("generate", "--variant", "D1", cwd=tmp_path)
    before = read_store(pipeline / "data/source/stack_cube.zarr")
    after = read_store(tmp_path / "data/source/stack_cube.zarr")
    np.testing.assert_array_equal(after.data["actions"], before.data["actions"])
    np.testing.assert_array_equal(after.episodes["seed"], before.episodes["seed"])
    m0 = json.loads((pipeline / "metrics/generate_stack_cube_D1.json").read_text())
    m1 = json.loads((tmp_path / "metrics/generate_stack_cube_D1.json").read_text())
    assert (m1["attempts"], m1["successes"]) == (m0["attempts"], m0["successes"])
