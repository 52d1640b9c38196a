"""robomimic's own training (``robomimic.scripts.train.train``) of one config file, run by
path under the learners' Python, where mimicgen_pipe is not installed::

    <python> mimicgen_pipe/external/_robomimic_train.py --config run.json

It differs from robomimic 0.3.0's ``scripts/train.py`` in two ways only:

- A failed run exits with status 1 (``train.py`` prints the error and exits 0).
- With ``train.hdf5_normalize_obs``, robomimic 0.3.0 normalises each training sample twice:
  ``SequenceDataset.get_item`` normalises the window, and ``postprocess_batch_for_training``
  normalises the batch again, while its ``RolloutPolicy`` normalises a rollout step once
  (robomimic fixed this after 0.3.0, in its pull request 81). Its ``normalize_obs`` also
  refuses a window or a batch of windows: it compares the (1, D) mean with (seq_length, D)
  ("shape mismatch in @normalize obs"). Here the dataset leaves its windows raw and
  ``normalize_obs`` broadcasts the statistics over the leading dimensions, so each training
  step is normalised once, (x - mean) / std, with the statistics robomimic computed over the
  training demos, as a rollout step is. robomimic saves those statistics in every
  checkpoint, and its ``RolloutPolicy`` applies them, unpatched: a checkpoint trained here
  rolls out as any robomimic checkpoint does.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

# Run by path, Python puts this folder first on sys.path, where robomimic.py would hide the
# framework of the same name.
HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != HERE]


def normalize_obs(obs_dict: dict, obs_normalization_stats: dict) -> dict:
    """robomimic's ``normalize_obs``, in place, with the (1, D) statistics broadcast over
    any leading dimensions of each observation (a window's steps)."""
    for key in obs_dict:
        stats = obs_normalization_stats[key]
        mean, std = stats["mean"][0], stats["std"][0]
        if obs_dict[key].shape[-mean.ndim :] != mean.shape:
            raise ValueError(
                f"observation {key!r}: shape {obs_dict[key].shape}, statistics {mean.shape}"
            )
        obs_dict[key] = (obs_dict[key] - mean) / std
    return obs_dict


def normalize_once() -> None:
    """Patch robomimic 0.3.0 so that training normalises each observation once: in
    ``postprocess_batch_for_training`` (by :func:`normalize_obs`), not also in
    ``SequenceDataset.get_item``, which still computes the statistics."""
    import robomimic.utils.obs_utils as obs_utils
    from robomimic.utils.dataset import SequenceDataset

    get_item = SequenceDataset.get_item

    def get_item_raw(self: SequenceDataset, index: int) -> dict:
        normalize, self.hdf5_normalize_obs = self.hdf5_normalize_obs, False
        try:
            return get_item(self, index)
        finally:
            self.hdf5_normalize_obs = normalize

    SequenceDataset.get_item = get_item_raw
    obs_utils.normalize_obs = normalize_obs


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", required=True, help="a robomimic config JSON (algo_name: bc)")
    args = p.parse_args()

    import robomimic.utils.torch_utils as torch_utils
    from robomimic.config import config_factory
    from robomimic.scripts.train import train

    with open(args.config) as f:
        external = json.load(f)
    config = config_factory(external["algo_name"])
    with config.values_unlocked():
        config.update(external)
    config.lock()
    if config.train.hdf5_normalize_obs:
        normalize_once()
    train(config, device=torch_utils.get_torch_device(try_to_use_cuda=config.train.cuda))
    return 0


if __name__ == "__main__":
    sys.exit(main())
