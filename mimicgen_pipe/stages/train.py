"""train: BC-RNN policies on the source demos or on generated datasets, one run per
training seed of the active profile (params train.profile). Given several datasets
(``--data source D0 D1``) it trains them side by side, ``train.workers`` processes at a time:
DVC runs one stage at a time, and one training keeps one core busy."""

from __future__ import annotations

import argparse
import csv
import dataclasses
from pathlib import Path

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.taskspec import check_task_version
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.metrics import metrics_identity, split_timings, write_metrics, write_timings
from mimicgen_pipe.data.outputs import claim, output_set
from mimicgen_pipe.data.params import Params, range_error
from mimicgen_pipe.learn.training import (
    POLICY_DIR,
    PolicyToTrain,
    TrainJob,
    policy_training,
    train_policies,
    training_metrics,
)
from mimicgen_pipe.stages import add_selection_arguments, check_data, output_path, stage_params


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument(
        "--data",
        required=True,
        nargs="+",
        help='training data, one policy each: "source" (the source demos) or a reset variant '
        "such as D1 (that variant's generated store); with --store, any name for each store",
    )
    p.add_argument(
        "--num-demos",
        type=int,
        nargs="+",
        help="generated demos each policy trains on (the first N kept), in place of "
        "train.num_demos: one for every --data, or one per --data",
    )
    p.add_argument(
        "--num-seeds",
        type=int,
        help="train each policy with seeds 0..N-1 (one run each), in place of "
        "train.<profile>.seeds",
    )
    p.add_argument(
        "--store",
        nargs="+",
        help="store to train on, one per --data (default: from --data, see layout)",
    )
    p.add_argument(
        "--out",
        nargs="+",
        help="checkpoint directory, one per --data (default: data/policies/<task>_<data>)",
    )
    p.add_argument(
        "--metrics",
        nargs="+",
        help="metrics JSON, one per --data (default: metrics/train_<task>_<data>.json)",
    )
    p.add_argument(
        "--plot",
        nargs="+",
        help="training curve CSV, one per --data (default: plots/train_<task>_<data>.csv)",
    )


def write_curve(path: Path, rows: list[dict]) -> None:
    """The training curve, one row per (training seed, epoch); the rows' wall-clock
    ``seconds`` go to the timings file instead (training_metrics' ``epoch_seconds``)."""
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(
            f, ["seed", "epoch", "step", "loss", "val_loss"], extrasaction="ignore"
        )
        writer.writeheader()
        writer.writerows(rows)


def policies(args: argparse.Namespace, params: Params) -> list[PolicyToTrain]:
    """The policies the command line asks for, checked before any work."""
    data: list[str] = args.data
    if len(set(data)) != len(data):
        raise InputError(f"--data {' '.join(data)}: each dataset at most once")
    num_demos = args.num_demos or [params.train.num_demos]
    for n in num_demos:  # each stands in for train.num_demos, held to its range
        if why := range_error("train.num_demos", n):
            raise InputError(f"--num-demos {n}: {why}")
    if len(num_demos) not in (1, len(data)):
        raise InputError(
            f"--num-demos: expected one count, or one per --data ({len(data)}), "
            f"got {len(num_demos)}"
        )
    for key in ("store", "out", "metrics", "plot"):
        given = getattr(args, key)
        if given is not None and len(given) != len(data):
            raise InputError(
                f"--{key}: expected one path per --data ({len(data)}), got {len(given)}"
            )
    for d in data:  # with --store, any name: it names the policy
        check_data(params, d, named=args.store is not None)
    t = params.task
    return [
        PolicyToTrain(
            d,
            Path(args.store[i] if args.store else layout.training_store(t, d)),
            output_path(args.out[i] if args.out else None, layout.policy_dir(t, d)),
            output_path(
                args.metrics[i] if args.metrics else None, layout.metrics_file("train", t, d)
            ),
            output_path(args.plot[i] if args.plot else None, layout.plot_file("train", t, d)),
            num_demos[i if len(num_demos) > 1 else 0],
        )
        for i, d in enumerate(data)
    ]


def with_seeds(params: Params, args: argparse.Namespace) -> Params:
    """``params`` with seeds 0..N-1 of --num-seeds, where given, as the active profile's
    training seeds."""
    if args.num_seeds is None:
        return params
    if why := range_error("suite.policy_seeds", args.num_seeds):
        raise InputError(f"--num-seeds {args.num_seeds}: {why}")
    t = params.train
    profile = dataclasses.replace(t.active, seeds=list(range(args.num_seeds)))
    return dataclasses.replace(params, train=dataclasses.replace(t, **{t.profile: profile}))


def resolve(args: argparse.Namespace) -> TrainJob:
    """The train run ``args`` ask for: the params, every policy's options and paths, and
    every training's store read and checked; writes nothing."""
    params = with_seeds(stage_params(args), args)
    t, prof = params.train, params.train.active
    todo = policies(args, params)
    # only the arrays and episodes the trainings use are read, each store checked first
    trainings = [
        policy_training(
            dataclasses.replace(params, train=dataclasses.replace(t, num_demos=p.num_demos)),
            p.data,
            p.store,
        )
        for p in todo
    ]
    spec = backends.task_spec(params.backend, params.task)
    for p, training in zip(todo, trainings, strict=True):  # data of the task as it is now
        check_task_version(training.data.attrs, spec, str(p.store))
    # image trainings side by side share one copy of the images (mapped from a file)
    side_by_side = min(t.workers, len(todo) * len(prof.seeds))
    return TrainJob(params.task, params.backend, t, tuple(todo), tuple(trainings), side_by_side)


def run(job: TrainJob) -> None:
    todo, prof = job.policies, job.train.active
    # fails at once if another run writes them, or if they would replace anything else
    claim(
        *(o for p in todo for o in ((p.out, POLICY_DIR), p.metrics, p.plot)),
        inputs=[p.store for p in todo],
    )
    # every policy's checkpoints, curve and metrics are written aside and renamed together
    # when all have trained, checkpoints last
    outputs = [p.plot for p in todo] + [p.metrics for p in todo] + [p.out for p in todo]
    times = []  # (metrics path, identity, timings) of each policy, written after the commit
    with output_set(*outputs) as tmps:
        n = len(todo)
        tmp_plots, tmp_metrics, tmp_outs = tmps[:n], tmps[n : 2 * n], tmps[2 * n :]
        curves = train_policies(job, tmp_outs)
        for i, (p, training, rows) in enumerate(zip(todo, job.trainings, curves, strict=True)):
            write_curve(tmp_plots[i], rows)
            meta = training.meta
            metrics, timings = split_timings(
                training_metrics(job.train, training, rows, job.side_by_side)
            )
            identity = metrics_identity("train", job.task, job.backend, meta["robot"], data=p.data)
            write_metrics(tmp_metrics[i], identity | metrics)
            times.append((p.metrics, identity, timings))
            episodes = meta["train_episodes"] + meta["val_episodes"]
            print(
                f"train: {len(prof.seeds)} run(s) on {episodes} episodes of {p.store}, "
                f"{timings['seconds_per_1000_steps']:.1f} s per 1000 steps -> {p.out}"
            )
    for path, identity, timings in times:
        write_timings(path, identity, timings)
