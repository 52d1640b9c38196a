"""train: BC-RNN policies on the source demos or on a generated dataset, one run per
training seed of the active profile (params train.profile)."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

import envs
from mimicgen_pipe import layout
from mimicgen_pipe.errors import InputError
from mimicgen_pipe.interrupts import Interrupted
from mimicgen_pipe.metrics import write_metrics
from mimicgen_pipe.outputs import claim, output_set
from mimicgen_pipe.params import as_dict
from mimicgen_pipe.policy import PolicyConfig
from mimicgen_pipe.store import read_store
from mimicgen_pipe.training import (
    TrainConfig,
    dataset_from_store,
    default_device,
    save_checkpoint,
    split_episodes,
    subset,
    train_policy,
)
from stages import add_selection_arguments, stage_params

SPLIT_SEED = 0  # the train/validation split is the same for every training seed


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument(
        "--data",
        required=True,
        help='training data: "source" (the source demos) or a reset variant such as D1 '
        "(that variant's generated store)",
    )
    p.add_argument("--store", help="store to train on (default: from --data, see layout)")
    p.add_argument("--out", help="checkpoint directory (default: data/policies/<task>_<data>)")
    p.add_argument("--metrics", help="metrics JSON (default: metrics/train_<task>_<data>.json)")
    p.add_argument("--plot", help="training curve CSV (default: plots/train_<task>_<data>.csv)")


def write_curve(path: Path, rows: list[dict]) -> None:
    """The training curve, one row per (training seed, epoch)."""
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, ["seed", "epoch", "step", "loss", "val_loss", "seconds"])
        writer.writeheader()
        writer.writerows(rows)


def run(args: argparse.Namespace) -> None:
    params = stage_params(args)
    t, prof = params.train, params.train.active
    spec = envs.task_spec(params.backend, params.task)
    if args.data != "source":
        envs.check_variant(spec, args.data)
    if not prof.seeds:
        raise InputError(f"{args.params}: train.{t.profile}.seeds: expected at least one seed")
    store_path = Path(args.store or layout.training_store(params.task, args.data))
    out = Path(args.out or layout.policy_dir(params.task, args.data))
    metrics_path = Path(args.metrics or layout.metrics_file("train", params.task, args.data))
    plot_path = Path(args.plot or layout.plot_file("train", params.task, args.data))
    claim(out, metrics_path, plot_path)  # fails at once if another run writes them

    store = read_store(
        store_path,
        required=["actions"],
        task=params.task,
        kind="source" if args.data == "source" else "generated",
    )
    data, dims = dataset_from_store(
        store, t.obs_keys, None if args.data == "source" else t.num_demos
    )
    train_eps, val_eps = split_episodes(
        data.n_episodes, t.val_fraction, np.random.default_rng(SPLIT_SEED)
    )
    train_data, val_data = subset(data, train_eps), subset(data, val_eps)
    policy = PolicyConfig(
        tuple(t.obs_keys),
        dims,
        int(data.actions.shape[1]),
        hidden=prof.hidden,
        layers=prof.layers,
        seq_len=prof.seq_len,
    )
    config = TrainConfig(
        prof.hidden,
        prof.layers,
        prof.seq_len,
        prof.batch_size,
        prof.lr,
        prof.epochs,
        prof.steps_per_epoch,
        prof.checkpoint_every,
        t.val_fraction,
        device=prof.device if prof.device != "auto" else default_device(),
        lr_schedule=prof.lr_schedule,
    )
    meta = {
        "task": params.task,
        "backend": params.backend,
        "robot": store.attrs.get("robot"),
        "data": args.data,
        "store": str(store_path),
        # the generate run whose data this is (none for source demos): the report checks it
        "data_run_id": store.attrs.get("run_id"),
        "control_mode": store.attrs.get("control_mode"),
        "train_episodes": int(train_data.n_episodes),
        "val_episodes": int(val_data.n_episodes),
        "train_params": as_dict(t),
    }
    if prof.threads:
        torch.set_num_threads(prof.threads)
    rows: list[dict] = []
    at = {"seed": prof.seeds[0], "epoch": 0}  # how far training got, for an interrupt
    # checkpoints, curve and metrics are written aside and renamed together, checkpoints last
    with output_set(plot_path, metrics_path, out) as (tmp_plot, tmp_metrics, tmp):
        tmp.mkdir()
        for seed in prof.seeds:
            bar = tqdm(total=prof.epochs, desc=f"train {args.data} seed {seed}", unit="epoch")
            at.update(seed=seed, epoch=0)

            def checkpoint(epoch: int, model, seed: int = seed) -> None:
                path = tmp / f"seed{seed}" / f"epoch{epoch:05d}.pt"
                step = epoch * prof.steps_per_epoch
                save_checkpoint(path, model, {**meta, "seed": seed, "epoch": epoch, "step": step})

            def progress(epoch: int, row: dict, bar=bar) -> None:
                at["epoch"] = epoch
                bar.update(1)
                bar.set_postfix(loss=f"{row['loss']:.2f}", val=f"{row['val_loss']:.2f}")

            try:
                history = train_policy(
                    train_data, val_data, policy, config, seed, checkpoint, progress
                )
            except Interrupted as exc:
                exc.detail = f"in training seed {at['seed']} at epoch {at['epoch']}/{prof.epochs}"
                raise
            finally:
                bar.close()
            rows += [{"seed": seed, **r} for r in history]
        write_curve(tmp_plot, rows)
        last = [r for r in rows if r["epoch"] == prof.epochs]
        seconds = sum(r["seconds"] for r in last)
        steps = prof.epochs * prof.steps_per_epoch * len(prof.seeds)
        write_metrics(
            tmp_metrics,
            {
                "profile": t.profile,
                "seeds": len(prof.seeds),
                "data_run_id": meta["data_run_id"],
                "train_episodes": int(train_data.n_episodes),
                "val_episodes": int(val_data.n_episodes),
                "gradient_steps": steps,
                "final_loss": float(np.mean([r["loss"] for r in last])),
                "final_val_loss": float(np.mean([r["val_loss"] for r in last])),
                "wall_seconds": seconds,
                "seconds_per_1000_steps": 1000 * seconds / steps,
                "torch_threads": torch.get_num_threads(),
            },
        )
    print(
        f"train: {len(prof.seeds)} run(s) on {data.n_episodes} episodes of {store_path}, "
        f"{1000 * seconds / steps:.1f} s per 1000 steps -> {out}"
    )
