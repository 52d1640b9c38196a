"""Run in the LeRobot check venv: load an exported dataset with lerobot's LeRobotDataset
(offline) and compare every frame with the arrays in EXPECTED.npz. Prints "ok" when all match.

usage: check_dataset.py DATASET_DIR EXPECTED.npz
"""

import os
import sys

os.environ.setdefault("HF_HUB_OFFLINE", "1")  # a missing file fails at once, never downloads

import numpy as np  # noqa: E402
from lerobot.datasets.lerobot_dataset import CODEBASE_VERSION, LeRobotDataset  # noqa: E402

root, expected = sys.argv[1], np.load(sys.argv[2])
ds = LeRobotDataset("local/mimicgen_pipe_export", root=root)
assert ds.meta.info["codebase_version"] == CODEBASE_VERSION, ds.meta.info["codebase_version"]
assert ds.fps == int(expected["fps"]), ds.fps
assert ds.num_episodes == len(expected["lengths"]), ds.num_episodes
assert len(ds) == len(expected["action"]), len(ds)
lengths = [ds.meta.episodes[i]["length"] for i in range(ds.num_episodes)]
assert lengths == expected["lengths"].tolist(), lengths
assert ds.meta.names["action"] == expected["action_names"].tolist()
assert ds.meta.names["observation.state"] == expected["state_names"].tolist()
task = str(expected["task"])
for i in range(len(ds)):
    item = ds[i]
    assert np.array_equal(item["action"].numpy(), expected["action"][i]), i
    assert np.array_equal(item["observation.state"].numpy(), expected["state"][i]), i
    assert item["episode_index"].item() == expected["episode_index"][i], i
    assert item["task"] == task, item["task"]
print("ok")
