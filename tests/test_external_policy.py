"""Policies trained elsewhere (mimicgen_pipe.formats.external): the wire format, the server loop
with a stand-in policy under this virtualenv's Python (tests/external_stand_in.py), the errors
before and during rollouts, and the evaluator's loop over them on a tiny fake env. The
round trip through robomimic's own training, with its check virtualenv, is marked slow."""

from __future__ import annotations

import csv
import io
import json
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.observations import observation_dims
from mimicgen_pipe.formats import external
from mimicgen_pipe.formats.external import (
    ExternalPolicy,
    PolicySpec,
    _serve,
    check_hello,
    parse_policy,
    policy_cameras,
    provided_inputs,
)
from mimicgen_pipe.learn.evaluation import EvalJob, evaluate_policies, success_rate
from mimicgen_pipe.run.executors import Executor
from tests.conftest import REPO, SMALL_PARAMS, cli

STAND_IN = REPO / "tests" / "external_stand_in.py"
CAMERAS = ("agentview", "eye_in_hand")
LOW_DIM = {"eef_pos": {"shape": [3], "dtype": "float32"},
           "gripper_qpos": {"shape": [2], "dtype": "float32"}}  # fmt: skip
OBS = {"eef_pos": np.array([0.1, 0.2, 0.3], np.float32),
       "gripper_qpos": np.array([0.04, 0.04], np.float32),
       "cubeA_pos": np.array([1.0, 2.0, 3.0], np.float32)}  # fmt: skip


def stand_in(tmp_path: Path, **config) -> list[str]:
    """The command line of a stand-in server with this config (see external_stand_in.py)."""
    path = tmp_path / f"stand_in_{len(list(tmp_path.glob('stand_in_*')))}.json"
    path.write_text(json.dumps({"observations": LOW_DIM} | config))
    return [sys.executable, str(STAND_IN), "--format", "stand_in", "--path", str(path),
            "--task", "stack_cube: grasp cubeA, then place on cubeB"]  # fmt: skip


def open_stand_in(tmp_path: Path, act_seconds: float = 60.0, **config) -> ExternalPolicy:
    return ExternalPolicy(
        stand_in(tmp_path, **config), dict, "stand_in:test", act_seconds=act_seconds
    )


def test_messages_round_trip_and_refuse_pickles():
    arrays = {"image": np.arange(12, dtype=np.uint8).reshape(2, 2, 3),
              "state": np.array([1.5, -2.0], np.float32)}  # fmt: skip
    data = _serve.encode({"op": "act", "n": 3}, arrays)
    (size,) = _serve.LENGTH.unpack(data[: _serve.LENGTH.size])
    assert size == len(data) - _serve.LENGTH.size
    header, back = _serve.read_message(io.BytesIO(data))
    assert header == {"op": "act", "n": 3}
    assert back.keys() == arrays.keys()
    for k, v in arrays.items():
        assert back[k].dtype == v.dtype and np.array_equal(back[k], v)
    assert _serve.read_message(io.BytesIO(b"")) is None
    with pytest.raises(EOFError):
        _serve.read_message(io.BytesIO(data[:-3]))
    # an object array would need unpickling: refused
    buf = io.BytesIO()
    np.savez(buf, header=np.array(json.dumps({"op": "act"})), x=np.array([{"a": 1}], object))
    with pytest.raises(ValueError, match="pickle"):
        _serve.decode(buf.getvalue())


def test_stand_in_policy_acts_through_its_server(tmp_path):
    """Hello, reset, act and close over the server's pipes: the action answers the
    observations sent (a print during loading reaches stderr, not the messages), the same
    seed gives the same action, and the server exits when closed."""
    with open_stand_in(tmp_path, meta={"env_kwargs": {"task": "stack_cube"}}) as policy:
        assert policy.hello["observations"] == LOW_DIM
        assert policy.hello["action_dim"] == 7
        assert policy.hello["meta"] == {"env_kwargs": {"task": "stack_cube"}}
        assert policy.keys == ("eef_pos", "gripper_qpos")
        actions = []
        for seed in (5, 5, 6):
            policy.reset(seed)
            actions.append(policy.act(OBS))
        sums = [0.6, 0.08]  # eef_pos, gripper_qpos, cycled over the 7 numbers
        expected = np.array([sums[i % 2] for i in range(7)], np.float32)
        assert actions[0].dtype == np.float32 and actions[0].shape == (7,)
        np.testing.assert_allclose(actions[0], expected, atol=0.05)
        np.testing.assert_array_equal(actions[0], actions[1])
        assert not np.array_equal(actions[0], actions[2])
        proc = policy._proc
    assert proc.returncode == 0


def test_server_run_by_path_refuses_an_unknown_format(tmp_path):
    """_serve.py as the frameworks run it (by path, its folder off sys.path): a format it
    does not know is its hello's error, which the client raises as one InputError."""
    command = [sys.executable, str(external.SERVER), "--format", "nosuch", "--path", "x"]
    with pytest.raises(InputError, match=r"cannot load the policy: .*'nosuch': unknown "
                       r"\(known: lerobot, robomimic\)"):  # fmt: skip
        ExternalPolicy(command, dict, "nosuch:x")


def test_a_server_that_fails_ends_or_hangs_is_one_error_not_a_hang(tmp_path):
    with pytest.raises(InputError, match="failed while loading the policy: cannot load the "
                       "policy: RuntimeError: weights missing"):  # fmt: skip
        open_stand_in(tmp_path, fail_load="weights missing")
    policy = open_stand_in(tmp_path, exit_at=2)
    policy.reset(0)
    policy.act(OBS)
    with pytest.raises(InputError, match=r"ended during act \(exit status 3\); its stderr "
                       "ends: .*stand-in: giving up"):  # fmt: skip
        policy.act(OBS)
    policy.close()
    policy = open_stand_in(tmp_path, act_seconds=1.0, hang_at=1)
    policy.reset(0)
    t0 = time.monotonic()
    with pytest.raises(InputError, match="gave no answer within 1 s during act"):
        policy.act(OBS)
    assert time.monotonic() - t0 < 10
    assert policy._proc.returncode is not None  # stopped, not left behind
    policy.close()
    with pytest.raises(InputError, match="cannot start its server"):
        ExternalPolicy([str(tmp_path / "no_python")], dict, "x:y")


def test_a_server_that_writes_garbage_is_one_error_before_any_allocation(tmp_path):
    garbage = "import sys, time; sys.stdout.buffer.write(b'\\xff' * 8 + b'junk'); "
    garbage += "sys.stdout.flush(); time.sleep(60)"
    t0 = time.monotonic()
    with pytest.raises(InputError, match=r"sent an unreadable message while loading the "
                       r"policy \(a message of 18446744073709551615 bytes announced, over "
                       r"the 256 MiB limit"):  # fmt: skip
        ExternalPolicy([sys.executable, "-c", garbage], dict, "x:garbage")
    assert time.monotonic() - t0 < 30  # at once, not at the hello's time limit
    # the server's side: a request whose length is garbage ends it with one error message
    out = io.BytesIO()
    status = _serve.serve(lambda: _StandInPolicy(), "x", io.BytesIO(b"\xff" * 8), out)
    assert status == 1
    answers = io.BytesIO(out.getvalue())
    assert _serve.read_message(answers)[0]["op"] == "hello"
    header, _ = _serve.read_message(answers)
    assert header["op"] == "error" and "over the 256 MiB limit" in header["message"]


class _StandInPolicy:
    observations: dict = {}
    action_dim, meta = 7, {}


def spec(fmt: str = "robomimic") -> PolicySpec:
    return PolicySpec(fmt, "/p", sys.executable, ("eef_pos", "gripper_qpos", "cubeA_pos"), "")


def test_a_policy_whose_inputs_our_env_lacks_is_refused_naming_them():
    dims = observation_dims(("cubeA", "cubeB"))
    provided = provided_inputs("robomimic", dims, spec().obs_keys)
    assert provided["cubeA_quat"] == ((4,), "float32")
    env = {"backend": "maniskill", "task": "stack_cube", "robot": "panda"}
    hello = {"observations": LOW_DIM, "action_dim": 7, "meta": {"env_kwargs": env}}
    check_hello(spec(), hello, provided, env, ())  # fits

    needs = LOW_DIM | {"robot0_joint_pos": {"shape": [7], "dtype": "float32"},
                       "frontview_image": {"shape": [84, 84, 3], "dtype": "uint8"}}  # fmt: skip
    lacks = (r"robomimic:/p: reads observations our env does not provide: robot0_joint_pos, "
             r"frontview_image")  # fmt: skip
    with pytest.raises(InputError, match=lacks + r" \(frontview_image: images of cameras it "
                       r"lacks; it has agentview, eye_in_hand\)"):  # fmt: skip
        check_hello(spec(), hello | {"observations": needs}, provided, env, CAMERAS)
    wide = {"eef_pos": {"shape": [4], "dtype": "float32"}}
    with pytest.raises(InputError, match=r"reads eef_pos \(4,\) float32 \(ours: \(3,\)"):
        check_hello(spec(), hello | {"observations": wide}, provided, env, ())
    with pytest.raises(InputError, match="acts with 10 numbers per step; our env takes 7"):
        check_hello(spec(), hello | {"action_dim": 10}, provided, env, ())
    # a two-arm task's env takes 7 per arm: a one-arm policy is refused there
    with pytest.raises(
        InputError, match=r"acts with 7 numbers per step; our env takes 14 .*2 arms"
    ):
        check_hello(spec(), hello, provided, env, (), action_dim=14)
    other = {"env_kwargs": env | {"task": "lift_cube"}}
    with pytest.raises(InputError, match="trained on data of {'task': 'lift_cube'}"):
        check_hello(spec(), hello | {"meta": other}, provided, env, ())


@pytest.mark.parametrize("fmt, key", [("robomimic", "{}_image"),
                                      ("lerobot", "observation.images.{}")])  # fmt: skip
def test_an_image_policy_gets_the_cameras_it_reads_at_its_size(fmt, key):
    image = {"shape": [64, 48, 3], "dtype": "uint8"}
    needs = {key.format("eye_in_hand"): image, "eef_pos": LOW_DIM["eef_pos"]}
    hello = {"observations": needs, "action_dim": 7, "meta": {}}
    cameras, size = policy_cameras(spec(fmt), hello, CAMERAS)
    assert (cameras, size) == (("eye_in_hand",), (64, 48))
    dims = observation_dims(("cubeA", "cubeB"))
    provided = provided_inputs(fmt, dims, spec().obs_keys, cameras, size)
    assert provided[key.format("eye_in_hand")] == ((64, 48, 3), "uint8")
    assert key.format("agentview") not in provided
    if fmt == "robomimic":
        check_hello(spec(fmt), hello, provided, {}, CAMERAS)
    other = {"shape": [84, 84, 3], "dtype": "uint8"}
    two = hello | {"observations": needs | {key.format("agentview"): other}}
    with pytest.raises(InputError, match="reads images of several sizes"):
        policy_cameras(spec(fmt), two, CAMERAS)
    assert policy_cameras(spec(fmt), {"observations": LOW_DIM}, CAMERAS) == ((), None)


def test_lerobot_inputs_are_the_export_s_frames(tmp_path):
    """A policy trained on our LeRobot export is given, at each step, the very features the
    export wrote for that step's observation."""
    import pyarrow.parquet as pq

    from mimicgen_pipe.formats import exporters
    from tests.test_export import export_info, synthetic_store

    store = synthetic_store(tmp_path / "g.zarr")
    info = export_info(store)
    path, _ = exporters.write(store, "lerobot", tmp_path, info)
    table = pq.read_table(path / "data/chunk-000/file-000.parquet").to_pydict()
    fmt = external.format_module("lerobot")
    obs_keys = tuple(info.obs_keys)
    for t in (0, 5, 20):
        obs = {k: store.data[f"obs/{k}"][t] for k in obs_keys}
        inputs = fmt.observation(obs, obs_keys)
        assert inputs.keys() == {"observation.state", "observation.environment_state"}
        for feature, x in inputs.items():
            assert x.dtype == np.float32
            np.testing.assert_array_equal(x, np.array(table[feature][t], np.float32))


def test_robomimic_inputs_are_the_export_s_obs(tmp_path):
    """A policy trained on our robomimic export is given, at each step, the very obs/<key>
    arrays the export wrote for that step (MimicGen's names, object included), images
    under the export's names; and our own keys, as exports before those names had them."""
    import h5py

    from mimicgen_pipe.formats import exporters
    from tests.test_export import CAMERAS as SIZES
    from tests.test_export import export_info, synthetic_store

    store = synthetic_store(tmp_path / "g.zarr", cameras=SIZES)
    info = export_info(store)
    path, _ = exporters.write(store, "robomimic", tmp_path, info)
    fmt = external.format_module("robomimic")
    assert [fmt.image_key(c) for c in SIZES] == ["agentview_image", "robot0_eye_in_hand_image"]
    images = {c: np.concatenate(list(exporters.episode_images(store, c))) for c in SIZES}
    with h5py.File(path, "r") as f:
        for demo, t, row in ((0, 0, 0), (0, 5, 5), (2, 4, 23)):
            obs = {k: store.data[f"obs/{k}"][row] for k in info.obs_keys}
            obs |= {f"{c}_image": images[c][row] for c in SIZES}
            inputs = fmt.observation(obs, tuple(info.obs_keys))
            written = f[f"data/demo_{demo}/obs"]
            assert set(written) <= set(inputs) and "object" in written
            for key in written:
                np.testing.assert_array_equal(inputs[key], written[key][t], err_msg=key)
            for key, value in obs.items():  # the names of earlier exports
                if key not in written:  # an object's key (cubeA_quat) is the export's own
                    np.testing.assert_array_equal(inputs[key], value)


def test_a_policy_of_an_unknown_kind_is_refused_saying_what_was_expected(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    (tmp_path / "empty").mkdir()
    expected = "expected lerobot:<LeRobot policy directory: .*>; robomimic:<robomimic checkpoint"
    for text, why in [
        ("nosuch:x", "policy format 'nosuch': unknown"),
        (str(tmp_path / "notes.txt"), "expected <format>:<path>"),
        (f"robomimic:{tmp_path / 'notes.txt'}", "not a checkpoint torch saved.*" + expected),
        (f"robomimic:{tmp_path / 'none.pth'}", "no such file"),
        (f"lerobot:{tmp_path / 'empty'}", "no config.json and no model.safetensors"),
        (f"lerobot:{tmp_path / 'notes.txt'}", "no such directory"),
    ]:
        with pytest.raises(InputError, match=why):
            parse_policy(text)
    (tmp_path / "params.yaml").write_text(SMALL_PARAMS)
    res = cli("evaluate_external", "--data", "D1", "--variant", "D1", "--policy",
              f"robomimic:{tmp_path / 'notes.txt'}", cwd=tmp_path, check=False)  # fmt: skip
    assert res.returncode == 2, res.stderr
    assert "not a checkpoint torch saved" in res.stderr and "Traceback" not in res.stderr


def test_a_lerobot_config_naming_another_backbone_is_refused_before_loading(tmp_path):
    from tests.test_no_network import lerobot_folder

    policy = lerobot_folder(tmp_path / "policy")
    for backbone, ok in (("resnet18", True), (None, True), ("get_model", False),
                         ("__builtins__", False)):  # fmt: skip
        (policy / "config.json").write_text(
            json.dumps({"type": "act", "vision_backbone": backbone})
        )
        if ok:
            assert parse_policy(f"lerobot:{policy}") == ("lerobot", policy)
            continue
        with pytest.raises(
            InputError,
            match=rf"config.json: vision_backbone '{backbone}' is "
            "not a backbone this server builds \\(one of resnet18, resnet34",
        ):
            parse_policy(f"lerobot:{policy}")  # fmt: skip


class FakeEnv:
    """A task without a simulator: the gripper moves by the action's first three numbers
    (world frame, metres), and the task succeeds once it is 1 m above its start."""

    def reset(self, seed: int, variant: str) -> None:
        self.pos = np.zeros(3)

    def rebuild(self) -> None:
        pass

    def eef_pose(self) -> np.ndarray:
        pose = np.eye(4)
        pose[:3, 3] = self.pos
        return pose

    def gripper_state(self) -> np.ndarray:
        return np.full(2, 0.04)

    def object_poses(self) -> dict[str, np.ndarray]:
        return {}

    def step(self, action: np.ndarray) -> None:
        self.pos = self.pos + np.asarray(action[:3], float)

    def is_success(self) -> bool:
        return bool(self.pos[2] > 1.0)


def load_stand_in(command: list[str], name: str) -> ExternalPolicy:
    return ExternalPolicy(command, dict, name)


def test_the_evaluator_rolls_out_a_served_policy_one_server_per_worker(tmp_path):
    """25 episodes in three blocks, on one worker and on two: one server per worker for all
    its blocks (a worker may run them all), gone once the evaluation ends; each episode ends
    on success or at the horizon, the same per seed on any number of workers (the stand-in
    climbs by the sum of eef_pos, which its seeded noise starts up or down)."""
    import functools

    seeds = list(range(100, 125))
    runs = {}
    for workers in (1, 2):
        log = tmp_path / f"servers{workers}.log"
        command = stand_in(tmp_path, observations={"eef_pos": LOW_DIM["eef_pos"]}, log=str(log))
        job = EvalJob(
            make_env=FakeEnv,
            load_policy=functools.partial(load_stand_in, command),
            variant="D0",
            horizon=30,
            objects=(),
        )
        results, _ = evaluate_policies(job, ["stand_in"], seeds, Executor("local", workers), "")
        runs[workers] = results["stand_in"]
        pids = [int(p) for p in log.read_text().split()]
        assert 1 <= len(pids) <= workers
        deadline = time.monotonic() + 10
        while any(_alive(p) for p in pids) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(_alive(p) for p in pids)
    rollouts = runs[1]
    assert runs[2] == rollouts
    assert [r.seed for r in rollouts] == seeds
    assert all(r.steps == 30 or (r.success and r.steps < 30) for r in rollouts)
    assert 0 < success_rate(rollouts) < 100


def _alive(pid: int) -> bool:
    """A process that runs (not a zombie: its parent, a worker, may be gone unreaped)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


class Recorder:
    """A still arm that records what it is shown, with the env's state at that moment."""

    def __init__(self, env) -> None:
        self.env, self.seen = env, []

    def reset(self, seed: int) -> None:
        self.seen = []

    def act(self, obs):
        self.seen.append((obs, self.env.get_state()))
        return np.zeros(7, np.float32)


@pytest.mark.sim
def test_rollouts_show_an_image_policy_its_cameras_pictures_of_the_moment():
    """With a renderer, every step's observation holds <camera>_image, the observe cameras'
    picture of the env's state at that step (as the observe stage pictures a stored state),
    beside the low-dim keys."""
    from mimicgen_pipe import backends
    from mimicgen_pipe.learn.evaluation import evaluation_seed, rollout

    env = backends.make_env("maniskill", "stack_cube")
    renderer = backends.make_renderer("maniskill", "stack_cube", "panda", 40, 32, ("agentview",))
    try:
        policy = Recorder(env)
        seed = evaluation_seed(0, "D1", 0)
        rollout(env, policy, seed, "D1", 3, env.spec.objects, renderer)
        assert len(policy.seen) == 3
        for obs, state in policy.seen:
            assert {"eef_pos", "cubeA_pos", "agentview_image"} <= set(obs)
            image = obs["agentview_image"]
            assert image.dtype == np.uint8 and image.shape == (32, 40, 3)
            np.testing.assert_array_equal(image, renderer.images(state)["agentview"])
        assert policy.seen[0][0]["agentview_image"].std() > 0  # a picture, not a blank
    finally:
        renderer.close()
        env.close()


@pytest.mark.slow
@pytest.mark.sim
@pytest.mark.skipif(
    not external.DEFAULT_PYTHON.exists(),
    reason="the learners' check venv .venv-learners is missing (made by scripts/setup.sh)",
)
def test_robomimic_policy_trained_on_our_export_is_evaluated_here(pipeline, tmp_path):
    """generate -> export -> robomimic's own train.py (BC-RNN, configs/robomimic/, a few
    steps, a checkpoint after each of 2 epochs) -> evaluate_external of the run's models/
    folder: both checkpoints in epoch order on the same scenes of our evaluation seeds, each
    episode run to the task's horizon or to success; the metrics of our evaluation (max and
    last over the checkpoints), the last policy's identity."""
    from mimicgen_pipe.learn.evaluation import evaluation_seed
    from tests.test_learners import learner, short_robomimic_config

    cli("export", "--variant", "D1", "--formats", "robomimic", "--out", str(tmp_path / "x"),
        cwd=pipeline)  # fmt: skip
    config_path = short_robomimic_config("bc_rnn_low_dim", tmp_path / "runs", 2, 5)
    config = json.loads(config_path.read_text())
    config["experiment"]["save"]["every_n_epochs"] = 1
    config["experiment"]["validate"] = False  # 4 demos: too few for a validation batch
    config["train"]["hdf5_validation_filter_key"] = None
    config_path.write_text(json.dumps(config))
    res = learner("python", "-m", "robomimic.scripts.train", "--config", str(config_path),
                  "--dataset", str(tmp_path / "x/demos.hdf5"), cwd=tmp_path)  # fmt: skip
    assert "finished run successfully!" in res.stdout, res.stdout[-3000:] + res.stderr[-3000:]
    (checkpoint,) = (tmp_path / "runs").glob("*/*/models/model_epoch_2.pth")

    cli("evaluate_external", "--policy", f"robomimic:{checkpoint.parent}", "--data", "D1",
        "--variant", "D1", "--episodes", "2", "--metrics", str(tmp_path / "m.json"),
        "--plot", str(tmp_path / "episodes.csv"), cwd=pipeline)  # fmt: skip
    m = json.loads((tmp_path / "m.json").read_text())
    identity = {"stage": "evaluate", "task": "stack_cube", "backend": "maniskill",
                "variant": "D1", "robot": "panda", "data": "D1", "purpose": None}  # fmt: skip
    assert {k: m[k] for k in identity} == identity
    assert (m["policy_format"], m["policy"]) == ("robomimic", str(checkpoint))
    assert m["policy_sha256"] == external.policy_digest(checkpoint)
    assert (m["episodes"], m["seeds"], m["checkpoints"], m["horizon"]) == (2, 1, 2, 200)
    assert m["epoch_unit"] == "epoch" and m["seed0_best_epoch"] in (1, 2)
    rows = list(csv.DictReader((tmp_path / "episodes.csv").open()))
    assert [int(r["epoch"]) for r in rows] == [1, 1, 2, 2]
    seeds = [evaluation_seed(0, "D1", i) for i in range(2)]
    assert [int(r["seed"]) for r in rows] == seeds * 2
    assert all(r["steps"] == "200" or (r["success"] == "1" and int(r["steps"]) < 200)
               for r in rows)  # fmt: skip
    rates = [100.0 * np.mean([r["success"] == "1" for r in rows if r["epoch"] == e])
             for e in ("1", "2")]  # fmt: skip
    assert (m["success_rate_max"], m["success_rate_last"]) == (max(rates), rates[1])

    from mimicgen_pipe import backends

    obs_keys = tuple(backends.task_spec("maniskill", "stack_cube").default_obs_keys)
    spec = PolicySpec("robomimic", str(checkpoint), str(external.DEFAULT_PYTHON), obs_keys, "")
    dims = observation_dims(("cubeA", "cubeB"))
    obs = {k: np.full(d, 0.1, np.float32) for k, d in dims.items()}
    inputs = external.format_module("robomimic").observation(obs, obs_keys)  # as the env gives
    with external.start_policy(spec) as policy:
        assert set(policy.keys) == set(config["observation"]["modalities"]["obs"]["low_dim"])
        runs = []
        for _ in range(2):
            policy.reset(7)
            runs.append(np.stack([policy.act(inputs) for _ in range(12)]))
    np.testing.assert_array_equal(runs[0], runs[1])


@pytest.mark.slow
@pytest.mark.sim
@pytest.mark.skipif(
    not external.DEFAULT_PYTHON.exists(),
    reason="the learners' check venv .venv-learners is missing (made by scripts/setup.sh)",
)
def test_lerobot_policy_trained_on_our_export_is_evaluated_here(pipeline, tmp_path):
    """generate -> LeRobot export -> lerobot-train (a tiny ACT, 4 steps) -> evaluate_external
    on its pretrained_model directory: our evaluation's metrics and seeds, the policy read
    the export's state and environment state, each episode run to the horizon or to
    success."""
    from mimicgen_pipe.learn.evaluation import evaluation_seed
    from tests.test_learners import learner

    cli("export", "--variant", "D1", "--formats", "lerobot", "--out", str(tmp_path / "x"),
        cwd=pipeline)  # fmt: skip
    res = learner(
        "lerobot-train", "--dataset.repo_id=local/stack_cube",
        f"--dataset.root={tmp_path / 'x/lerobot'}", "--policy.type=act",
        "--policy.push_to_hub=false", "--policy.device=cpu", "--policy.dim_model=32",
        "--policy.dim_feedforward=64", "--policy.n_encoder_layers=1",
        "--policy.n_decoder_layers=1", "--policy.chunk_size=10", "--policy.n_action_steps=10",
        "--steps=4", "--batch_size=4", "--num_workers=0", "--save_freq=4", "--eval_freq=0",
        "--wandb.enable=false", f"--output_dir={tmp_path / 'run'}", cwd=tmp_path,
    )  # fmt: skip
    model = tmp_path / "run/checkpoints/last/pretrained_model"
    assert res.returncode == 0 and model.is_dir(), res.stdout[-2000:] + res.stderr[-3000:]

    cli("evaluate_external", "--policy", f"lerobot:{model}", "--data", "D1", "--variant", "D1",
        "--episodes", "2", "--metrics", str(tmp_path / "m.json"),
        "--plot", str(tmp_path / "episodes.csv"), cwd=pipeline)  # fmt: skip
    m = json.loads((tmp_path / "m.json").read_text())
    assert (m["stage"], m["variant"], m["data"], m["robot"]) == ("evaluate", "D1", "D1", "panda")
    assert (m["policy_format"], m["policy_sha256"]) == ("lerobot", external.policy_digest(model))
    assert (m["episodes"], m["seeds"], m["checkpoints"], m["horizon"]) == (2, 1, 1, 200)
    assert (m["seed0_best_epoch"], m["epoch_unit"]) == (4, "step")  # checkpoints/last: step 4
    rows = list(csv.DictReader((tmp_path / "episodes.csv").open()))
    assert [int(r["seed"]) for r in rows] == [evaluation_seed(0, "D1", i) for i in range(2)]
    assert all(r["steps"] == "200" or (r["success"] == "1" and int(r["steps"]) < 200)
               for r in rows)  # fmt: skip
    config = json.loads((model / "config.json").read_text())
    assert set(config["input_features"]) == {"observation.state", "observation.environment_state"}


# A checkpoint with no pickle payload at all (it loads with weights_only=True) whose config
# names an image encoder by a string robomimic's VisualCore would eval().
HOSTILE_CHECKPOINT = """
import json, sys, torch
from robomimic.config import config_factory
config = config_factory("bc")
with config.values_unlocked():
    config.observation.modalities.obs.low_dim = ["eef_pos"]
    config.observation.modalities.obs.rgb = ["agentview_image"]
    config.observation.encoder.rgb.core_kwargs.backbone_class = (
        f"(__import__('os').system('touch {sys.argv[2]}'), ResNet18Conv)[1]")
torch.save({"algo_name": "bc", "config": config.dump(), "model": {"nets": {}},
            "env_metadata": {}, "shape_metadata": {
                "ac_dim": 7, "all_obs_keys": ["eef_pos", "agentview_image"], "use_images": True,
                "all_shapes": {"eef_pos": [3], "agentview_image": [3, 84, 84]}}}, sys.argv[1])
"""


@pytest.mark.parametrize(
    ("key", "value"),
    [("core_kwargs.backbone_class", "ResNet18Conv"), ("core_kwargs.pool_class", "SpatialSoftmax"),
     ("core_class", "VisualCore"), ("obs_randomizer_class", "CropRandomizer")],
)  # fmt: skip
def test_robomimic_class_names_outside_the_allowlist_are_refused_naming_the_key(key, value):
    from mimicgen_pipe.formats.external import robomimic

    def config(name: object) -> dict:
        rgb: dict = {"core_class": "VisualCore", "core_kwargs": {}}
        *parents, last = key.split(".")
        node = rgb
        for part in parents:
            node = node[part]
        node[last] = name
        return {"config": json.dumps({"observation": {"encoder": {"rgb": rgb}}})}

    robomimic.checkpoint_config(config(value))  # robomimic's own class: accepted
    robomimic.checkpoint_config(config(None))
    for bad in (f"__import__('os').system('true') or {value}", f" {value}", ["x"]):
        with pytest.raises(ValueError, match=rf"config\.observation\.encoder\.rgb\.{key}: "):
            robomimic.checkpoint_config(config(bad))
    with pytest.raises(ValueError, match=r"config\.x\.0\.my_class: 'Mine' is not a class"):
        robomimic.checkpoint_config({"config": json.dumps({"x": [{"my_class": "Mine"}]})})
    with pytest.raises(ValueError, match="not a robomimic config JSON string"):
        robomimic.checkpoint_config({"config": "{"})


@pytest.mark.skipif(
    not external.DEFAULT_PYTHON.exists(),
    reason="the learners' check venv .venv-learners is missing (made by scripts/setup.sh)",
)
def test_a_checkpoint_whose_config_would_run_code_is_refused_and_runs_none(tmp_path):
    import subprocess

    checkpoint, marker = tmp_path / "model.pth", tmp_path / "marker"
    made = subprocess.run(
        [str(external.DEFAULT_PYTHON), "-c", HOSTILE_CHECKPOINT, str(checkpoint), str(marker)],
        capture_output=True, text=True,
    )  # fmt: skip
    assert made.returncode == 0, made.stderr[-2000:]
    (tmp_path / "params.yaml").write_text(SMALL_PARAMS)
    res = cli("evaluate_external", "--policy", f"robomimic:{checkpoint}", "--data", "D0",
              "--variant", "D0", "--episodes", "1", "--metrics", str(tmp_path / "m.json"),
              cwd=tmp_path, check=False)  # fmt: skip
    assert not marker.exists()
    assert res.returncode == 2, res.stderr[-2000:]
    (line,) = res.stderr.strip().splitlines()
    assert "config.observation.encoder.rgb.core_kwargs.backbone_class" in line
    assert "not a class this server builds" in line and len(line) < 1000
    assert not (tmp_path / "m.json").exists()


def test_a_robomimic_run_folder_is_its_checkpoints_in_epoch_order(tmp_path):
    """robomimic:<folder> stands for its model_epoch_<N>.pth by epoch (100 after 50, not
    before it as by name), other files left out; a file stands for itself; a folder without
    checkpoints, or with one that torch did not save, is refused saying why."""
    import torch

    fmt = external.format_module("robomimic")
    for epoch in (100, 50, 150):
        torch.save({"epoch": torch.tensor(epoch)}, tmp_path / f"model_epoch_{epoch}.pth")
    (tmp_path / "config.json").write_text("{}")
    assert [p.name for p in fmt.run_checkpoints(tmp_path)] == [
        "model_epoch_50.pth", "model_epoch_100.pth", "model_epoch_150.pth"
    ]  # fmt: skip
    assert fmt.why_not(tmp_path) is None
    assert fmt.run_checkpoints(tmp_path / "model_epoch_50.pth") == [tmp_path / "model_epoch_50.pth"]
    empty = tmp_path / "empty"
    empty.mkdir()
    assert "without model_epoch_<N>.pth" in fmt.why_not(empty)
    (tmp_path / "model_epoch_200.pth").write_text("not a checkpoint")
    assert "not a checkpoint torch saved" in fmt.why_not(tmp_path)
