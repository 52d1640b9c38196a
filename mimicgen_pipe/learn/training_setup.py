"""What the two BC-RNN training loops share: mimicgen_pipe.learn.training.train_policy (one policy)
and mimicgen_pipe.learn.stacked_training.train_stacked (several as one network). The training data
(SequenceData) and its episode-aware windows, how one policy trains (TrainConfig) and one
training run (TrainingRun), the policy before training (its seeded initial weights and
normalisation), and the learning-rate schedule."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from mimicgen_pipe.learn.policy import BCRNN, PolicyConfig


class MappedImages:
    """(N, cameras, H, W, 3) uint8 images in a ``.npy`` file, mapped read-only: indexed as
    the array (an index gives an in-memory copy), pickled as the file's path, so that
    trainings side by side in other processes share one copy of the images (the page
    cache's) instead of each receiving its own."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self._array = np.load(self.path, mmap_mode="r")

    @classmethod
    def write(cls, path: str | os.PathLike, images: np.ndarray) -> MappedImages:
        np.save(path, images)
        return cls(path)

    def __reduce__(self) -> tuple[type[MappedImages], tuple[Path]]:
        return (MappedImages, (self.path,))

    def __getitem__(self, index: Any) -> np.ndarray:
        return np.array(self._array[index])

    @property
    def shape(self) -> tuple[int, ...]:
        return self._array.shape


@dataclass(frozen=True)
class SequenceData:
    """Episodes concatenated: obs (N, D) float32, actions (N, A) float32, episode_ends (E,)
    cumulative exclusive ends; for an image policy, images (N, cameras, H, W, 3) uint8 RGB
    (cameras in PolicyConfig.image_keys order), in memory or mapped from a file."""

    obs: np.ndarray
    actions: np.ndarray
    episode_ends: np.ndarray
    images: np.ndarray | MappedImages | None = None

    @property
    def episode_starts(self) -> np.ndarray:
        return np.concatenate([[0], self.episode_ends[:-1]]).astype(np.int64)

    @property
    def n_episodes(self) -> int:
        return len(self.episode_ends)


@dataclass(frozen=True)
class TrainConfig:
    """How one policy trains: ``policy``, the network (its architecture and observation
    layout, as its checkpoints store it), and the schedule: Adam at ``lr``, constant or (with
    ``lr_schedule`` "cosine") annealed to lr / 100 over the run; epochs x steps_per_epoch
    gradient steps on batches of batch_size windows of policy.seq_len steps; a checkpoint
    every checkpoint_every epochs (and at the last); on torch device ``device``."""

    policy: PolicyConfig
    batch_size: int
    lr: float
    epochs: int
    steps_per_epoch: int
    checkpoint_every: int
    lr_schedule: Literal["constant", "cosine"] = "constant"
    device: str = "cpu"
    shift: tuple[int, int] = (0, 0)


@dataclass(frozen=True)
class TrainingRun:
    """One training: ``seed`` on ``train_data``, validated on ``val_data``. ``label`` names it
    on its progress bar, drawn on terminal line ``position`` (runs side by side each have
    their own line)."""

    train_data: SequenceData
    val_data: SequenceData
    config: TrainConfig
    seed: int
    label: str = "train"
    position: int = 0


def window_index(data: SequenceData, starts: np.ndarray, seq_len: int) -> np.ndarray:
    """(B, seq_len) step indices of windows beginning at ``starts``; a window running past
    its episode's end repeats the last step (robomimic's sequence padding)."""
    ep = np.searchsorted(data.episode_ends, starts, side="right")
    last = data.episode_ends[ep] - 1
    return np.minimum(starts[:, None] + np.arange(seq_len), last[:, None])


def validation_windows(data: SequenceData, seq_len: int, limit: int = 2000) -> np.ndarray:
    """Fixed validation windows: every seq_len-th step of every episode (at most ``limit``)."""
    starts = np.concatenate(
        [
            np.arange(s, e, seq_len)
            for s, e in zip(data.episode_starts, data.episode_ends, strict=False)
        ]
    )
    starts = starts[np.linspace(0, len(starts) - 1, min(limit, len(starts))).astype(int)]
    return window_index(data, starts, seq_len)


def shift_images(
    images: torch.Tensor, shift: tuple[int, int], generator: torch.Generator
) -> torch.Tensor:
    """Random shifts of (N, H, W, C) images, each its own: down by dy and right by dx pixels,
    drawn uniformly from [-shift[0], shift[0]] and [-shift[1], shift[1]], the border pixels
    repeated into the uncovered strip (the paper's pixel-shift augmentation, as pad-and-crop
    with edge padding)."""
    if shift == (0, 0):
        return images
    n, h, w = images.shape[:3]
    dy = torch.randint(-shift[0], shift[0] + 1, (n, 1), generator=generator)
    dx = torch.randint(-shift[1], shift[1] + 1, (n, 1), generator=generator)
    # the batch edge-padded once, then each image a window of it: a third of the time of
    # one fancy index over (image, row, column) on 2 cores, the same pixels
    sy, sx = shift
    padded = np.pad(images.numpy(), ((0, 0), (sy, sy), (sx, sx), (0, 0)), mode="edge")
    out = np.empty(images.shape, padded.dtype)
    for i, (y, x) in enumerate(
        zip((sy - dy[:, 0]).tolist(), (sx - dx[:, 0]).tolist(), strict=True)
    ):
        out[i] = padded[i, y : y + h, x : x + w]
    return torch.from_numpy(out)


def initial_policy(policy: PolicyConfig, train_data: SequenceData, seed: int) -> BCRNN:
    """The network ``policy`` before training: built right after torch is seeded with
    ``seed`` (which fixes its initial weights), observations normalised by the training
    data's per-column mean and standard deviation."""
    torch.manual_seed(seed)
    model = BCRNN(policy)
    model.set_normalisation(train_data.obs.mean(0), train_data.obs.std(0))
    return model


def lr_scheduler(
    opt: torch.optim.Optimizer, config: TrainConfig
) -> torch.optim.lr_scheduler.CosineAnnealingLR | None:
    """torch's schedule of ``config``'s learning rate for ``opt``, stepped after every gradient
    step: annealed to lr / 100 over epochs x steps_per_epoch steps ("cosine"), or None for a
    constant rate."""
    if config.lr_schedule != "cosine":
        return None
    total_steps = config.epochs * config.steps_per_epoch
    return torch.optim.lr_scheduler.CosineAnnealingLR(opt, total_steps, eta_min=config.lr / 100)


def annealed_lr(config: TrainConfig, done: int) -> float:
    """The learning rate after ``done`` gradient steps of a "cosine" schedule, in closed form
    (lr_scheduler's torch steps it one step at a time): from lr down to lr / 100."""
    total_steps = config.epochs * config.steps_per_epoch
    low = config.lr / 100
    return low + (config.lr - low) * (1 + math.cos(math.pi * done / total_steps)) / 2
