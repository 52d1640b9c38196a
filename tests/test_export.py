"""Export (robomimic HDF5, LeRobot, ManiSkill trajectories), each read back by the format's
own library or tool, camera images and subtask labels included; robomimic import as source
demos; manual subtask annotation."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import subprocess
import sys

import h5py
import numpy as np
import pytest

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.taskspec import SubtaskSpec
from mimicgen_pipe.data.metrics import IDENTITY_FIELDS, is_timing
from mimicgen_pipe.data.store import read_store, store_cameras, write_store
from mimicgen_pipe.formats import exporters
from mimicgen_pipe.method.segments import gripper_events, read_boundaries
from mimicgen_pipe.sources import robomimic_source
from tests.conftest import REPO, cli

LENGTHS = (12, 7, 5)
OBS = {"eef_pos": 3, "eef_quat": 4, "cubeA_pos": 3, "cubeA_quat": 4, "gripper_qpos": 2}
# the quaternions the simulator read (wxyz) of the poses they observe: obs/<key> = the pose's
QUAT_POSES = {"eef_quat": "eef_pose", "cubeA_quat": "object_poses/cubeA"}
RUN_ID = "0123456789abcdef"  # the synthetic store's run id and the params that made it
GENERATE_PARAMS = {"generate": {"mode": "fixed_attempts", "seed": 0}, "pose_noise": {"level": 0}}
# (height, width): both cameras one size, as LeRobot's Diffusion policy wants them
CAMERAS = {"agentview": (84, 96), "eye_in_hand": (84, 96)}
SUBTASK_STARTS = [t // 2 for t in LENGTHS]  # where grasp_cubeA's signal rises: place_on_cubeB


def _images(n: int, h: int, w: int, seed: int) -> np.ndarray:
    """(n, h, w, 3) uint8: smooth gradients, a blue level that changes by 24 a step and a square
    that moves by 5 pixels a step (what a video codec keeps well, each frame far from the
    next), different for every seed."""
    y, x = np.mgrid[0:h, 0:w]
    out = np.empty((n, h, w, 3), np.uint8)
    for t in range(n):
        out[t, ..., 0] = (2 * x + 40 * seed) % 256
        out[t, ..., 1] = (2 * y + 60 * seed) % 256
        out[t, ..., 2] = (24 * t + 20 * seed) % 200
        out[t, 8:24, 5 * t % (w - 16) :][:, :16] = (250, 250, 30)
    return out


# the export stage's params for the synthetic stores (which record these observations only,
# and random states no simulator can restore: no success evaluated per step)
PARAMS = (
    "task: stack_cube\nexport: {workers: 1, step_success: false}\n"
    f"train: {{obs_keys: [{', '.join(OBS)}]}}\n"
)


def _pose_rows(rng, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return np.concatenate(
        [rng.normal(size=(n, 3)), q / np.linalg.norm(q, axis=1, keepdims=True)], 1
    )


def synthetic_store(
    path,
    backend: str = "maniskill",
    drop: tuple[str, ...] = (),
    task="stack_cube",
    cameras: dict[str, tuple[int, int]] | None = None,
):
    """A small generated store of stack_cube with random (but well-formed) values, with
    ``cameras``' images (an observed store) when given; read as the export stage reads it."""
    rng = np.random.default_rng(0)
    steps = []
    for i, t in enumerate(LENGTHS):
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
        ep |= {f"obs/{k}": ep[pose][:, 3:].astype(np.float32) for k, pose in QUAT_POSES.items()}
        for j, (c, (h, w)) in enumerate((cameras or {}).items()):
            ep[f"obs/{c}_image"] = _images(t, h, w, seed=2 * i + j)
        steps.append({k: v for k, v in ep.items() if k not in drop})
    n = len(LENGTHS)
    episodes = {
        "seed": np.arange(n, dtype=np.int64) + 100,
        "success": np.ones(n, bool),
        "source_demo": rng.integers(0, 10, (n, 2)),
    }
    attrs = {"task": task, "variant": "D1", "backend": backend, "robot": "panda",
             "control_mode": "pd_ee_delta_pose", "control_freq": 20, "run_id": RUN_ID,
             "params": GENERATE_PARAMS}  # fmt: skip
    if cameras:
        from mimicgen_pipe.core.cameras import calibration

        attrs["cameras"] = {c: {"height": h, "width": w} for c, (h, w) in cameras.items()}
        attrs["camera_calibration"] = {c: calibration(c, h, w) for c, (h, w) in cameras.items()}
    write_store(path, "generated", steps, episodes, attrs)
    return exporters.read(path, task)


def export_info(store):
    from mimicgen_pipe import backends

    spec = backends.task_spec("maniskill", "stack_cube")
    return exporters.export_info(store.attrs, spec, list(OBS), 0.34)


# MimicGen's (robosuite's) names of the synthetic store's observations in the robomimic export
# (their name -> the keys of ours it concatenates)
MIMICGEN_OBS = {"robot0_eef_pos": ("eef_pos",), "robot0_eef_quat": ("eef_quat",),
                "cubeA_pos": ("cubeA_pos",), "cubeA_quat": ("cubeA_quat",),
                "robot0_gripper_qpos": ("gripper_qpos",),
                "object": ("cubeA_pos", "cubeA_quat")}  # fmt: skip
MIMICGEN_CAMERAS = {"agentview_image": "agentview", "robot0_eye_in_hand_image": "eye_in_hand"}


XYZW = [1, 2, 3, 0]  # a wxyz quaternion's components in robosuite's order, xyzw


def mimicgen_obs(ep: dict, t: int, key: str) -> np.ndarray:
    """Step ``t``'s value of the robomimic export's ``obs/<key>`` from the episode's arrays
    (quaternions reordered to robosuite's xyzw)."""
    rows = [ep[f"obs/{ours}"][t] for ours in MIMICGEN_OBS[key]]
    ours = MIMICGEN_OBS[key]
    return np.concatenate(
        [r[XYZW] if o in QUAT_POSES else r for o, r in zip(ours, rows, strict=True)]
    )


# the task's success after each step: episode 0 from 3 steps before its end, episode 1 at its
# end only, episode 2 once on the way (step 2) and at its end
STEP_SUCCESS = np.concatenate(
    [np.arange(12) >= 9, np.arange(7) == 6, np.isin(np.arange(5), [2, 4])]
)


def test_robomimic_export_reads_back_with_robomimics_dataset_class(tmp_path):
    """robomimic's SequenceDataset, asked for MimicGen's observation keys (robot0_eef_pos,
    robot0_gripper_qpos, object, agentview_image, robot0_eye_in_hand_image), gives back our
    actions, states, subtask labels, rewards and dones, low-dim observations and camera
    images (next_obs too) for every step of the train and valid splits; datagen_info keeps
    the poses as 4x4 matrices; env_args name the cameras and their size as robomimic's
    env_meta does, and the cameras' calibration is the store's."""
    import robomimic.utils.obs_utils as obs_utils
    from robomimic.utils.dataset import SequenceDataset

    store = synthetic_store(tmp_path / "g.zarr", cameras=CAMERAS)
    path, figures = exporters.write(
        store, "robomimic", tmp_path, export_info(store), step_success=STEP_SUCCESS
    )
    images = {k: np.concatenate(list(exporters.episode_images(store, c)))
              for k, c in MIMICGEN_CAMERAS.items()}  # fmt: skip
    labels = np.concatenate(
        [np.arange(t) >= s for t, s in zip(LENGTHS, SUBTASK_STARTS, strict=True)]
    ).astype(np.int64)
    dones = STEP_SUCCESS | np.isin(np.arange(sum(LENGTHS)), np.cumsum(LENGTHS) - 1)
    obs_utils.initialize_obs_utils_with_obs_specs(
        {"obs": {"low_dim": list(MIMICGEN_OBS), "rgb": list(images)}}
    )
    seen = 0
    for split, demos in (("train", [0, 1]), ("valid", [2])):
        ds = SequenceDataset(
            hdf5_path=str(path), obs_keys=[*MIMICGEN_OBS, *images],
            dataset_keys=["actions", "states", "subtask_index", "rewards", "dones"],
            seq_length=1, hdf5_cache_mode="all", filter_by_attribute=split,
        )  # fmt: skip
        assert len(ds) == sum(LENGTHS[i] for i in demos)
        k = 0
        for i in demos:
            ep = store.episode(i)
            start = store.episode_starts[i]
            for t in range(LENGTHS[i]):
                sample = ds[k]
                np.testing.assert_array_equal(sample["actions"][0], ep["actions"][t])
                np.testing.assert_array_equal(sample["states"][0], ep["env_state"][t])
                assert sample["subtask_index"][0] == labels[start + t]
                assert sample["rewards"][0] == float(STEP_SUCCESS[start + t])
                assert sample["dones"][0] == float(dones[start + t])
                for key in MIMICGEN_OBS:
                    np.testing.assert_array_equal(sample["obs"][key][0], mimicgen_obs(ep, t, key))
                for key, value in images.items():
                    np.testing.assert_array_equal(sample["obs"][key][0], value[start + t])
                    nxt = value[start + min(t + 1, LENGTHS[i] - 1)]
                    np.testing.assert_array_equal(sample["next_obs"][key][0], nxt)
                k += 1
        seen += k
    assert seen == sum(LENGTHS)
    with h5py.File(path, "r") as f:
        assert json.loads(f["data"].attrs["subtasks"]) == ["grasp_cubeA", "place_on_cubeB"]
        image = f["data/demo_0/obs/agentview_image"]
        assert image.dtype == np.uint8 and image.shape == (12, 84, 96, 3)
        assert image.chunks == (4, 84, 96, 3) and image.compression == "gzip"
        assert f["data/demo_0/next_obs/agentview_image"].is_virtual  # no second copy
        stored = sum(f[f"data/demo_{i}/obs/{k}"].id.get_storage_size()
                     for i in range(3) for k in images)  # fmt: skip
        assert figures == {"image_bytes": stored}
        assert f["data"].attrs["total"] == sum(LENGTHS)
        env_args = json.loads(f["data"].attrs["env_args"])
        assert env_args["env_kwargs"] == {
            "backend": "maniskill", "task": "stack_cube", "robot": "panda",
            "camera_names": ["agentview", "robot0_eye_in_hand"], "camera_heights": 84,
            "camera_widths": 96,
        }  # fmt: skip
        assert json.loads(f["data"].attrs["object_keys"]) == ["cubeA_pos", "cubeA_quat"]
        calibration = json.loads(f["data"].attrs["camera_calibration"])
        theirs = store.attrs["camera_calibration"]
        assert calibration == {k.removesuffix("_image"): theirs[c]
                               for k, c in MIMICGEN_CAMERAS.items()}  # fmt: skip
        assert f["data/demo_0/rewards"].dtype == np.float64
        assert f["data/demo_0/dones"].dtype == np.int64
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


def test_robomimic_quaternions_are_robosuites_xyzw_and_the_file_says_what_it_holds(tmp_path):
    """robot0_eef_quat (and every object quaternion, in obs/object too) is robosuite's xyzw:
    the store's eef pose rotation converted by scipy (scalar last), and the simulator's wxyz
    read reordered. data.attrs["mimicgen_pipe"] records what made the file and its
    conventions (xyzw); robomimic's own env_meta reader finds robomimic's fields, of a
    non-robosuite env, with a note saying robomimic cannot build it."""
    import robomimic.utils.env_utils as env_utils
    from scipy.spatial.transform import Rotation

    store = synthetic_store(tmp_path / "g.zarr")
    path, _ = exporters.write(store, "robomimic", tmp_path, export_info(store))
    rotations = {k: store.poses(pose)[:, :3, :3] for k, pose in QUAT_POSES.items()}
    with h5py.File(path, "r") as f:

        def rows(name: str) -> np.ndarray:
            return np.concatenate([f[f"data/demo_{i}/obs/{name}"][:] for i in range(3)])

        written = {"eef_quat": rows("robot0_eef_quat"), "cubeA_quat": rows("cubeA_quat")}
        obj = rows("object")
        made = json.loads(f["data"].attrs["mimicgen_pipe"])
        # as robomimic's FileUtils.get_env_metadata_from_dataset reads it
        env_meta = json.loads(f["data"].attrs["env_args"])
    np.testing.assert_array_equal(obj[:, 3:7], written["cubeA_quat"])  # after cubeA_pos
    for key, quat in written.items():
        np.testing.assert_array_equal(quat, store.data[f"obs/{key}"][:, XYZW])
        scipy_xyzw = Rotation.from_matrix(rotations[key]).as_quat()
        sign = np.sign(np.sum(scipy_xyzw * quat, axis=1, keepdims=True))  # q and -q agree
        np.testing.assert_allclose(quat, sign * scipy_xyzw, atol=1e-6)
        assert not np.allclose(quat, store.data[f"obs/{key}"], atol=1e-3)  # not wxyz
    assert made == provenance(quaternion_order="xyzw")
    assert not env_utils.is_robosuite_env(env_meta=env_meta)
    assert (env_meta["env_name"], env_meta["type"]) == ("maniskill:stack_cube", 2)
    assert env_meta["env_kwargs"] == {"backend": "maniskill", "task": "stack_cube",
                                      "robot": "panda"}  # fmt: skip
    assert "not a robosuite or gym env" in env_meta["note"]
    assert "robomimic cannot build it" in env_meta["note"]


LEARNERS = REPO / "tests/learners"  # scripts run in the learners' check venv
# LeRobot's per-dimension names of the synthetic store's observation.state and
# environment_state: each quaternion component named, in the order written (wxyz)
STATE_NAMES = ["eef_pos.x", "eef_pos.y", "eef_pos.z", "eef_quat.qw", "eef_quat.qx",
               "eef_quat.qy", "eef_quat.qz", "gripper_qpos.x", "gripper_qpos.y"]  # fmt: skip
ENV_STATE_NAMES = ["cubeA_pos.x", "cubeA_pos.y", "cubeA_pos.z", "cubeA_quat.qw",
                   "cubeA_quat.qx", "cubeA_quat.qy", "cubeA_quat.qz"]  # fmt: skip


def provenance(quaternion_order="wxyz", control_mode="pd_ee_delta_pose") -> dict:
    """What an export of the synthetic store records about it under "mimicgen_pipe"."""
    import importlib.metadata

    return {
        "tool": "mimicgen-pipe", "tool_version": importlib.metadata.version("mimicgen-pipe"),
        "kind": "generated", "run_id": RUN_ID, "task": "stack_cube", "variant": "D1",
        "backend": "maniskill", "robot": "panda", "params": GENERATE_PARAMS,
        "conventions": {
            "quaternion_order": quaternion_order, "pose_frame": "world",
            "units": {"length": "m", "angle": "rad", "time": "s"},
            "control_mode": control_mode, "control_freq_hz": 20,
        },
    }  # fmt: skip


def _lerobot_check(tmp_path, store, *flags: str) -> subprocess.CompletedProcess:
    """Export ``store`` as LeRobot and run tests/learners/check_dataset.py on it in the
    learners' check venv, with the arrays it must find."""
    python = REPO / ".venv-learners/bin/python"
    assert python.exists(), "the learners' check venv is missing: run scripts/setup.sh"
    info = export_info(store)
    path, _ = exporters.write(store, "lerobot", tmp_path, info, step_success=STEP_SUCCESS)
    lengths = store.lengths
    obs = {k: store.data[f"obs/{k}"] for k in OBS}
    videos = {
        f"images/observation.images.{c}": np.concatenate(list(exporters.episode_images(store, c)))
        for c in store_cameras(store.attrs)
    }
    calibration = {
        f"calibration/observation.images.{c}/{part}": np.array(v[part])
        for c, v in store.attrs["camera_calibration"].items() for part in ("intrinsics", "pose")
    }  # fmt: skip
    dones = STEP_SUCCESS | np.isin(np.arange(sum(LENGTHS)), np.cumsum(LENGTHS) - 1)
    outcomes = {"next.reward": STEP_SUCCESS.astype(np.float32), "next.done": dones,
                "next.success": STEP_SUCCESS}  # fmt: skip
    np.savez(tmp_path / "expected.npz", action=store.data["actions"],
             state=np.concatenate([obs["eef_pos"], obs["eef_quat"], obs["gripper_qpos"]], 1),
             env_state=np.concatenate([obs["cubeA_pos"], obs["cubeA_quat"]], 1), lengths=lengths,
             episode_index=np.repeat(np.arange(len(LENGTHS)), lengths),
             subtask_index=exporters.subtask_labels(store, info.subtasks),
             subtasks=["grasp cubeA", "place on cubeB"], fps=20, task=info.task_description,
             action_names=list(exporters.ACTION_NAMES),
             state_names=STATE_NAMES, env_state_names=ENV_STATE_NAMES,
             provenance=json.dumps(provenance()),
             video_keys=[k.removeprefix("images/") for k in videos], **videos,
             **calibration, **outcomes)  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env |= {"HF_HOME": str(tmp_path / "hf")}
    return subprocess.run(
        [str(python), str(LEARNERS / "check_dataset.py"), str(path), str(tmp_path / "expected.npz"),
         *flags],
        capture_output=True, text=True, env=env,
    )  # fmt: skip


def test_lerobot_export_loads_with_lerobots_dataset_class(tmp_path):
    """lerobot 0.4.4's LeRobotDataset (in its own venv, offline) reads every frame back:
    action, observation.state (robot) and observation.environment_state (objects) equal
    ours, subtask_index and its subtask string, next.reward, next.done and next.success
    (success after the step, done on success or at the episode's end), each camera's frame
    decoded from the video near ours and nearer than any other frame of the episode; episode
    lengths, names, fps, image stats, each camera's calibration in its feature's info and the
    task string."""
    store = synthetic_store(tmp_path / "g.zarr", cameras=CAMERAS)
    res = _lerobot_check(tmp_path, store)
    assert res.returncode == 0 and res.stdout.strip().endswith("ok"), res.stderr[-3000:]
    assert export_info(store).task_description == "stack_cube: grasp cubeA, then place on cubeB"


def test_lerobot_export_passes_act_and_diffusion_feature_checks(tmp_path):
    """LeRobot's ACT and Diffusion configs, given our dataset's features as lerobot-train
    splits them, pass their own feature checks (images and environment state as inputs)."""
    store = synthetic_store(tmp_path / "g.zarr", cameras=CAMERAS)
    res = _lerobot_check(tmp_path, store, "--policies")
    assert res.returncode == 0 and res.stdout.strip().endswith("ok"), res.stderr[-3000:]


def test_lerobot_layout_is_lerobots_and_the_same_bytes_every_time(tmp_path):
    """One AV1 video per camera with LeRobot's video info, each episode's span in it, image
    stats per channel in [0, 1], the subtask table; a second export of the same store is the
    same bytes, file for file. A store without images gives no videos."""
    import pyarrow.parquet as pq

    store = synthetic_store(tmp_path / "g.zarr", cameras=CAMERAS)
    info = export_info(store)
    path, figures = exporters.write(store, "lerobot", tmp_path / "a", info)
    again, _ = exporters.write(store, "lerobot", tmp_path / "b", info)
    files = sorted(p.relative_to(path) for p in path.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    for f in files:
        assert (path / f).read_bytes() == (again / f).read_bytes(), f
    videos = sorted(str(f) for f in files if f.suffix == ".mp4")
    assert videos == [f"videos/observation.images.{c}/chunk-000/file-000.mp4" for c in CAMERAS]
    assert figures == {"image_bytes": sum((path / v).stat().st_size for v in videos)}
    meta = json.loads((path / "meta/info.json").read_text())
    feature = meta["features"]["observation.images.agentview"]
    assert feature["dtype"] == "video" and feature["shape"] == [*CAMERAS["agentview"], 3]
    assert feature["info"]["video.codec"] == "av1" and feature["info"]["video.fps"] == 20
    assert meta["video_path"] == exporters.lerobot.VIDEO_PATH
    assert meta["features"]["subtask_index"] == {"dtype": "int64", "shape": [1], "names": None}
    assert meta["features"]["observation.environment_state"]["names"] == ENV_STATE_NAMES
    assert meta["features"]["observation.state"]["names"] == STATE_NAMES
    assert meta["mimicgen_pipe"] == provenance()
    card = (path / "README.md").read_text()
    assert card.startswith("---\ntask_categories:\n- robotics\n")
    for words in (
        f"run id `{RUN_ID}`",
        info.task_description,
        "Quaternions wxyz",
        "agentview (84x96 px)",
        "**Episodes:** 3",
        "pd_ee_delta_pose at 20 Hz",
    ):
        assert words in card, words  # fmt: skip
    episodes = pq.read_table(path / exporters.lerobot.EPISODES_PATH).to_pydict()
    key = "videos/observation.images.eye_in_hand"
    ends = np.cumsum(LENGTHS) / 20
    np.testing.assert_allclose(episodes[f"{key}/from_timestamp"], [0, *ends[:-1]])
    np.testing.assert_allclose(episodes[f"{key}/to_timestamp"], ends)
    stats = json.loads((path / "meta/stats.json").read_text())["observation.images.agentview"]
    mean = np.array(stats["mean"])
    assert mean.shape == (3, 1, 1) and stats["count"] == [sum(LENGTHS)]
    assert 0 <= np.min(stats["min"]) and np.max(stats["max"]) <= 1
    images = np.concatenate(list(exporters.episode_images(store, "agentview")))
    np.testing.assert_allclose(mean[:, 0, 0], images.reshape(-1, 3).mean(0) / 255)
    median = episodes["stats/observation.images.agentview/q50"][0]  # episode 0's, LeRobot's way
    pixels = images[: LENGTHS[0]].reshape(-1, 3) / 255
    np.testing.assert_allclose(np.ravel(median), np.quantile(pixels, 0.5, axis=0))
    subtasks = pq.read_table(path / "meta/subtasks.parquet").to_pydict()
    assert subtasks == {"subtask_index": [0, 1], "subtask": ["grasp cubeA", "place on cubeB"]}
    frames = pq.read_table(path / "data/chunk-000/file-000.parquet")
    np.testing.assert_array_equal(
        frames["subtask_index"].to_numpy(), exporters.subtask_labels(store, info.subtasks)
    )
    plain = synthetic_store(tmp_path / "plain.zarr")
    path, figures = exporters.write(plain, "lerobot", tmp_path / "c", export_info(plain))
    assert figures == {"image_bytes": 0} and not (path / "videos").exists()
    assert json.loads((path / "meta/info.json").read_text())["video_path"] is None


def test_lerobot_videos_go_on_in_a_new_file_past_the_file_size(tmp_path, monkeypatch):
    """Past video_files_size_in_mb the next episode starts the next file, at time 0, as
    LeRobot numbers files; its frames are the episode's."""
    import av

    monkeypatch.setattr(exporters.lerobot, "VIDEO_FILE_MB", 0)  # every episode its own file
    store = synthetic_store(tmp_path / "g.zarr", cameras=CAMERAS)
    path, _ = exporters.write(store, "lerobot", tmp_path, export_info(store))
    episodes = pq_dict(path / exporters.lerobot.EPISODES_PATH)
    key = "videos/observation.images.agentview"
    assert episodes[f"{key}/file_index"] == [0, 1, 2]
    assert episodes[f"{key}/chunk_index"] == [0, 0, 0]
    assert episodes[f"{key}/from_timestamp"] == [0.0, 0.0, 0.0]
    np.testing.assert_allclose(episodes[f"{key}/to_timestamp"], np.array(LENGTHS) / 20)
    with av.open(str(path / "videos/observation.images.agentview/chunk-000/file-002.mp4")) as f:
        assert sum(1 for _ in f.decode(video=0)) == LENGTHS[2]


def pq_dict(path) -> dict[str, list]:
    import pyarrow.parquet as pq

    return pq.read_table(path).to_pydict()


def test_subtask_labels_come_from_subtask_ends_or_term_signals(tmp_path):
    """Each step's subtask: from meta/episodes/subtask_term_index where the store has it,
    else from the term signal's first rise; None from a store with neither."""
    spec = export_info(synthetic_store(tmp_path / "g.zarr")).subtasks
    store = synthetic_store(tmp_path / "g.zarr")
    expected = np.concatenate([np.arange(t) >= s for t, s in zip(LENGTHS, SUBTASK_STARTS,
                                                                 strict=True)])  # fmt: skip
    np.testing.assert_array_equal(exporters.subtask_labels(store, spec), expected)
    ends = np.array([[3], [5], [1]])
    parsed = dataclasses.replace(store, episodes={**store.episodes, "subtask_term_index": ends})
    by_ends = np.concatenate([np.arange(t) >= e for t, e in zip(LENGTHS, ends[:, 0],
                                                                strict=True)])  # fmt: skip
    np.testing.assert_array_equal(exporters.subtask_labels(parsed, spec), by_ends)
    bare = synthetic_store(tmp_path / "bare.zarr", drop=("subtask_signals/grasp_cubeA",))
    assert exporters.subtask_labels(bare, spec) is None


def fake_replays(store) -> dict:
    """The ManiSkill exporter's replay arguments for a synthetic store, standing in for the
    simulator's: each episode's states (one more after its last step), STEP_SUCCESS, zero
    joint actions, and a last observation one more than the store's last."""
    from mimicgen_pipe.core.contracts import Replayed

    layout = [("actors", "cubeA", 13), ("articulations", "panda", 7)]  # the 20 state values
    replays = []
    for i, (s, e) in enumerate(zip(store.episode_starts, store.episode_ends, strict=True)):
        ep = store.episode(i)
        states = np.concatenate([ep["env_state"], ep["env_state"][-1:] + 1])
        last = {k: ep[f"obs/{k}"][-1] + 1 for k in OBS}
        joint = np.zeros((e - s, 8), np.float32)
        replays.append(Replayed(states, STEP_SUCCESS[s:e], joint, last))
    env_info = {"env_id": "StackCube-v1", "max_episode_steps": 50,
                "env_kwargs": {"obs_mode": "none", "control_mode": "pd_ee_delta_pose"}}  # fmt: skip
    return {"replays": replays, "layout": layout, "env_info": env_info}


def test_maniskill_trajectory_reads_back_with_maniskills_dataset_class(tmp_path):
    """ManiSkill's own ManiSkillTrajectoryDataset reads our trajectory file: per step the
    action, the observation before it (obs/<key>, the store's), the sparse success reward,
    success, fail and terminated as the replay gives them; each trajectory's obs holds one
    row more, the replay's observation after the last step; the json's env_kwargs ask for
    ManiSkill's sparse reward. Replays stand in for the simulator's (no simulator runs)."""
    from mani_skill.trajectory.dataset import ManiSkillTrajectoryDataset

    store = synthetic_store(tmp_path / "g.zarr")
    replays = fake_replays(store)
    path, _ = exporters.write(store, "maniskill", tmp_path, export_info(store), **replays)
    replays = replays["replays"]
    ds = ManiSkillTrajectoryDataset(str(path))
    assert len(ds) == sum(LENGTHS)
    np.testing.assert_array_equal(ds.rewards, STEP_SUCCESS.astype(np.float32))
    np.testing.assert_array_equal(ds.success, STEP_SUCCESS)
    np.testing.assert_array_equal(ds.terminated, STEP_SUCCESS)
    assert ds.fail.dtype == bool and not ds.fail.any()
    for row in (0, 11, 12, sum(LENGTHS) - 1):
        item = ds[row]
        np.testing.assert_array_equal(item["action"].numpy(), store.data["actions"][row])
        for key in OBS:
            np.testing.assert_array_equal(item["obs"][key], store.data[f"obs/{key}"][row])
    assert ds.env_kwargs["reward_mode"] == "sparse"
    assert ds.env_kwargs["obs_mode"] == "state_dict"  # a dict of low-dim state, as obs/ holds
    assert ds.json_data["mimicgen_pipe"] == provenance()
    joint = json.loads((tmp_path / "trajectory.pd_joint_pos.json").read_text())
    assert joint["mimicgen_pipe"] == provenance(control_mode="pd_joint_pos")
    assert joint["env_info"]["env_kwargs"]["obs_mode"] == "state_dict"
    with h5py.File(path, "r") as f:
        for i, t in enumerate(LENGTHS):
            obs = f[f"traj_{i}/obs/eef_pos"]
            assert obs.shape == (t + 1, 3) and obs.dtype == np.float32
            np.testing.assert_array_equal(obs[-1], replays[i].last_obs["eef_pos"])


def test_camera_calibration_projects_as_the_cameras_see(tmp_path):
    """Each camera's K has the focal length its field of view gives; agentview's pose puts
    the point it looks at in the image centre, the table's far edge above it and the arm's
    side (+y) on the image's right; the wrist camera sees a point ahead of it along the
    fingers at its centre. A store's calibration with a wrong entry is one error naming
    the key, before anything is written."""
    from mimicgen_pipe.core import camera_calibration as cc
    from mimicgen_pipe.core import cameras as _cameras

    h, w = 84, 96
    agent = _cameras.calibration("agentview", h, w)
    k = np.array(agent["intrinsics"])
    assert k[0, 0] == k[1, 1] == pytest.approx(h / 2 / np.tan(_cameras.AGENTVIEW_FOV / 2))
    assert (k[0, 2], k[1, 2]) == (w / 2, h / 2) and agent["frame"] == "world"
    target = np.array(_cameras.AGENTVIEW_TARGET)
    np.testing.assert_allclose(cc.project(agent, target), [[w / 2, h / 2]], atol=1e-9)
    (u, v), (u2, v2) = cc.project(agent, [target + [0, 0.1, 0], target + [0, 0, 0.1]])
    assert u > w / 2 and v2 < h / 2  # +y to the right, up is up
    assert np.isnan(cc.project(agent, [[2.0, 0.0, 0.6]])).all()  # behind the camera
    wrist = _cameras.calibration("eye_in_hand", h, w)
    ahead = _cameras.WRIST_POS + 0.2 * _cameras.WRIST_FORWARD
    assert wrist["frame"] == "panda_hand"
    np.testing.assert_allclose(cc.project(wrist, ahead), [[w / 2, h / 2]], atol=1e-9)
    for what in ("intrinsics", "pose"):
        store = synthetic_store(tmp_path / f"{what}.zarr", cameras=CAMERAS)
        bad = json.loads(json.dumps(store.attrs["camera_calibration"]))
        bad["eye_in_hand"][what][1][1] = -1.0
        broken = dataclasses.replace(store, attrs={**store.attrs, "camera_calibration": bad})
        with pytest.raises(InputError, match=f"camera_calibration.eye_in_hand.{what}: expected"):
            exporters.check(broken, "robomimic", export_info(store))


def test_robomimic_file_reads_back_as_source_demos(tmp_path):
    store = synthetic_store(tmp_path / "g.zarr")
    path, _ = exporters.write(store, "robomimic", tmp_path, export_info(store))
    demos = robomimic_source.read(path, "maniskill", "stack_cube")
    assert [d.seed for d in demos] == [100, 101, 102]
    for i, d in enumerate(demos):
        np.testing.assert_array_equal(d.actions, store.episode(i)["actions"])
        np.testing.assert_array_equal(d.initial_state, store.episode(i)["env_state"][0])
    with pytest.raises(InputError, match="expected 'pybullet'/'stack_cube'"):
        robomimic_source.read(path, "pybullet", "stack_cube")


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
        (
            ["--formats", "maniskill,lerobot", "--store", "nocamera.zarr"],
            "cannot export as lerobot: no data/obs/agentview_image (attrs.cameras lists "
            "'agentview')",
        ),
    ],
)
def test_export_bad_input_is_one_error_before_anything_is_written(tmp_path, args, expected):
    (tmp_path / "params.yaml").write_text(PARAMS)
    synthetic_store(tmp_path / "input" / "g.zarr")
    synthetic_store(tmp_path / "pb.zarr", backend="pybullet", task="stack")
    synthetic_store(tmp_path / "nostate.zarr", drop=("env_state",))
    nocamera = ("obs/agentview_image",)
    synthetic_store(tmp_path / "nocamera.zarr", drop=nocamera, cameras=CAMERAS)
    if "--store" not in args and "give either" not in expected:
        args = [*args, "--store", "input/g.zarr"]
    res = cli("export", *args, "--out", "out", cwd=tmp_path, check=False)
    assert res.returncode == 2, res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and expected in lines[0], res.stderr
    assert not (tmp_path / "out").exists() and not (tmp_path / "metrics").exists()


def test_export_metrics_hold_each_formats_image_bytes_and_its_timings_the_seconds(tmp_path):
    """The export stage on a store with images: its metrics hold the bytes the images take
    in each format (robomimic's image datasets, LeRobot's videos) and no time; its timings
    file (metrics/ -> timings/), the seconds each format took, under the same identity."""
    (tmp_path / "params.yaml").write_text(PARAMS)
    synthetic_store(tmp_path / "observed.zarr", cameras=CAMERAS)
    cli("export", "--store", "observed.zarr", "--formats", "robomimic,lerobot", "--out", "out",
        "--metrics", "metrics/m.json", cwd=tmp_path)  # fmt: skip
    metrics = json.loads((tmp_path / "metrics/m.json").read_text())
    timings = json.loads((tmp_path / "timings/m.json").read_text())
    assert not [k for k in metrics if is_timing(k)]
    identity = {k: metrics[k] for k in IDENTITY_FIELDS}
    assert timings.keys() == {*identity, "robomimic_seconds", "lerobot_seconds", "cpu"}
    assert timings.items() >= identity.items()
    assert timings["robomimic_seconds"] > 0 and timings["lerobot_seconds"] > 0
    with h5py.File(tmp_path / "out/demos.hdf5", "r") as f:
        demos = [f[f"data/demo_{i}/obs"] for i in range(len(LENGTHS))]
        stored = sum(g[k].id.get_storage_size() for g in demos for k in MIMICGEN_CAMERAS)
    videos = sum(p.stat().st_size for p in (tmp_path / "out/lerobot/videos").rglob("*.mp4"))
    assert metrics["robomimic_image_bytes"] == stored > 0
    assert metrics["lerobot_image_bytes"] == videos > 0


@pytest.mark.sim
def test_states_the_env_cannot_take_are_one_error_when_success_is_evaluated(tmp_path):
    """With export.step_success, a store whose env_state is not the back end's state (the
    synthetic store's 20 random values) is one error naming data/env_state, the width
    expected and the way out, before anything is written."""
    (tmp_path / "params.yaml").write_text(
        PARAMS.replace("step_success: false", "step_success: true")
    )
    synthetic_store(tmp_path / "g.zarr")
    res = cli("export", "--store", "g.zarr", "--formats", "robomimic", "--out", "out",
              cwd=tmp_path, check=False)  # fmt: skip
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert "g.zarr: data/env_state has (20,) values a step, expected (" in lines[0]
    assert "export.step_success: false" in lines[0]
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
@pytest.mark.slow  # about 1 min (2 on a loaded machine); the default run keeps under 20 min
def test_maniskill_export_replays_in_maniskills_own_tool(pipeline):
    """Every exported episode replays to success with ManiSkill's replay_trajectory, both the
    delta-pose file and its pd_joint_pos copy, and the pd_joint_pos copy converts with -c;
    actions and first states are ours; the rewards (sparse success) are the replay's
    success, and the robomimic export's rewards, evaluated from the stored states, the same;
    obs holds the stored observations and one more after the last step."""
    cli("export", "--variant", "D1", "--formats", "maniskill,robomimic", cwd=pipeline)
    out = pipeline / "data/export/stack_cube_D1"
    store = read_store(pipeline / "data/generated/stack_cube_D1.zarr")
    n = store.n_episodes
    metrics = json.loads((pipeline / "metrics/export_stack_cube_D1.json").read_text())
    assert metrics["episodes"] == n and metrics["maniskill_replay_success"] == 1.0
    with h5py.File(out / "trajectory.h5", "r") as f:
        assert sorted(f) == [f"traj_{i}" for i in range(n)]
        h5 = h5py.File(out / "demos.hdf5", "r")
        for i in range(n):
            ep, traj = store.episode(i), f[f"traj_{i}"]
            np.testing.assert_array_equal(traj["actions"][:], ep["actions"])
            robot = traj["env_states/articulations/panda"]
            assert robot.shape[0] == len(ep["actions"]) + 1
            np.testing.assert_array_equal(robot[0], ep["env_state"][0][-31:])
            np.testing.assert_array_equal(traj["rewards"][:], traj["success"][:])
            assert traj["rewards"][-1] == 1.0 and not traj["fail"][:].any()
            np.testing.assert_array_equal(traj["obs/eef_pos"][:-1], ep["obs/eef_pos"])
            assert traj["obs/eef_pos"].shape == (len(ep["actions"]) + 1, 3)
            np.testing.assert_array_equal(h5[f"data/demo_{i}/rewards"][:], traj["rewards"][:])
        h5.close()
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
