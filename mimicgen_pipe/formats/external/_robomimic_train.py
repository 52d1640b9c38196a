"""robomimic's own training (``robomimic.scripts.train.train``) of one config file, run by
path under the learners' Python, where mimicgen_pipe is not installed::

    <python> mimicgen_pipe/formats/external/_robomimic_train.py --config run.json [--dataset
    demos.hdf5]

It takes robomimic 0.3.0's ``scripts/train.py``'s ``--config`` and ``--dataset``, and differs
from it in these ways only:

- A failed run exits with status 1 (``train.py`` prints the error and exits 0); so does a run
  that saved no checkpoint with saving on. A dataset that is not a file is refused in one
  line, with status 2, before robomimic makes its run folder.
- ``--num_epochs`` and ``--epoch_every_n_steps`` shorten a run (``train.num_epochs``,
  ``experiment.epoch_every_n_steps``); a checkpoint is saved after the last epoch of such a
  run too (``experiment.save.epochs``).
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
import os
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


def parse_args() -> argparse.Namespace:
    """robomimic's ``--config`` and ``--dataset``, and the two run-length flags."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", required=True, help="a robomimic config JSON (algo_name: bc)")
    p.add_argument("--dataset", help="the robomimic HDF5 to train on (default: train.data)")
    p.add_argument("--num_epochs", type=int, help="train.num_epochs, the last one saved")
    p.add_argument("--epoch_every_n_steps", type=int, help="experiment.epoch_every_n_steps")
    return p.parse_args()


def with_arguments(external: dict, args: argparse.Namespace) -> dict:
    """The config file's values with the command line's put in."""
    train = external.setdefault("train", {})
    experiment = external.setdefault("experiment", {})
    if args.dataset is not None:
        train["data"] = args.dataset
    if args.num_epochs is not None:
        train["num_epochs"] = args.num_epochs
        # a short run's epochs may miss save.every_n_epochs: its last one is saved too
        save = experiment.setdefault("save", {})
        save["epochs"] = [*save.get("epochs", []), args.num_epochs]
    if args.epoch_every_n_steps is not None:
        experiment["epoch_every_n_steps"] = args.epoch_every_n_steps
    return external


def record_checkpoint_folder() -> list[str]:
    """A list that gets the checkpoint folder robomimic's ``train`` makes for its run."""
    import robomimic.utils.train_utils as train_utils

    folders: list[str] = []
    get_exp_dir = train_utils.get_exp_dir

    def recorded(*args: object, **kwargs: object) -> tuple:
        dirs = get_exp_dir(*args, **kwargs)
        folders.append(dirs[1])  # (log_dir, output_dir, video_dir): the models folder
        return dirs

    train_utils.get_exp_dir = recorded
    return folders


def main() -> int:
    args = parse_args()
    with open(args.config) as f:
        external = with_arguments(json.load(f), args)
    dataset = external["train"].get("data")
    if not (dataset and os.path.isfile(os.path.expanduser(dataset))):
        where = "--dataset" if args.dataset is not None else f"{args.config}: train.data"
        print(f"{where} {dataset}: no such file (expected a robomimic HDF5, an export's "
              "demos.hdf5)", file=sys.stderr)  # fmt: skip
        return 2

    import robomimic.utils.torch_utils as torch_utils
    from robomimic.config import config_factory
    from robomimic.scripts.train import train

    config = config_factory(external["algo_name"])
    with config.values_unlocked():
        config.update(external)
    config.lock()
    if config.train.hdf5_normalize_obs:
        normalize_once()
    folders = record_checkpoint_folder()
    train(config, device=torch_utils.get_torch_device(try_to_use_cuda=config.train.cuda))
    if config.experiment.save.enabled and not [p for f in folders for p in Path(f).glob("*.pth")]:
        save = config.experiment.save
        print(f"robomimic saved no checkpoint in {folders[0]}: experiment.save.every_n_epochs "
              f"{save.every_n_epochs} and .epochs {list(save.epochs)} name no epoch of "
              f"train.num_epochs {config.train.num_epochs}", file=sys.stderr)  # fmt: skip
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
