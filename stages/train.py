"""train: BC-RNN policies on the source demos or on generated datasets, one run per
training seed of the active profile (params train.profile). Given several datasets
(``--data source D0 D1``) it trains them side by side, ``train.workers`` processes at a time:
DVC runs one stage at a time, and one training keeps one core busy."""

from __future__ import annotations

import argparse
import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

import envs
from mimicgen_pipe import layout
from mimicgen_pipe.errors import InputError
from mimicgen_pipe.interrupts import Interrupted
from mimicgen_pipe.metrics import write_metrics
from mimicgen_pipe.outputs import claim, directory_kind, output_set
from mimicgen_pipe.params import Params, training_params
from mimicgen_pipe.policy import PolicyConfig
from mimicgen_pipe.training import (
    TrainConfig,
    TrainingRun,
    default_device,
    load_training_data,
    run_trainings,
    save_checkpoint,
)
from stages import add_selection_arguments, stage_params

SPLIT_SEED = 0  # the train/validation split is the same for every training seed


# a policy directory: the checkpoints of every training seed
POLICY_DIR = directory_kind("policy directory", r"seed\d+/epoch\d+\.pt")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument(
        "--data",
        required=True,
        nargs="+",
        help='training data, one policy each: "source" (the source demos) or a reset variant '
        "such as D1 (that variant's generated store)",
    )
    p.add_argument(
        "--store",
        nargs="+",
        help="store to train on, one per --data (default: from --data, see layout)",
    )
    p.add_argument(
        "--out", help="checkpoint directory, one --data only (default: data/policies/<task>_<data>)"
    )
    p.add_argument(
        "--metrics",
        help="metrics JSON, one --data only (default: metrics/train_<task>_<data>.json)",
    )
    p.add_argument(
        "--plot",
        help="training curve CSV, one --data only (default: plots/train_<task>_<data>.csv)",
    )


def write_curve(path: Path, rows: list[dict]) -> None:
    """The training curve, one row per (training seed, epoch)."""
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, ["seed", "epoch", "step", "loss", "val_loss", "seconds"])
        writer.writeheader()
        writer.writerows(rows)


@dataclass(frozen=True)
class Policy:
    """One policy this stage trains: on ``data`` read from ``store``, written to ``out``
    (checkpoints), ``metrics`` and ``plot`` (training curve)."""

    data: str
    store: Path
    out: Path
    metrics: Path
    plot: Path


def policies(args: argparse.Namespace, params: Params) -> list[Policy]:
    """The policies the command line asks for, checked before any work."""
    data: list[str] = args.data
    if len(set(data)) != len(data):
        raise InputError(f"--data {' '.join(data)}: each dataset at most once")
    if args.store is not None and len(args.store) != len(data):
        raise InputError(
            f"--store: expected one store per --data ({len(data)}), got {len(args.store)}"
        )
    named = [f"--{k}" for k in ("out", "metrics", "plot") if getattr(args, k) is not None]
    if named and len(data) > 1:
        raise InputError(f"{', '.join(named)}: name one training's outputs, give one --data")
    spec = envs.task_spec(params.backend, params.task)
    for d in data:
        if d != "source":
            envs.check_variant(spec, d)
    stores = args.store or [layout.training_store(params.task, d) for d in data]
    return [
        Policy(
            d,
            Path(store),
            Path(args.out or layout.policy_dir(params.task, d)),
            Path(args.metrics or layout.metrics_file("train", params.task, d)),
            Path(args.plot or layout.plot_file("train", params.task, d)),
        )
        for d, store in zip(data, stores, strict=True)
    ]


def run(args: argparse.Namespace) -> None:
    params = stage_params(args)
    t, prof = params.train, params.train.active
    if not prof.seeds:
        raise InputError(f"{args.params}: train.{t.profile}.seeds: expected at least one seed")
    todo = policies(args, params)
    # fails at once if another run writes them, or if they would replace anything else
    claim(
        *(o for p in todo for o in ((p.out, POLICY_DIR), p.metrics, p.plot)),
        inputs=[p.store for p in todo],
    )
    # only the arrays and episodes the trainings use are read, each store checked first
    datasets = [
        load_training_data(
            p.store,
            t.obs_keys,
            None if p.data == "source" else t.num_demos,
            t.val_fraction,
            SPLIT_SEED,
            task=params.task,
            kind="source" if p.data == "source" else "generated",
        )
        for p in todo
    ]
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
    runs: list[TrainingRun] = []
    owners: list[int] = []  # the policy each run trains
    metas: list[dict] = []
    for k, (p, data) in enumerate(zip(todo, datasets, strict=True)):
        train_data, val_data = data.train, data.val
        policy = PolicyConfig(
            tuple(t.obs_keys),
            data.obs_dims,
            data.action_dim,
            hidden=prof.hidden,
            layers=prof.layers,
            seq_len=prof.seq_len,
        )
        for seed in prof.seeds:
            label = f"train {p.data} seed {seed}"
            runs.append(TrainingRun(train_data, val_data, policy, config, seed, label, len(runs)))
            owners.append(k)
        metas.append(
            {
                "task": params.task,
                "backend": params.backend,
                "robot": data.attrs.get("robot"),
                "data": p.data,
                "store": str(p.store),
                # the generate run whose data this is (none for source demos): the report
                # checks it
                "data_run_id": data.attrs.get("run_id"),
                "control_mode": data.attrs.get("control_mode"),
                "train_episodes": int(train_data.n_episodes),
                "val_episodes": int(val_data.n_episodes),
                "train_params": training_params(t),
            }
        )
    side_by_side = min(t.workers, len(runs))
    # every policy's checkpoints, curve and metrics are written aside and renamed together
    # when all have trained, checkpoints last
    outputs = [p.plot for p in todo] + [p.metrics for p in todo] + [p.out for p in todo]
    with output_set(*outputs) as tmps:
        n = len(todo)
        tmp_plots, tmp_metrics, tmp_outs = tmps[:n], tmps[n : 2 * n], tmps[2 * n :]
        results = run_trainings(runs, side_by_side, prof.threads)
        curves: list[list[dict]] = [[] for _ in todo]  # one row per (seed, epoch)
        finished = 0
        try:
            for k, run_, (history, checkpoints) in zip(owners, runs, results, strict=True):
                for epoch, model in checkpoints:
                    step = epoch * prof.steps_per_epoch
                    meta = {**metas[k], "seed": run_.seed, "epoch": epoch, "step": step}
                    save_checkpoint(
                        tmp_outs[k] / f"seed{run_.seed}" / f"epoch{epoch:05d}.pt", model, meta
                    )
                curves[k] += [{"seed": run_.seed, **r} for r in history]
                finished += 1
        except Interrupted as exc:
            exc.detail = f"with {finished} of {len(runs)} trainings finished"
            raise
        for i, (p, meta, rows) in enumerate(zip(todo, metas, curves, strict=True)):
            write_curve(tmp_plots[i], rows)
            last = [r for r in rows if r["epoch"] == prof.epochs]
            seconds = sum(r["seconds"] for r in last)
            steps = prof.epochs * prof.steps_per_epoch * len(prof.seeds)
            write_metrics(
                tmp_metrics[i],
                {
                    "profile": t.profile,
                    "seeds": len(prof.seeds),
                    "data_run_id": meta["data_run_id"],
                    "train_episodes": meta["train_episodes"],
                    "val_episodes": meta["val_episodes"],
                    "gradient_steps": steps,
                    "final_loss": float(np.mean([r["loss"] for r in last])),
                    "final_val_loss": float(np.mean([r["val_loss"] for r in last])),
                    "wall_seconds": seconds,
                    "seconds_per_1000_steps": 1000 * seconds / steps,
                    "torch_threads": prof.threads or torch.get_num_threads(),
                    "trainings_side_by_side": side_by_side,
                },
            )
            episodes = meta["train_episodes"] + meta["val_episodes"]
            print(
                f"train: {len(prof.seeds)} run(s) on {episodes} episodes of {p.store}, "
                f"{1000 * seconds / steps:.1f} s per 1000 steps -> {p.out}"
            )
