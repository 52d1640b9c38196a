"""Run in the learners' check venv: what robomimic 0.3.0's training feeds its network with
observation normalisation on, once train_robomimic's trainer has patched it. Windows of 10
steps from robomimic's own SequenceDataset (hdf5_normalize_obs) go through its own
postprocess_batch_for_training, as run_epoch sends them; the same windows from a dataset
without normalisation are the raw observations. Prints one JSON line: error, the largest
|fed - (raw - mean) / std| over keys, steps and windows (0 when each step is normalised once,
as robomimic's RolloutPolicy normalises a rollout step), and moved, the largest |fed - raw|.

usage: check_robomimic_normalization.py TRAINER.py DATASET.hdf5
"""

import importlib.util
import json
import sys

import numpy as np
import robomimic.utils.obs_utils as obs_utils
import torch
from robomimic.algo.algo import Algo
from robomimic.utils.dataset import SequenceDataset

trainer_path, dataset = sys.argv[1:]
spec = importlib.util.spec_from_file_location("robomimic_trainer", trainer_path)
trainer = importlib.util.module_from_spec(spec)
spec.loader.exec_module(trainer)
trainer.normalize_once()

keys = ["robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos", "object"]
obs_utils.initialize_obs_modality_mapping_from_dict({"low_dim": keys})


def windows(normalize: bool) -> SequenceDataset:
    return SequenceDataset(
        hdf5_path=dataset, obs_keys=keys, dataset_keys=("actions",), seq_length=10,
        pad_seq_length=True, pad_frame_stack=True, hdf5_cache_mode="all",
        hdf5_normalize_obs=normalize, filter_by_attribute="train",
    )  # fmt: skip


normalized, raw = windows(True), windows(False)
stats = normalized.get_obs_normalization_stats()
picked = [0, len(raw) // 2, len(raw) - 1]
batch = torch.utils.data.default_collate([normalized[i] for i in picked])
fed = Algo.postprocess_batch_for_training(None, {"obs": batch["obs"]}, stats)["obs"]
error = moved = 0.0
for k in keys:
    x = np.stack([raw[i]["obs"][k] for i in picked]).astype(np.float64)
    once = (x - stats[k]["mean"][0]) / stats[k]["std"][0]
    got = np.asarray(fed[k], dtype=np.float64)
    error, moved = max(error, np.abs(got - once).max()), max(moved, np.abs(got - x).max())
print(json.dumps({"error": float(error), "moved": float(moved)}))
