"""robomimic's and LeRobot's own trainers train on our exports, with the commands and configs
that docs/exports.md gives: robomimic's scripts/train.py (BC-RNN, low-dim and image configs of
configs/robomimic/) on the robomimic export, lerobot-train (ACT, configs/lerobot/act.json) on
the LeRobot export, with and without camera video. Each runs a few steps in the learners'
check venv (.venv-learners, made by scripts/setup.sh) on a small synthetic store exported by
``mimicgen-pipe export``, as a generated store and as an observed one (with images); the
tests skip without that venv."""

from __future__ import annotations

import csv
import json
import math
import os
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

from mimicgen_pipe.data.store import write_store
from tests.conftest import REPO, cli

LEARNERS = REPO / ".venv-learners"
CHECKS = REPO / "tests/learners"
pytestmark = pytest.mark.skipif(
    not (LEARNERS / "bin/python").exists(),
    reason="the learners' check venv .venv-learners is missing (made by scripts/setup.sh)",
)

TASK = "stack_cube"
# 9 train episodes, more steps than a batch: robomimic drops a last partial batch
LENGTHS = (40,) * 10
# random states, which no simulator restores: no success evaluated per step
PARAMS = f"task: {TASK}\nexport: {{formats: [robomimic, lerobot], step_success: false}}\n"
# the contract's default cameras (a front view and a wrist view, as the paper's image agents
# see) and size
CAMERAS = ("agentview", "eye_in_hand")
IMAGE_SIZE = (84, 84)


def _dims(key: str) -> int:
    return {"quat": 4, "qpos": 2}.get(key.rsplit("_", 1)[-1], 3)


def _pose_rows(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return np.concatenate(
        [rng.normal(size=(n, 3)), q / np.linalg.norm(q, axis=1, keepdims=True)], 1
    )


def learnable_store(path: Path, images: bool) -> None:
    """A generated stack_cube store whose actions are a fixed smooth function of the
    observations (so that a few training steps lower the loss); with ``images``, an observed
    one: images of both cameras in which a square moves with the end effector (across the
    front view, up and down the wrist view)."""
    from mimicgen_pipe import backends

    keys = backends.task_spec("maniskill", TASK).obs_keys
    rng = np.random.default_rng(0)
    weights = rng.normal(size=(sum(map(_dims, keys)), 6)) / 4
    h, w = IMAGE_SIZE
    steps = []
    for t in LENGTHS:
        obs = {k: np.cumsum(rng.normal(0, 0.05, (t, _dims(k))), 0).astype(np.float32) for k in keys}
        flat = np.concatenate([obs[k] for k in keys], 1)
        gripper = np.where(np.arange(t) < t // 2, 1.0, -1.0).astype(np.float32)
        actions = np.concatenate([np.tanh(flat @ weights), gripper[:, None]], 1)
        frames = {c: np.full((t, h, w, 3), 60, np.uint8) for c in CAMERAS}
        corner = np.clip(((obs["eef_pos"] + 1) * 30).astype(int), 0, h - 12)
        for s, (y, x, z) in enumerate(corner):
            frames["agentview"][s, y : y + 12, x : x + 12] = (230, 200, 40)
            frames["eye_in_hand"][s, z : z + 12, 10:22] = (40, 200, 230)
        steps.append({
            "actions": actions.astype(np.float32),
            "env_state": rng.normal(size=(t, 20)).astype(np.float32),
            "eef_pose": _pose_rows(rng, t),
            "target_pose": _pose_rows(rng, t),
            "object_poses/cubeA": _pose_rows(rng, t),
            "object_poses/cubeB": _pose_rows(rng, t),
            "gripper": gripper,
            "subtask_signals/grasp_cubeA": np.arange(t) >= t // 2,
            **{f"obs/{k}": v for k, v in obs.items()},
            **({f"obs/{c}_image": frames[c] for c in CAMERAS} if images else {}),
        })  # fmt: skip
    n = len(LENGTHS)
    episodes = {"seed": np.arange(n, dtype=np.int64), "success": np.ones(n, bool),
                "source_demo": rng.integers(0, 10, (n, 2))}  # fmt: skip
    attrs = {"task": TASK, "variant": "D1", "backend": "maniskill", "robot": "panda",
             "control_mode": "pd_ee_delta_pose", "control_freq": 20}  # fmt: skip
    if images:
        attrs["cameras"] = {c: {"height": h, "width": w} for c in CAMERAS}
    write_store(path, "generated", steps, episodes, attrs)


@pytest.fixture(scope="module")
def exports(tmp_path_factory) -> dict[str, Path]:
    """The export directories (robomimic and LeRobot, as the export stage writes them) of a
    small learnable store: "generated" without images, "observed" with them."""
    work = tmp_path_factory.mktemp("learners")
    (work / "params.yaml").write_text(PARAMS)
    out = {}
    for name, images in (("generated", False), ("observed", True)):
        learnable_store(work / f"{name}.zarr", images)
        cli("export", "--store", f"{name}.zarr", "--out", f"export/{name}", cwd=work)
        out[name] = work / "export" / name
    return out


def learner(*args: str, cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    """Run ``args`` (a command of the learners' venv: bin/<args[0]>) offline in ``cwd``."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env |= {"HF_HOME": str(cwd / "hf"), "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled",
            "MPLCONFIGDIR": str(cwd / "mpl")}  # fmt: skip
    return subprocess.run(
        [str(LEARNERS / "bin" / args[0]), *args[1:]],
        cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout,
    )  # fmt: skip


def short_robomimic_config(name: str, out: Path, epochs: int, steps: int) -> Path:
    """configs/robomimic/<name>.json with only its run length shortened and its output
    directory moved to ``out``; returns the written config."""
    config = json.loads((REPO / "configs/robomimic" / f"{name}.json").read_text())
    config["train"] |= {"output_dir": str(out), "num_epochs": epochs}
    config["experiment"]["epoch_every_n_steps"] = steps
    config["experiment"]["save"]["every_n_epochs"] = epochs
    path = out.parent / f"{name}.json"
    path.write_text(json.dumps(config, indent=4))
    return path


def robomimic_losses(stdout: str) -> list[float]:
    """The training loss robomimic's train.py prints after each epoch, read as the
    train_robomimic stage reads robomimic's log."""
    from mimicgen_pipe.formats.external import epoch_losses

    return [loss for _, loss in epoch_losses(stdout)]


@pytest.mark.parametrize(
    ("config", "store", "epochs", "steps"),
    [
        ("bc_rnn_low_dim", "generated", 3, 2),
        pytest.param("bc_rnn_image", "observed", 3, 3, marks=pytest.mark.slow),
    ],
)
def test_robomimic_trains_bc_rnn_on_our_export(exports, tmp_path, config, store, epochs, steps):
    """robomimic's own train.py (rollouts off) trains BC-RNN on our HDF5: it ends with
    "finished run successfully!" (it exits 0 on errors too), logs a finite loss per epoch that
    falls, and writes a checkpoint from which robomimic rebuilds the policy. The low-dim
    config's observation keys are robomimic's own default BC config's, MimicGen's Stack
    keys (robot0_eef_pos, robot0_eef_quat, robot0_gripper_qpos, object), unedited."""
    path = short_robomimic_config(config, tmp_path / "runs", epochs, steps)
    res = learner("python", "-m", "robomimic.scripts.train", "--config", str(path),
                  "--dataset", str(exports[store] / "demos.hdf5"), cwd=tmp_path)  # fmt: skip
    assert res.returncode == 0 and "finished run successfully!" in res.stdout, res.stdout[-3000:]
    losses = robomimic_losses(res.stdout)
    assert len(losses) == epochs and all(map(math.isfinite, losses)), losses
    assert losses[-1] < losses[0], losses
    (checkpoint,) = (tmp_path / "runs").glob(f"*/*/models/model_epoch_{epochs}.pth")
    res = learner("python", str(CHECKS / "check_robomimic_checkpoint.py"), str(checkpoint),
                  str(exports[store] / "demos.hdf5"), cwd=tmp_path)  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    report = json.loads(res.stdout.splitlines()[-1])
    wanted = json.loads((REPO / "configs/robomimic" / f"{config}.json").read_text())
    modalities = wanted["observation"]["modalities"]["obs"]
    assert report["algo_name"] == "bc"
    assert sorted(report["obs_keys"]) == sorted(modalities["low_dim"] + modalities["rgb"])
    if config == "bc_rnn_low_dim":  # robomimic's (and MimicGen's Stack) keys, unedited
        assert modalities["low_dim"] == report["stock_low_dim"], report["stock_low_dim"]
    assert report["action_shape"] == [7] and report["action_finite"]
    assert any(k.startswith("policy.nets.rnn") for k in report["model_keys"]), report


@pytest.mark.slow
def test_the_robomimic_trainer_fails_a_run_that_saves_no_checkpoint(exports, tmp_path):
    """mimicgen_pipe/formats/external/_robomimic_train.py (the README's robomimic command) exits 1
    after a run whose epochs miss every save (robomimic's train.py exits 0), and saves the
    last epoch of a run it shortens itself (--num_epochs)."""
    from mimicgen_pipe.formats.external import _robomimic_train

    def run(out: Path, *extra: str) -> subprocess.CompletedProcess:
        """One epoch of one step, a checkpoint every 2 epochs, into ``out``."""
        out.parent.mkdir()
        path = short_robomimic_config("bc_rnn_low_dim", out, 1, 1)
        config = json.loads(path.read_text())
        config["experiment"]["save"]["every_n_epochs"] = 2
        path.write_text(json.dumps(config))
        return learner("python", _robomimic_train.__file__, "--config", str(path), "--dataset",
                       str(exports["generated"] / "demos.hdf5"), *extra, cwd=tmp_path)  # fmt: skip

    res = run(tmp_path / "unsaved" / "runs")
    assert res.returncode == 1, res.stdout[-3000:] + res.stderr[-3000:]
    assert "robomimic saved no checkpoint" in res.stdout + res.stderr
    res = run(tmp_path / "saved" / "runs", "--num_epochs", "1")
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert list((tmp_path / "saved/runs").glob("*/*/models/model_epoch_1.pth"))


def test_train_robomimic_normalizes_a_sequence_dataset_as_robomimic_does(exports, tmp_path):
    """train_robomimic (robomimic 0.3.0's own training at our profile's size, here 2x8 LSTM,
    3 epochs of 4 steps, a checkpoint every epoch) with --obs normalized: robomimic 0.3.0's
    own train.py stops on this sequence dataset, ours trains. Each checkpoint carries the
    mean and std robomimic computed over the export's training demos (mask/train), the loss
    curve has one finite row per epoch, and the metrics name the checkpoints' epochs."""
    import h5py

    params = tmp_path / "params.yaml"
    params.write_text(PARAMS + "train: {cpu: {hidden: 8, epochs: 3, steps_per_epoch: 4, "
                      "batch_size: 4, seeds: [3]}}\nevaluate: {every_epochs: 1}\n")  # fmt: skip
    dataset = exports["generated"] / "demos.hdf5"
    cli("train_robomimic", "--params", str(params), "--dataset", str(dataset), "--obs",
        "normalized", "--out", "run", "--metrics", "m.json", "--plot", "c.csv",
        cwd=tmp_path)  # fmt: skip
    m = json.loads((tmp_path / "m.json").read_text())
    assert (m["stage"], m["task"], m["data"]) == ("train", TASK, "D0")
    assert (m["checkpoint_epochs"], m["normalize_obs"], m["seed"]) == ([1, 2, 3], True, 3)
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == [
        f"model_epoch_{e}.pth" for e in (1, 2, 3)
    ]
    curve = list(csv.DictReader((tmp_path / "c.csv").open()))
    assert [int(r["epoch"]) for r in curve] == [1, 2, 3]
    assert all(math.isfinite(float(r["loss"])) for r in curve)
    with h5py.File(dataset) as f:
        demos = [d.decode() for d in f["mask/train"][:]]
        pos = np.concatenate([f[f"data/{d}/obs/robot0_eef_pos"][:] for d in demos]).astype(float)
    import torch

    ckpt = torch.load(tmp_path / "run/model_epoch_3.pth", weights_only=True)
    stats = ckpt["obs_normalization_stats"]["robot0_eef_pos"]
    assert np.allclose(stats["mean"][0], pos.mean(0), atol=1e-5)
    assert np.allclose(stats["std"][0], pos.std(0) + 1e-3, atol=1e-5)  # robomimic's + 1e-3
    assert json.loads(ckpt["config"])["algo"]["rnn"]["hidden_dim"] == 8


def test_robomimic_training_normalizes_each_step_once(exports, tmp_path):
    """robomimic 0.3.0 normalises a training window twice (its dataset, then
    postprocess_batch_for_training) and a rollout step once; with train_robomimic's patch,
    robomimic's own dataset and batch processing feed the network (raw - mean) / std, the
    rollout's input, once."""
    from mimicgen_pipe.formats.external import _robomimic_train

    res = learner("python", str(CHECKS / "check_robomimic_normalization.py"),
                  _robomimic_train.__file__, str(exports["generated"] / "demos.hdf5"),
                  cwd=tmp_path)  # fmt: skip
    assert res.returncode == 0, res.stderr[-3000:]
    report = json.loads(res.stdout.splitlines()[-1])
    assert report["error"] < 1e-4, report
    assert report["moved"] > 0.1, report  # normalised at all


def lerobot_losses(log: str) -> list[float]:
    """The training loss lerobot-train logs every log_freq steps."""
    return [float(x) for x in re.findall(r" step:\d+ .*? loss:([-+.\deE]+|nan|inf) ", log)]


@pytest.mark.slow
@pytest.mark.parametrize("store", ["observed", "generated"])
def test_lerobot_trains_act_on_our_export(exports, tmp_path, store):
    """lerobot-train trains ACT (configs/lerobot/act.json) on our LeRobot export:
    observation.state and observation.environment_state as inputs, and the camera video of
    an observed store. It exits 0, logs a finite loss every step that falls, and writes a
    policy directory that lerobot loads back with our features, every stored weight in it."""
    steps = 3
    root = exports[store] / "lerobot"
    res = learner("lerobot-train", f"--config_path={REPO / 'configs/lerobot/act.json'}",
                  f"--dataset.root={root}", f"--output_dir={tmp_path / 'act'}",
                  f"--steps={steps}", f"--save_freq={steps}", "--log_freq=1", "--num_workers=0",
                  cwd=tmp_path)  # fmt: skip
    log = res.stdout + res.stderr
    assert res.returncode == 0, log[-3000:]
    losses = lerobot_losses(log)
    assert len(losses) == steps and all(map(math.isfinite, losses)), losses
    assert losses[-1] < losses[0], losses
    policy = tmp_path / f"act/checkpoints/{steps:06d}/pretrained_model"
    assert (policy / "model.safetensors").is_file() and (policy / "config.json").is_file()
    res = learner("python", str(CHECKS / "check_lerobot_checkpoint.py"), str(policy), cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    report = json.loads(res.stdout.splitlines()[-1])
    h, w = IMAGE_SIZE
    images = {f"observation.images.{c}": [3, h, w] for c in CAMERAS if store == "observed"}
    assert report["type"] == "act"
    assert report["input_features"] == {
        "observation.state": [9],  # eef_pos, eef_quat, gripper_qpos
        "observation.environment_state": [23],  # the cubes' poses and relative positions
        **images,
    }
    assert report["output_features"] == {"action": [7]}
    assert report["loaded_equal"] == report["stored_tensors"] > 0


@pytest.mark.slow
def test_lerobot_trains_diffusion_on_our_export(exports, tmp_path):
    """lerobot-train trains Diffusion Policy (configs/lerobot/diffusion.json, made tiny: a
    small U-Net, no learning-rate warm-up) on our LeRobot export, observation.state and
    observation.environment_state as inputs: it exits 0, logs a finite loss every step, lower
    over the last steps than over the first (a noise-prediction loss at random diffusion
    steps: averaged over three), and writes a policy directory that lerobot loads back."""
    steps = 8
    root = exports["generated"] / "lerobot"
    res = learner("lerobot-train", f"--config_path={REPO / 'configs/lerobot/diffusion.json'}",
                  f"--dataset.root={root}", f"--output_dir={tmp_path / 'dp'}",
                  "--policy.down_dims=[16,32]", "--policy.diffusion_step_embed_dim=16",
                  "--policy.optimizer_lr=1e-3", "--policy.scheduler_warmup_steps=0",
                  "--batch_size=16", f"--steps={steps}", f"--save_freq={steps}", "--log_freq=1",
                  "--num_workers=0", cwd=tmp_path)  # fmt: skip
    log = res.stdout + res.stderr
    assert res.returncode == 0, log[-3000:]
    losses = lerobot_losses(log)
    assert len(losses) == steps and all(map(math.isfinite, losses)), losses
    assert np.mean(losses[-3:]) < np.mean(losses[:3]), losses
    policy = tmp_path / f"dp/checkpoints/{steps:06d}/pretrained_model"
    res = learner("python", str(CHECKS / "check_lerobot_checkpoint.py"), str(policy), cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    report = json.loads(res.stdout.splitlines()[-1])
    assert report["type"] == "diffusion"
    assert report["input_features"] == {
        "observation.state": [9],
        "observation.environment_state": [23],
    }
    assert report["output_features"] == {"action": [7]}
    assert report["loaded_equal"] == report["stored_tensors"] > 0
