"""The observe stage: camera images rendered from stored states (ManiSkill and PyBullet),
the same bytes on any number of workers and after a resumed interruption, its bad-input
errors, and image arrays chunked along the steps in the store (read chunk by chunk,
checksummed)."""

from __future__ import annotations

import hashlib
import json
import signal
from pathlib import Path

import numpy as np
import pytest

from mimicgen_pipe import backends
from mimicgen_pipe.cli import main
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.interrupts import Interrupted
from mimicgen_pipe.data import store as store_module
from mimicgen_pipe.data.store import open_store, read_store, write_store

CAMERAS = ("agentview", "eye_in_hand")
SIZE = 32  # px: small images, the same code path as 84


def random_store(path: Path, backend: str, task: str, lengths: list[int]) -> Path:
    """A generated-kind store of episodes of random arm motions (every step's env_state, the
    actions and end-effector poses), one episode per entry of ``lengths``."""
    env = backends.make_env(backend, task, "panda")
    rng = np.random.default_rng(0)
    steps, seeds = [], []
    for k, n in enumerate(lengths):
        env.reset(seed=k, variant="D0")
        ep: dict[str, list] = {"actions": [], "env_state": [], "eef_pose": []}
        for _ in range(n):
            action = np.r_[rng.uniform(-1, 1, 6), 1.0].astype(np.float32)
            ep["actions"].append(action)
            ep["env_state"].append(env.get_state())
            ep["eef_pose"].append(env.eef_pose())
            env.step(action)
        steps.append({key: np.asarray(v) for key, v in ep.items()})
        seeds.append(k)
    env.close()
    attrs = {"task": task, "variant": "D0", "backend": backend, "robot": "panda"}
    episodes = {"seed": np.asarray(seeds, np.int64)}
    return write_store(path, "generated", steps, episodes, attrs)


def observe(
    work: Path, store: Path, out: str, backend: str, task: str, *args: str, **keys: object
) -> tuple[int, Path]:
    """Run the observe stage in this process (exit status, output path); ``args``: more of
    its command line; ``keys``: observe params besides small images on one worker."""
    section = {"height": SIZE, "width": SIZE, "workers": 1} | keys
    (work / "params.yaml").write_text(
        f"task: {task}\nbackend: {backend}\nobserve: {json.dumps(section)}\n"
    )
    code = main(
        ["observe", "--params", str(work / "params.yaml"), "--variant", "D0",
         "--store", str(store), "--out", str(work / out),
         "--metrics", str(work / f"{out}.json"), *args]
    )  # fmt: skip
    return code, work / out


def digest(path: Path) -> str:
    h = hashlib.sha256()
    for f in sorted(p for p in path.rglob("*") if p.is_file()):
        h.update(f.relative_to(path).as_posix().encode() + f.read_bytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def maniskill_store(tmp_path_factory) -> Path:
    return random_store(
        tmp_path_factory.mktemp("ms") / "in.zarr", "maniskill", "stack_cube", [6, 5, 4]
    )


@pytest.fixture(scope="module")
def pybullet_store(tmp_path_factory) -> Path:
    return random_store(
        tmp_path_factory.mktemp("pb") / "in.zarr", "pybullet", "stack", [5, 4, 4, 3]
    )


@pytest.mark.parametrize("backend", ["maniskill", "pybullet"])
def test_images_are_the_states_rendered(
    backend, maniskill_store, pybullet_store, tmp_path, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    store, task = (
        (maniskill_store, "stack_cube") if backend == "maniskill" else (pybullet_store, "stack")
    )
    code, out = observe(tmp_path, store, "obs.zarr", backend, task, episodes=2)
    assert code == 0
    source, view = read_store(store), open_store(out, kind="generated")
    n = int(source.episode_ends[1])
    assert dict(view.attrs["cameras"]) == {c: {"height": SIZE, "width": SIZE} for c in CAMERAS}
    assert list(view.episode_ends) == list(source.episode_ends[:2])
    for key, value in source.data.items():  # every input array kept, rows of 2 episodes
        assert np.array_equal(view.read_rows(key, [0, 1]), value[:n])
    assert np.array_equal(view.episode_field("seed"), source.episodes["seed"][:2])
    images = {c: view.read_rows(f"obs/{c}_image", [0, 1]) for c in CAMERAS}
    renderer = backends.make_renderer(backend, task, "panda", SIZE, SIZE, CAMERAS)
    for im in images.values():
        assert im.shape == (n, SIZE, SIZE, 3) and im.dtype == np.uint8
        assert im[0].std() > 5  # a picture, not a flat colour
        assert not np.array_equal(im[0], im[5])  # the arm moved between steps 0 and 5
    for t in (0, 5, n - 1):  # row t is env_state row t
        fresh = renderer.images(source.data["env_state"][t])
        assert all(np.array_equal(images[c][t], fresh[c]) for c in CAMERAS)
    assert view.attrs["camera_calibration"] == backends.camera_calibration(CAMERAS, SIZE, SIZE)
    for camera, calib in view.attrs["camera_calibration"].items():  # the renderer's cameras
        k, world_to_camera = renderer_camera(renderer, backend, camera)
        np.testing.assert_allclose(calib["intrinsics"], k, rtol=1e-5)
        pose = np.asarray(calib["pose"])
        assert calib["frame"] == ("world" if camera == "agentview" else "panda_hand")
        if camera == "eye_in_hand":  # after the last picture's state
            pose = hand_pose(renderer, backend) @ pose
        np.testing.assert_allclose(np.linalg.inv(pose)[:3], world_to_camera, atol=2e-5)
    renderer.close()


def hand_pose(renderer, backend: str) -> np.ndarray:
    """The panda_hand link's 4x4 world pose in the renderer's scene now."""
    from mimicgen_pipe.core import poses

    if backend == "maniskill":
        hand = renderer._env.unwrapped.agent.robot.links_map["panda_hand"].pose
        return hand.to_transformation_matrix()[0].numpy().astype(np.float64)
    env = renderer._env
    pos, xyzw = env._sim.getLinkState(env._robot, renderer._hand, computeForwardKinematics=True)[
        4:6
    ]
    return poses.pose_from_pq(np.array(pos), np.roll(np.array(xyzw), 1))


def renderer_camera(renderer, backend: str, camera: str) -> tuple[np.ndarray, np.ndarray]:
    """(K, the 3x4 world-to-camera transform, OpenCV axes) of ``camera`` as the renderer
    pictures with it: SAPIEN's own matrices, or those of PyBullet's view and projection
    matrices (OpenGL's column-major, camera axes x right, y up, z back)."""
    if backend == "maniskill":
        sapien = renderer._render_cameras[camera]
        return sapien.get_intrinsic_matrix(), sapien.get_extrinsic_matrix()
    view, proj = renderer._agentview if camera == "agentview" else (
        renderer._wrist_view(), renderer._wrist_proj)  # fmt: skip
    w, h = renderer._size
    f = np.reshape(proj, (4, 4)).T[1, 1] * h / 2  # 1 / tan(fov_y / 2), in pixels
    k = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]])
    gl = np.reshape(view, (4, 4)).T
    return k, (np.diag([1.0, -1.0, -1.0, 1.0]) @ gl)[:3]


def test_same_bytes_with_one_and_two_workers(pybullet_store, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code1, one = observe(tmp_path, pybullet_store, "one.zarr", "pybullet", "stack")
    code2, two = observe(tmp_path, pybullet_store, "two.zarr", "pybullet", "stack", workers=2)
    assert code1 == code2 == 0 and digest(one) == digest(two)
    assert open_store(one).shape("obs/eye_in_hand_image") == (16, SIZE, SIZE, 3)


def test_a_resumed_run_gives_the_same_bytes(pybullet_store, tmp_path, monkeypatch, capsys):
    import mimicgen_pipe.media.camera_images as library

    monkeypatch.chdir(tmp_path)
    assert observe(tmp_path, pybullet_store, "whole.zarr", "pybullet", "stack")[0] == 0
    whole = tmp_path / "whole.zarr"
    write = library.write_observed

    def interrupted_after_one_block(writer, view, job, images, blocks, *rest):
        next(images)  # the first block, saved in the work directory
        raise Interrupted(signal.SIGTERM)

    monkeypatch.setattr(library, "write_observed", interrupted_after_one_block)
    code, _ = observe(tmp_path, pybullet_store, "again.zarr", "pybullet", "stack")
    assert code == 143 and "interrupted (SIGTERM); nothing written" in capsys.readouterr().err
    assert not (tmp_path / "again.zarr").exists()
    assert len(list((tmp_path / ".again.zarr.work").glob("block-*.npz"))) == 1
    monkeypatch.setattr(library, "write_observed", write)
    rendered = []
    render_block = library._render_block
    monkeypatch.setattr(library, "_render_block", lambda b: rendered.append(b) or render_block(b))
    code, again = observe(tmp_path, pybullet_store, "again.zarr", "pybullet", "stack")
    assert code == 0 and "resuming: 1 finished blocks" in capsys.readouterr().out
    assert rendered == [[2, 3]]  # the first block came from the work directory
    assert digest(again) == digest(whole)
    assert not (tmp_path / ".again.zarr.work").exists()


def test_episodes_on_the_command_line_stand_in_for_the_params(
    pybullet_store, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    code, out = observe(
        tmp_path, pybullet_store, "two.zarr", "pybullet", "stack", "--episodes", "2"
    )
    assert code == 0
    view = open_store(out)
    assert view.n_episodes == 2 and view.shape("obs/agentview_image") == (5 + 4, SIZE, SIZE, 3)
    assert view.attrs["observe"]["episodes"] == 2
    code, out = observe(
        tmp_path, pybullet_store, "nine.zarr", "pybullet", "stack", "--episodes", "9"
    )
    err = capsys.readouterr().err
    assert code == 2 and f"--episodes 9: {pybullet_store} has 4 episodes" in err
    assert not out.exists()


@pytest.mark.parametrize(
    "keys,needle",
    [
        (
            {"cameras": ["agentview", "birdview"]},
            "observe.cameras: 'birdview' not a camera of panda on pybullet "
            "(known: agentview, eye_in_hand)",
        ),
        ({"height": 0}, "observe.height: expected a value in [1, 4096], got 0"),
        ({"width": 8.5}, "observe.width: expected an integer, got 8.5"),
        ({"episodes": 5}, "observe.episodes 5: "),
        ({"episodes": 0}, "observe.episodes: expected a value in [1, 10000000], got 0"),
    ],
)
def test_bad_input_is_one_error_before_any_work(
    pybullet_store, tmp_path, monkeypatch, capsys, keys, needle
):
    monkeypatch.chdir(tmp_path)
    code, out = observe(tmp_path, pybullet_store, "obs.zarr", "pybullet", "stack", **keys)
    err = capsys.readouterr().err
    assert code == 2 and needle in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_a_store_without_states_is_refused(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    steps = [{"actions": np.zeros((3, 7), np.float32)}]
    attrs = {"task": "stack", "variant": "D0", "backend": "pybullet", "robot": "panda"}
    store = write_store(tmp_path / "in.zarr", "generated", steps, {}, attrs)
    code, _ = observe(tmp_path, store, "obs.zarr", "pybullet", "stack")
    assert code == 2 and "in.zarr: no data/env_state" in capsys.readouterr().err


def chunked_store(path: Path, monkeypatch) -> tuple[Path, np.ndarray]:
    """A store whose data/obs/cam_image is chunked along the steps, 4 steps a chunk."""
    monkeypatch.setattr(store_module, "ROW_CHUNK_BYTES", 4 * 2 * 2 * 3)
    images = np.arange(22 * 2 * 2 * 3, dtype=np.uint8).reshape(22, 2, 2, 3)
    ends = np.array([5, 9, 22])
    with store_module.store_writer(path, "generated", ends, {"task": "t"}) as w:
        w.array("actions", np.zeros((22, 7), np.float32))
        rows = w.rows("obs/cam_image", (2, 2, 3), np.uint8)
        for block in np.split(images, [3, 10, 11]):  # blocks that do not fit the chunks
            rows.append(block)
        rows.close()
    return path, images


def test_image_arrays_are_chunked_along_the_steps_and_read_by_episode(tmp_path, monkeypatch):
    path, images = chunked_store(tmp_path / "s.zarr", monkeypatch)
    files = (p for p in (path / "data/obs/cam_image/c").rglob("*") if p.is_file())
    chunks = sorted(files, key=lambda p: int(p.relative_to(path / "data/obs/cam_image/c").parts[0]))
    assert len(chunks) == 6  # 22 steps, 4 a chunk
    view = open_store(path)
    assert np.array_equal(view.read_rows("obs/cam_image", [1]), images[5:9])
    assert np.array_equal(view.read_rows("obs/cam_image", [0, 2]), np.r_[images[:5], images[9:]])
    assert np.array_equal(read_store(path).data["obs/cam_image"], images)
    # a damaged chunk outside the rows asked for is not read; one inside them is an error
    last = chunks[-1]
    last.write_bytes(last.read_bytes()[:-1] + bytes([last.read_bytes()[-1] ^ 1]))
    assert np.array_equal(view.read_rows("obs/cam_image", [0]), images[:5])
    with pytest.raises(InputError, match=r"data/obs/cam_image: a chunk cannot be decoded"):
        view.read_rows("obs/cam_image", [2])
    last.unlink()
    with pytest.raises(InputError, match=r"data/obs/cam_image: 1 of 6 chunk\(s\) missing"):
        open_store(path)


def test_a_damaged_image_chunk_of_an_observed_store_names_the_array(
    pybullet_store, tmp_path, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    _, out = observe(tmp_path, pybullet_store, "obs.zarr", "pybullet", "stack", episodes=1)
    chunk = next(p for p in (out / "data/obs/agentview_image/c").rglob("*") if p.is_file())
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0xFF
    chunk.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"data/obs/agentview_image: a chunk cannot be decoded"):
        open_store(out).read_rows("obs/agentview_image", [0])
    with pytest.raises(InputError, match=r"data/obs/agentview_image"):
        read_store(out)
