"""Seconds per gradient step of the image BC-RNN (mimicgen_pipe.learn.policy, two 84x84 cameras,
the robot's 9 low-dim values, seq_len 10) for a few encoder widths, LSTM sizes and batch
sizes, on random images and actions: forward, backward and Adam, the pixel shift included.
Prints one line per size; the median of steps 3-8.

    .venv/bin/python lab/scripts/image_encoder_cost.py --threads 2
    .venv/bin/python lab/scripts/image_encoder_cost.py --threads 1 --channels 16 \
        --image-sizes 84 64 48
"""

from __future__ import annotations

if __name__ == "__main__":  # mimicgen-pipe's code paths, pinned before numpy or torch loads,
    from mimicgen_pipe.run import arithmetic  # so that a run here has the stages' last bits

    arithmetic.pin()

import argparse
import time

import numpy as np
import torch

from mimicgen_pipe.learn.policy import BCRNN, PolicyConfig, nll_loss
from mimicgen_pipe.learn.training_setup import shift_images

SIZES = [  # (channels, LSTM hidden, batch)
    (32, 400, 16),
    (32, 100, 16),
    (16, 400, 16),
    (16, 100, 16),
    (32, 400, 32),
    (32, 100, 8),
]


def seconds_per_step(
    channels: int, hidden: int, batch: int, size: int = 84, steps: int = 8
) -> float:
    config = PolicyConfig(
        ("eef_pos", "eef_quat", "gripper_qpos"), (3, 4, 2), 7, hidden=hidden,
        image_keys=("agentview_image", "eye_in_hand_image"), channels=channels,
        image_size=(size, size),
    )  # fmt: skip
    torch.manual_seed(0)
    model = BCRNN(config)
    opt = torch.optim.Adam(model.parameters(), 1e-3)
    gen = torch.Generator().manual_seed(0)
    images = torch.randint(0, 256, (batch, 10, 2, size, size, 3), dtype=torch.uint8)
    obs, actions = torch.randn(batch, 10, 9), torch.rand(batch, 10, 7) * 2 - 1
    times = []
    for _ in range(steps):
        t0 = time.perf_counter()
        pad = round(0.1 * size)
        frames = shift_images(images.view(-1, size, size, 3), (pad, pad), gen).view(images.shape)
        loss = nll_loss(model, obs, actions, frames)
        opt.zero_grad()
        loss.backward()
        opt.step()
        times.append(time.perf_counter() - t0)
    return float(np.median(times[2:]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--threads", type=int, default=2, help="torch threads")
    ap.add_argument("--image-sizes", type=int, nargs="+", default=[84], help="square images [px]")
    ap.add_argument("--channels", type=int, help="only this encoder width, LSTM 400, batch 16")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    sizes = [(a.channels, 400, 16)] if a.channels else SIZES
    for size in a.image_sizes:
        for channels, hidden, batch in sizes:
            s = seconds_per_step(channels, hidden, batch, size)
            print(f"threads {a.threads} size {size} channels {channels} hidden {hidden} "
                  f"batch {batch}: {s:.3f} s/step")  # fmt: skip


if __name__ == "__main__":
    main()
