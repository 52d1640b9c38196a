"""Image policies (train.profile cpu_image): the camera encoder's shapes, the pixel-shift
augmentation, a tiny image policy that learns from pixels alone, its checkpoint acting on
images, and the train and evaluate stages on an observed store, rollouts on rendered
observations included, with their bad-input errors."""

from __future__ import annotations

import csv
import json
import pickle
from dataclasses import replace

import numpy as np
import pytest
import torch

from mimicgen_pipe.data.params import TrainParams
from mimicgen_pipe.learn.policy import BCRNN, ImageEncoder, PolicyConfig, RolloutPolicy
from mimicgen_pipe.learn.training import (
    PolicyTraining,
    TrainingData,
    TrainJob,
    load_checkpoint,
    save_checkpoint,
    train_policies,
    train_policy,
)
from mimicgen_pipe.learn.training_setup import (
    MappedImages,
    SequenceData,
    TrainConfig,
    shift_images,
)
from tests.conftest import cli

SIZE = 32  # px: small images, the code path of 84


def image_config(**kw) -> PolicyConfig:
    d = dict(hidden=16, layers=1, seq_len=4, modes=2, image_keys=("agentview_image",),
             image_size=(SIZE, SIZE), channels=8, keypoints=8, image_features=8)  # fmt: skip
    return PolicyConfig(("eef_pos",), (3,), 2, **(d | kw))


def test_encoder_and_policy_shapes():
    enc = ImageEncoder(84, 84, channels=16, keypoints=12, features=20)
    out = enc(torch.randint(0, 256, (5, 84, 84, 3), dtype=torch.uint8))
    assert out.shape == (5, 20) and torch.isfinite(out).all()
    # a 17-px image is the smallest the three convolutions leave a map of
    assert ImageEncoder(17, 17, 4, 4, 4)(torch.zeros(1, 17, 17, 3, dtype=torch.uint8)).shape == (
        1,
        4,
    )
    with pytest.raises(ValueError, match="too small"):
        ImageEncoder(16, 40, 4, 4, 4)

    config = image_config(image_keys=("agentview_image", "eye_in_hand_image"), image_size=(24, 40))
    model = BCRNN(config)
    assert config.lstm_input == 3 + 2 * 8 and model.lstm.input_size == 19
    assert len(model.encoders) == 2
    images = torch.randint(0, 256, (3, 4, 2, 24, 40, 3), dtype=torch.uint8)
    means, scales, logits, _ = model(torch.randn(3, 4, 3), images=images)
    assert means.shape == scales.shape == (3, 4, 2, 2) and logits.shape == (3, 4, 2)
    with pytest.raises(ValueError, match="needs images"):
        model(torch.randn(3, 4, 3))


def test_image_fields_are_recorded_only_for_an_image_policy():
    low_dim = PolicyConfig(("eef_pos",), (3,), 7)
    assert set(low_dim.as_dict()) == {"obs_keys", "obs_dims", "action_dim", "hidden", "layers",
                                      "seq_len", "modes", "min_std"}  # fmt: skip
    config = image_config()
    assert PolicyConfig.from_dict(config.as_dict()) == config
    assert PolicyConfig.from_dict(low_dim.as_dict()) == low_dim
    # a low-dim network is built as before image policies: same seeded weights, same names
    torch.manual_seed(3)
    names = list(BCRNN(low_dim).state_dict())
    assert not any(n.startswith("encoders") for n in names)


def test_shift_moves_each_image_within_the_bound_and_repeats_the_border():
    n, h, w, s = 400, 12, 10, (3, 2)
    # every pixel of every image distinct: one shift alone explains each output
    images = torch.arange(n * h * w * 3, dtype=torch.int64).view(n, h, w, 3)
    out = shift_images(images, s, torch.Generator().manual_seed(0))
    assert out.shape == images.shape
    seen = set()
    for i in range(n):
        src = np.pad(images[i].numpy(), ((s[0], s[0]), (s[1], s[1]), (0, 0)), mode="edge")
        found = [
            (dy, dx)
            for dy in range(-s[0], s[0] + 1)
            for dx in range(-s[1], s[1] + 1)
            if np.array_equal(
                out[i].numpy(), src[s[0] - dy : s[0] - dy + h, s[1] - dx : s[1] - dx + w]
            )
        ]
        assert len(found) == 1, f"image {i}: no shift within {s} explains it"
        seen.add(found[0])
    assert len(seen) == (2 * s[0] + 1) * (2 * s[1] + 1)  # every shift drawn, extremes too
    same = shift_images(images, s, torch.Generator().manual_seed(0))
    assert torch.equal(out, same)  # the draws are the generator's
    assert shift_images(images, (0, 0), torch.Generator()) is images


def square_episodes(n_episodes: int, steps: int, seed: int) -> SequenceData:
    """Episodes whose only information is in the picture: a bright square at a random spot
    each step, the action its centre in [-1, 1]; the low-dim observation is constant."""
    rng = np.random.default_rng(seed)
    n = n_episodes * steps
    images = np.zeros((n, 1, SIZE, SIZE, 3), np.uint8)
    actions = np.empty((n, 2), np.float32)
    for t in range(n):
        y, x = rng.integers(0, SIZE - 6, 2)
        images[t, 0, y : y + 6, x : x + 6] = 255
        actions[t] = (np.array([x, y]) + 3) / SIZE * 2 - 1
    ends = np.arange(1, n_episodes + 1, dtype=np.int64) * steps
    return SequenceData(np.zeros((n, 3), np.float32), actions, ends, images)


def test_a_tiny_image_policy_learns_where_the_square_is():
    train, val = square_episodes(12, 10, seed=0), square_episodes(3, 10, seed=1)
    config = TrainConfig(image_config(modes=1), batch_size=8, lr=3e-3, epochs=6,
                         steps_per_epoch=40, checkpoint_every=6, shift=(2, 2))  # fmt: skip
    saved: list[BCRNN] = []
    torch.set_num_threads(1)
    rows = train_policy(train, val, config, seed=0, on_checkpoint=lambda e, m: saved.append(m))
    assert rows[-1]["loss"] < rows[0]["loss"] - 1.0
    assert rows[-1]["val_loss"] < rows[0]["val_loss"] - 1.0
    # the policy's mean action follows the square on held-out pictures
    model = saved[-1].eval()
    with torch.no_grad():
        means, *_ = model(
            torch.from_numpy(val.obs)[:, None], images=torch.from_numpy(val.images)[:, None]
        )
    error = np.abs(means[:, 0, 0].numpy() - val.actions).mean()
    assert error < 0.5 * np.abs(val.actions - val.actions.mean(0)).mean()


def test_mapped_images_index_as_the_array_and_pickle_as_their_path(tmp_path):
    images = square_episodes(3, 10, seed=0).images
    mapped = MappedImages.write(tmp_path / "images.npy", images)
    rows = np.array([[4, 2], [29, 0]])
    assert np.array_equal(mapped[rows], images[rows]) and mapped.shape == images.shape
    sent = pickle.dumps(mapped)
    assert len(sent) < 1000 < images.nbytes  # the path, not the pictures
    assert np.array_equal(pickle.loads(sent)[rows], images[rows])


def test_image_trainings_side_by_side_give_the_checkpoints_one_by_one_gives(tmp_path):
    """Two seeds in two processes, each reading the images mapped from one file, save the
    bytes that the same two trainings save one after the other in this process."""
    train, val = square_episodes(6, 10, seed=0), square_episodes(2, 10, seed=1)
    config = TrainConfig(image_config(modes=1), batch_size=4, lr=3e-3, epochs=2,
                         steps_per_epoch=3, checkpoint_every=2, shift=(2, 2))  # fmt: skip
    data = TrainingData(train, val, (3,), 2, {}, ("agentview",), (SIZE, SIZE))
    training = PolicyTraining("D0", data, config, {"task": "stack_cube"})
    t = TrainParams(profile="cpu_image")
    t = replace(t, cpu_image=replace(t.cpu_image, seeds=[0, 1], threads=1))
    saved = {}
    for side_by_side in (1, 2):
        out = tmp_path / f"side_by_side_{side_by_side}"
        job = TrainJob("stack_cube", "maniskill", t, (), (training,), side_by_side)
        curves = train_policies(job, [out])
        saved[side_by_side] = (
            {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*.pt"))},
            [{k: v for k, v in r.items() if k != "seconds"} for r in curves[0]],
        )
    assert len(saved[1][0]) == 2 and saved[1] == saved[2]


def test_an_image_checkpoint_loads_and_acts_on_the_pictures(tmp_path):
    torch.manual_seed(0)
    model = BCRNN(image_config())
    save_checkpoint(tmp_path / "c.pt", model, {"task": "stack_cube", "epoch": 1})
    loaded, _ = load_checkpoint(tmp_path / "c.pt")
    assert loaded.config == model.config
    policy = RolloutPolicy(loaded, component="most_likely")
    obs = {"eef_pos": np.zeros(3, np.float32)}
    rng = np.random.default_rng(0)
    actions = []
    for _ in range(2):
        policy.reset(0)
        image = rng.integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8)
        actions.append(policy.act(obs | {"agentview_image": image}))
    assert actions[0].shape == (2,) and not np.array_equal(actions[0], actions[1])
    batch = torch.from_numpy(np.stack([image]))[None, None]
    means, _, logits, _ = model(torch.zeros(1, 1, 3), images=batch)
    k = int(torch.argmax(logits[0, 0]))
    np.testing.assert_allclose(actions[1], means[0, 0, k].detach().numpy(), atol=1e-3)


TINY_IMAGE = """
task: stack_cube
train:
  profile: cpu_image
  num_demos: 2
  val_fraction: 0.0
  cpu_image: {{hidden: 16, layers: 1, seq_len: 5, batch_size: 4, lr: 0.001, epochs: 2,
    steps_per_epoch: 3, checkpoint_every: 2, seeds: [0], threads: 1, device: cpu,
    cameras: {cameras}, image_size: {size}, channels: 4, keypoints: 4, image_features: 4}}
evaluate: {{episodes: 1, every_epochs: 2, workers: 1}}
observe: {{cameras: [agentview], height: {h}, width: {w}, workers: 1, episodes: 2}}
"""


@pytest.fixture(scope="module")
def observed(pipeline, tmp_path_factory):
    """The session pipeline's first 2 D1 demos observed by agentview at 24x32 px."""
    work = tmp_path_factory.mktemp("image_policy")
    (work / "params.yaml").write_text(
        TINY_IMAGE.format(cameras="[agentview]", size="[24, 32]", h=24, w=32)
    )
    store = pipeline / "data/generated/stack_cube_D1.zarr"
    cli("observe", "--variant", "D1", "--store", str(store), "--out", "observed.zarr",
        "--metrics", "observe.json", cwd=work)  # fmt: skip
    return work


def train(work, store, params="params.yaml"):
    return cli("train", "--params", params, "--data", "D1", "--store", str(store),
               "--out", "policy", "--metrics", "train.json", "--plot", "train.csv",
               cwd=work, check=False)  # fmt: skip


@pytest.mark.sim
def test_train_and_evaluate_an_image_policy_on_rendered_observations(observed):
    res = train(observed, "observed.zarr")
    assert res.returncode == 0, res.stderr[-2000:]
    model, meta = load_checkpoint(observed / "policy/seed0/epoch00002.pt")
    assert model.config.image_keys == ("agentview_image",)
    assert model.config.image_size == (24, 32)
    # the robot's own keys beside the camera, no object poses
    assert model.config.obs_keys == ("eef_pos", "eef_quat", "gripper_qpos")
    assert meta["train_params"]["cpu_image"]["cameras"] == ["agentview"]
    res = cli("evaluate", "--data", "D1", "--variant", "D1", "--policies", "policy",
              "--metrics", "eval.json", "--plot", "eval.csv", cwd=observed)  # fmt: skip
    assert "cameras agentview, rendered at 24x32 (HxW) every step" in res.stdout
    assert "agentview_image (24, 32, 3) uint8" in res.stdout
    metrics = json.loads((observed / "eval.json").read_text())
    assert metrics["cameras"] == ["agentview"] and metrics["image_size"] == [24, 32]
    rows = list(csv.DictReader((observed / "eval.csv").open()))
    assert [(r["seed"], r["epoch"]) for r in rows] == [("0", "2")]


@pytest.mark.sim
@pytest.mark.parametrize(
    ("store", "cameras", "size", "message"),
    [
        ("generated", "[agentview]", "[24, 32]", "no camera images, but the image policy sees"),
        ("observed", "[agentview, eye_in_hand]", "[24, 32]", "no images of camera 'eye_in_hand'"),
        ("observed", "[agentview]", "[32, 32]", "agentview images are 24x32 px"),
    ],
)
def test_an_image_profile_that_does_not_fit_the_store_is_one_error(
    observed, pipeline, store, cameras, size, message
):
    path = (
        pipeline / "data/generated/stack_cube_D1.zarr" if store == "generated" else "observed.zarr"
    )
    h, w = json.loads(size)
    text = TINY_IMAGE.format(cameras=cameras, size=size, h=h, w=w)
    (observed / "bad.yaml").write_text(text)
    res = train(observed, path, "bad.yaml")
    assert res.returncode == 2 and message in res.stderr, res.stderr[-2000:]
    assert res.stderr.count("error:") == 1
    assert not (observed / "bad_policy").exists()


def test_object_keys_with_an_image_profile_are_refused(tmp_path):
    text = TINY_IMAGE.format(cameras="[agentview]", size="[24, 32]", h=24, w=32)
    text = text.replace("train:\n", "train:\n  obs_keys: [eef_pos, cubeA_pos]\n")
    (tmp_path / "params.yaml").write_text(text)
    res = cli("train", "--data", "D1", cwd=tmp_path, check=False)
    assert res.returncode == 2
    assert "train.obs_keys: ['cubeA_pos'] are the objects' keys" in res.stderr
    assert res.stderr.count("error:") == 1
