"""evaluate: roll out a training run's checkpoints (every ``evaluate.every_epochs``-th epoch
and the last) in one reset variant."""

from __future__ import annotations

import argparse
import csv
import functools
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

import envs
from mimicgen_pipe import layout
from mimicgen_pipe.errors import InputError
from mimicgen_pipe.evaluation import (
    EvalJob,
    evaluated_checkpoints,
    evaluation_seed,
    run_evaluation,
)
from mimicgen_pipe.interrupts import Interrupted
from mimicgen_pipe.metrics import evaluation_metrics, write_metrics
from mimicgen_pipe.observations import observation_dims
from mimicgen_pipe.outputs import check_same_run, claim, output_set
from mimicgen_pipe.params import stage_executor
from mimicgen_pipe.training import load_checkpoint, load_rollout_policy
from stages import add_selection_arguments, stage_params


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument(
        "--data", required=True, help='the policy\'s training data: "source" or a variant'
    )
    p.add_argument("--variant", required=True, help="reset variant to evaluate in, e.g. D1")
    p.add_argument("--policies", help="checkpoint directory (default: data/policies/<task>_<data>)")
    p.add_argument(
        "--metrics", help="metrics JSON (default: metrics/evaluate_<task>_<data>_on_<variant>.json)"
    )
    p.add_argument("--plot", help="success per checkpoint CSV (default: plots/evaluate_<...>.csv)")


def find_checkpoints(directory: Path) -> dict[int, list[Path]]:
    """Training seed -> its checkpoints in epoch order (layout: seed<k>/epoch<NNNNN>.pt)."""
    runs: dict[int, list[Path]] = {}
    for run_dir in sorted(directory.glob("seed*")):
        ckpts = sorted(run_dir.glob("epoch*.pt"))
        if ckpts and run_dir.name[4:].isdigit():
            runs[int(run_dir.name[4:])] = ckpts
    if not runs:
        raise InputError(f"{directory}: no checkpoints (expected seed<k>/epoch<N>.pt)")
    return runs


def check_meta(ckpt: Path, meta: dict) -> None:
    """The meta keys an evaluation reads: ``task`` (a string) and ``epoch`` (a positive
    integer); one line naming the file and the key otherwise."""
    for key, kind, ok in (
        ("task", "a task name", lambda v: isinstance(v, str)),
        ("epoch", "a positive integer", lambda v: type(v) is int and v > 0),
    ):
        if key not in meta:
            raise InputError(
                f"{ckpt}: meta has no {key!r} (expected {kind}); not a checkpoint the train "
                "stage wrote"
            )
        if not ok(meta[key]):
            raise InputError(f"{ckpt}: meta {key!r} is {meta[key]!r}, expected {kind}")


def run(args: argparse.Namespace) -> None:
    params = stage_params(args)
    spec = envs.task_spec(params.backend, params.task)
    envs.check_variant(spec, args.variant)
    name = f"{args.data}_on_{args.variant}"
    policies = Path(args.policies or layout.policy_dir(params.task, args.data))
    metrics_path = Path(args.metrics or layout.metrics_file("evaluate", params.task, name))
    plot_path = Path(args.plot or layout.plot_file("evaluate", params.task, name))
    claim(metrics_path, plot_path, inputs=[policies])  # fails at once if another run writes them
    executor = stage_executor(params, "evaluate")  # refuses unsafe Ray settings before any work

    # a policy acts with the arm its training data was recorded with
    robot = params.source.robot if args.data == "source" else params.generate.robot
    envs.check_robot(params.backend, robot)
    runs = find_checkpoints(policies)
    expected = observation_dims(spec.objects)
    epochs: dict[Path, int] = {}
    data_run_ids: dict[str, object] = {}
    for ckpt in (c for ckpts in runs.values() for c in ckpts):
        model, meta = load_checkpoint(ckpt)
        check_meta(ckpt, meta)
        layout_ = dict(zip(model.config.obs_keys, model.config.obs_dims, strict=True))
        wrong = {k: d for k, d in layout_.items() if expected.get(k) != d}
        if meta.get("task") != params.task or wrong:
            raise InputError(
                f"{ckpt}: observation layout {layout_} (task {meta.get('task')!r}) does not fit "
                f"task {params.task!r}, whose observations are {expected}"
            )
        if list(model.config.obs_keys) != list(params.train.obs_keys):
            raise InputError(
                f"{ckpt}: trained on observation keys {list(model.config.obs_keys)}, but "
                f"params train.obs_keys is {list(params.train.obs_keys)}"
            )
        epochs[ckpt] = int(meta["epoch"])
        data_run_ids[str(ckpt)] = meta.get("data_run_id")
    check_same_run(data_run_ids, "train")  # checkpoints of one training run only
    e = params.evaluate
    try:
        runs = {
            seed: [
                ckpts[i] for i in evaluated_checkpoints([epochs[c] for c in ckpts], e.every_epochs)
            ]
            for seed, ckpts in runs.items()
        }
    except InputError as exc:
        raise InputError(f"{policies}: {exc}") from None

    seeds = [evaluation_seed(e.seed, args.variant, i) for i in range(e.episodes)]
    job = EvalJob(
        make_env=functools.partial(
            envs.make_env, params.backend, params.task, robot, params.maniskill.fast_step
        ),
        load_policy=load_rollout_policy,
        variant=args.variant,
        horizon=spec.horizon,
        objects=spec.objects,
    )
    names = [str(c) for ckpts in runs.values() for c in ckpts]
    success: dict[str, list[bool]] = {n: [] for n in names}
    t0 = time.perf_counter()
    bar = tqdm(total=len(names) * e.episodes, desc=f"evaluate {name}", unit="episode")
    results = run_evaluation(job, names, seeds, executor)
    try:
        for ckpt, rollouts in results:
            success[ckpt] += [r.success for r in rollouts]
            bar.update(len(rollouts))
    except Interrupted as exc:
        exc.detail = f"after {bar.n} of {bar.total} episodes"
        raise
    finally:
        results.close()
        bar.close()
    wall = time.perf_counter() - t0

    per_run = {
        seed: [(epochs[c], 100.0 * float(np.mean(success[str(c)]))) for c in ckpts]
        for seed, ckpts in runs.items()
    }
    metrics = evaluation_metrics(per_run)
    metrics.update(
        data_run_id=next(iter(data_run_ids.values())),
        episodes=e.episodes,
        every_epochs=e.every_epochs,
        horizon=spec.horizon,
        wall_seconds=wall,
        seconds_per_episode=wall / (len(names) * e.episodes),
        workers=e.workers,
        executor=e.executor,
    )
    with output_set(plot_path, metrics_path) as (tmp_plot, tmp_metrics):
        with tmp_plot.open("w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["seed", "epoch", "success_rate"])
            writer.writerows((s, ep, rate) for s, rows in per_run.items() for ep, rate in rows)
        write_metrics(tmp_metrics, metrics)
    print(
        f"evaluate {name}: success {metrics['success_rate_max']:.1f}% (max over checkpoints), "
        f"{metrics['success_rate_last']:.1f}% (last checkpoint) -> {metrics_path}"
    )
