"""Where one gradient step of the image BC-RNN goes on a real observed store: drawing the
windows, gathering their images and shifting them, the forward pass, the backward pass and
Adam (ms each, mean of steps 6-25), and one validation pass, with the train stage's code
and a params file's image profile (train.cpu_image, its image size the store's).

    .venv/bin/python lab/scripts/image_step_cost.py --params params.yaml \\
        --store data/observed/stack_cube_D0.zarr --demos 20 --threads 1
"""

from __future__ import annotations

if __name__ == "__main__":  # mimicgen-pipe's code paths, pinned before numpy or torch loads,
    from mimicgen_pipe.run import arithmetic  # so that a run here has the stages' last bits

    arithmetic.pin()

import argparse
import dataclasses
import time

import numpy as np
import torch

from mimicgen_pipe.data.params import load_params
from mimicgen_pipe.learn.policy import nll_loss
from mimicgen_pipe.learn.training import (
    _frames,
    _validation_loss,
    load_training_data,
    train_config,
)
from mimicgen_pipe.learn.training_setup import initial_policy, validation_windows, window_index

OBS_KEYS = ["eef_pos", "eef_quat", "gripper_qpos"]  # an image policy's low-dim keys


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--store", required=True, help="an observed store (the observe stage's)")
    ap.add_argument("--demos", type=int, default=100, help="its first N demos")
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    params = load_params(a.params)
    prof = params.train.cpu_image
    t0 = time.perf_counter()
    data = load_training_data(a.store, OBS_KEYS, a.demos, 0.1, 0, cameras=prof.cameras,
                              image_size=tuple(prof.image_size))  # fmt: skip
    print(f"read {a.demos} demos: {time.perf_counter() - t0:.1f} s")
    train = dataclasses.replace(params.train, profile="cpu_image", obs_keys=OBS_KEYS)
    config = train_config(train, data)
    model = initial_policy(config.policy, data.train, 0)
    opt = torch.optim.Adam(model.parameters(), lr=config.lr)
    rng, shifts = np.random.default_rng(0), torch.Generator().manual_seed(0)
    obs, actions = torch.from_numpy(data.train.obs), torch.from_numpy(data.train.actions)
    parts = dict.fromkeys(("windows", "images", "forward", "backward", "adam"), 0.0)
    for step in range(25):
        t = [time.perf_counter()]
        starts = rng.integers(0, len(data.train.obs), config.batch_size)
        windows = window_index(data.train, starts, config.policy.seq_len)
        t.append(time.perf_counter())
        frames = _frames(data.train.images, windows, config.shift, shifts)
        t.append(time.perf_counter())
        idx = torch.from_numpy(windows)
        loss = nll_loss(model, obs[idx], actions[idx], frames)
        t.append(time.perf_counter())
        opt.zero_grad()
        loss.backward()
        t.append(time.perf_counter())
        opt.step()
        t.append(time.perf_counter())
        if step >= 5:
            for key, a0, a1 in zip(parts, t, t[1:], strict=False):
                parts[key] += (a1 - a0) / 20
    print("ms per step:", {k: round(v * 1000, 1) for k, v in parts.items()})
    val = validation_windows(data.val, config.policy.seq_len, 200)
    t0 = time.perf_counter()
    model.eval()
    with torch.no_grad():
        _validation_loss(model, data.val, val, torch.device("cpu"))
    print(f"one validation pass: {time.perf_counter() - t0:.2f} s")


if __name__ == "__main__":
    main()
