"""Run in the learners' check venv: rebuild the policy of a checkpoint that robomimic's
train.py wrote, with robomimic's own loader, and run it on the first step of the dataset's
first demo. The checkpoint is read with torch.load(weights_only=True) (a pickle that needs
more is an error) and handed to robomimic as a dict. Prints one JSON line: algo_name,
obs_keys, model_keys, the action's shape and whether it is finite, and stock_low_dim: the
low-dim observation keys of robomimic's own default BC config (config_factory("bc")).

usage: check_robomimic_checkpoint.py CHECKPOINT.pth DATASET.hdf5
"""

import json
import sys

import h5py
import numpy as np
import robomimic.utils.file_utils as file_utils
import robomimic.utils.obs_utils as obs_utils
import torch
from robomimic.config import config_factory

checkpoint, dataset = sys.argv[1:]
ckpt_dict = torch.load(checkpoint, map_location="cpu", weights_only=True)
policy, ckpt = file_utils.policy_from_checkpoint(ckpt_dict=ckpt_dict, device=torch.device("cpu"))
keys = ckpt["shape_metadata"]["all_obs_keys"]
with h5py.File(dataset, "r") as f:
    obs = {k: f[f"data/demo_0/obs/{k}"][0] for k in keys}
policy.start_episode()
action = policy(ob=obs_utils.process_obs_dict(obs))
report = {
    "algo_name": ckpt["algo_name"],
    "obs_keys": keys,
    "model_keys": sorted(ckpt["model"]),
    "action_shape": list(np.shape(action)),
    "action_finite": bool(np.isfinite(action).all()),
    "stock_low_dim": list(config_factory("bc").observation.modalities.obs.low_dim),
}
print(json.dumps(report))
