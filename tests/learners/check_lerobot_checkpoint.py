"""Run in the learners' check venv: load a policy directory that lerobot-train wrote
(checkpoints/<step>/pretrained_model) with lerobot's own classes, offline, and print one JSON
line: the policy type, its input and output features (name -> shape) and how many of the
weights in model.safetensors the loaded policy holds.

usage: check_lerobot_checkpoint.py POLICY_DIR
"""

import json
import os
import sys

os.environ.setdefault("HF_HUB_OFFLINE", "1")  # a missing file fails at once, never downloads

from lerobot.configs.policies import PreTrainedConfig  # noqa: E402
from lerobot.policies.factory import get_policy_class  # noqa: E402
from safetensors import safe_open  # noqa: E402

directory = sys.argv[1]
config = PreTrainedConfig.from_pretrained(directory)
policy = get_policy_class(config.type).from_pretrained(directory, config=config)
state = policy.state_dict()
with safe_open(os.path.join(directory, "model.safetensors"), "pt") as f:
    stored = list(f.keys())
    same = sum(k in state and f.get_tensor(k).equal(state[k]) for k in stored)
report = {
    "type": config.type,
    "input_features": {k: list(v.shape) for k, v in config.input_features.items()},
    "output_features": {k: list(v.shape) for k, v in config.output_features.items()},
    "stored_tensors": len(stored),
    "loaded_equal": same,
}
print(json.dumps(report))
