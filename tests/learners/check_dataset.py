"""Load an exported dataset with lerobot's LeRobotDataset
(offline) and compare every frame with the arrays in EXPECTED.npz, camera images (decoded from
the videos), subtask labels and next.reward, next.done, next.success included, each
video feature's camera calibration with calibration/<video key>/{intrinsics,pose}, info.json's
"mimicgen_pipe" with the JSON of provenance, and README.md as a Hugging Face dataset card. With
--policies, also build lerobot's ACT and Diffusion configs from the dataset's features, as
lerobot-train does, and run their feature checks. Prints "ok" when all match.

usage: check_dataset.py DATASET_DIR EXPECTED.npz [--policies]

Run in the learners' check venv (.venv-learners), where lerobot decodes the videos with its
own decoder (torchcodec over the system's FFmpeg).
"""

import os
import sys

os.environ.setdefault("HF_HUB_OFFLINE", "1")  # a missing file fails at once, never downloads

import json  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from huggingface_hub import DatasetCard  # noqa: E402
from lerobot.datasets.lerobot_dataset import CODEBASE_VERSION, LeRobotDataset  # noqa: E402

MAX_IMAGE_ERROR = 12.0  # mean absolute error of a decoded frame, 0..255 (AV1 at crf 30)


def check_policy_features(ds: LeRobotDataset) -> None:
    """ACT's and Diffusion's feature checks accept the dataset's features, split into inputs
    and outputs as lerobot-train's make_policy splits them."""
    from lerobot.configs.types import FeatureType
    from lerobot.datasets.utils import dataset_to_policy_features
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

    features = dataset_to_policy_features(ds.meta.features)
    outputs = {k: f for k, f in features.items() if f.type is FeatureType.ACTION}
    inputs = {k: f for k, f in features.items() if k not in outputs}
    for config in (ACTConfig, DiffusionConfig):
        policy = config(input_features=inputs, output_features=outputs)
        policy.validate_features()
        assert policy.env_state_feature is not None, config
        assert list(policy.image_features) == list(expected["video_keys"]), policy.image_features


root, expected = sys.argv[1], np.load(sys.argv[2])
ds = LeRobotDataset("local/mimicgen_pipe_export", root=root)  # its own video decoder
assert ds.meta.info["codebase_version"] == CODEBASE_VERSION, ds.meta.info["codebase_version"]
assert ds.fps == int(expected["fps"]), ds.fps
assert ds.num_episodes == len(expected["lengths"]), ds.num_episodes
assert len(ds) == len(expected["action"]), len(ds)
lengths = [ds.meta.episodes[i]["length"] for i in range(ds.num_episodes)]
assert lengths == expected["lengths"].tolist(), lengths
assert ds.meta.names["action"] == expected["action_names"].tolist()
assert ds.meta.names["observation.state"] == expected["state_names"].tolist()
assert ds.meta.names["observation.environment_state"] == expected["env_state_names"].tolist()
assert ds.meta.video_keys == expected["video_keys"].tolist(), ds.meta.video_keys
for key in ds.meta.video_keys:
    assert ds.meta.stats[key]["mean"].shape == (3, 1, 1), ds.meta.stats[key]["mean"].shape
    info = ds.meta.features[key]["info"]
    for part in ("intrinsics", "pose"):
        assert np.array_equal(info[f"camera.{part}"], expected[f"calibration/{key}/{part}"]), key
for key, dtype in (("next.reward", "float32"), ("next.done", "bool"), ("next.success", "bool")):
    feature = ds.meta.features[key]
    assert (feature["dtype"], list(feature["shape"])) == (dtype, [1]), (key, feature)
subtasks = expected["subtasks"].tolist()
assert ds.meta.subtasks.index.tolist() == subtasks, ds.meta.subtasks
# what made the data and its conventions (info.json's "mimicgen_pipe"), and the dataset
# card as the Hugging Face Hub reads it
assert ds.meta.info["mimicgen_pipe"] == json.loads(str(expected["provenance"]))
card = DatasetCard.load(Path(root) / "README.md")
assert card.data.task_categories == ["robotics"] and "LeRobot" in card.data.tags, card.data
assert card.data.configs == [{"config_name": "default", "data_files": "data/*/*.parquet"}]
task = str(expected["task"])
assert task in card.text, card.text
starts = np.concatenate([[0], np.cumsum(expected["lengths"])[:-1]])
same: dict[str, list] = {key: [] for key in ds.meta.video_keys}  # error to our frame
shifted: dict[str, list] = {key: [] for key in ds.meta.video_keys}  # to the ones beside it
for i in range(len(ds)):
    item = ds[i]
    assert np.array_equal(item["action"].numpy(), expected["action"][i]), i
    assert np.array_equal(item["observation.state"].numpy(), expected["state"][i]), i
    env_state = item["observation.environment_state"].numpy()
    assert np.array_equal(env_state, expected["env_state"][i]), i
    ep = item["episode_index"].item()
    assert ep == expected["episode_index"][i], i
    assert item["task"] == task, item["task"]
    label = int(expected["subtask_index"][i])
    assert item["subtask_index"].item() == label, (i, item["subtask_index"])
    assert item["subtask"] == subtasks[label], (i, item["subtask"])
    for key in ("next.reward", "next.done", "next.success"):
        assert item[key].item() == expected[key][i], (i, key, item[key])
    t = i - starts[ep]
    for key in ds.meta.video_keys:
        image = item[key].numpy()  # (3, H, W) float32 in [0, 1]
        assert image.dtype == np.float32 and image.shape[0] == 3, (key, image.shape)
        ours = expected[f"images/{key}"][starts[ep] : starts[ep] + lengths[ep]]
        error = np.abs(image.transpose(1, 2, 0) * 255.0 - ours).mean(axis=(1, 2, 3))
        same[key].append(error[t])
        shifted[key] += [error[u] for u in (t - 1, t + 1) if 0 <= u < len(ours)]
for key in ds.meta.video_keys:
    # lossy video: each frame near ours, and the frames in step with ours (nearer to the
    # same step than to the steps beside it, on average: a frame's neighbour may be as near
    # where the scene hardly moves)
    mean, most, beside = np.mean(same[key]), np.max(same[key]), np.mean(shifted[key])
    print(f"{key}: mean absolute error {mean:.2f}, at most {most:.2f} of 255; {beside:.2f} beside")
    assert np.max(same[key]) < MAX_IMAGE_ERROR, key
    assert np.mean(same[key]) < np.mean(shifted[key]), key
if "--policies" in sys.argv[3:]:
    check_policy_features(ds)
print("ok")
