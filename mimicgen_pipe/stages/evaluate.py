"""evaluate: roll out a training run's checkpoints (every ``evaluate.every_epochs``-th epoch
and the last) in one reset variant."""

from __future__ import annotations

import argparse
import csv
import functools
from pathlib import Path

from mimicgen_pipe import backends
from mimicgen_pipe.data import layout, pipelines
from mimicgen_pipe.data.metrics import (
    evaluation_metrics,
    metrics_identity,
    split_timings,
    write_metrics,
    write_timings,
)
from mimicgen_pipe.data.outputs import claim, output_set
from mimicgen_pipe.learn.evaluation import (
    EvalJob,
    EvaluateJob,
    checkpoints_to_evaluate,
    evaluate_checkpoints,
    evaluation_seed,
    policy_inputs,
    run_metrics,
)
from mimicgen_pipe.learn.training import load_rollout_policy
from mimicgen_pipe.run.executors import stage_executor
from mimicgen_pipe.stages import (
    add_selection_arguments,
    camera_renderer,
    check_data,
    output_path,
    stage_params,
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument(
        "--data",
        required=True,
        help='the policy\'s training data: "source", a variant or the name it was trained under',
    )
    p.add_argument("--variant", required=True, help="reset variant to evaluate in, e.g. D1")
    p.add_argument("--policies", help="checkpoint directory (default: data/policies/<task>_<data>)")
    p.add_argument(
        "--metrics", help="metrics JSON (default: metrics/evaluate_<task>_<data>_on_<variant>.json)"
    )
    p.add_argument("--plot", help="success per checkpoint CSV (default: plots/evaluate_<...>.csv)")


def write_success_rates(path: Path, per_run: dict[int, list[tuple[int, float]]]) -> None:
    """Success rate [%] per checkpoint, one row per (training seed, epoch)."""
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["seed", "epoch", "success_rate"])
        writer.writerows((s, ep, rate) for s, rows in per_run.items() for ep, rate in rows)


def checkpoints_made_by(data: str, policies: Path, default: bool) -> str:
    """What writes the checkpoints of ``policies`` (the policy directory of training data
    ``data``; ``default``: the default one), for the error when there are none: the
    pipeline stage that tracks it (a train run by hand writes elsewhere), else the train
    command."""
    if tracked := pipelines.made_by(policies):
        return tracked
    command = f"mimicgen-pipe train --data {data}" + ("" if default else f" --out {policies}")
    return f"; the train stage writes them: run `{command}` first"


def resolve(args: argparse.Namespace) -> EvaluateJob:
    """The evaluate run ``args`` ask for: the params, the executor's settings, the robot,
    every checkpoint to roll out loaded and checked, and the cameras an image policy reads;
    writes nothing."""
    params = stage_params(args)
    spec = backends.task_spec(params.backend, params.task)
    backends.check_variant(spec, args.variant)
    check_data(params, args.data, named=args.policies is not None)
    name = f"{args.data}_on_{args.variant}"
    policies = Path(args.policies or layout.policy_dir(params.task, args.data))
    metrics_path = output_path(args.metrics, layout.metrics_file("evaluate", params.task, name))
    plot_path = output_path(args.plot, layout.plot_file("evaluate", params.task, name))
    executor = stage_executor(params, "evaluate")  # refuses unsafe Ray settings
    # a policy acts with the arm its training data was recorded with
    robot = params.source.robot if args.data == "source" else params.generate.robot
    backends.check_robot(params.backend, robot)
    e = params.evaluate
    checkpoints = checkpoints_to_evaluate(
        policies, spec, params.train.obs_keys, e.every_epochs,
        checkpoints_made_by(args.data, policies, args.policies is None),
    )  # fmt: skip
    # an image policy's cameras, rendered in the workers at its training size
    cameras, size = checkpoints.cameras, checkpoints.image_size
    backends.check_cameras(params.backend, robot, cameras, f"{policies}: the policy's cameras")
    rollouts = EvalJob(
        make_env=functools.partial(
            backends.make_env, params.backend, params.task, robot, params.maniskill.lean_step
        ),
        load_policy=load_rollout_policy,
        variant=args.variant,
        horizon=spec.horizon,
        objects=spec.objects,
        arms=spec.arms,
        make_cameras=camera_renderer(params, robot, cameras, size),
    )
    return EvaluateJob(
        task=params.task,
        backend=params.backend,
        robot=robot,
        data=args.data,
        variant=args.variant,
        policies=policies,
        checkpoints=checkpoints,
        inputs=policy_inputs(checkpoints, params.train.obs_keys, spec.observation_dims),
        seeds=tuple(evaluation_seed(e.seed, args.variant, i) for i in range(e.episodes)),
        evaluate=e,
        executor=executor,
        rollouts=rollouts,
        metrics_path=metrics_path,
        plot=plot_path,
    )


def run(job: EvaluateJob) -> None:
    # fails at once if another run writes them
    claim(job.metrics_path, job.plot, inputs=[job.policies])
    for line in job.plan():
        print(line)
    per_run, wall = evaluate_checkpoints(job)
    metrics, timings = split_timings(evaluation_metrics(per_run) | run_metrics(job, wall))
    identity = metrics_identity(
        "evaluate", job.task, job.backend, job.robot, variant=job.variant, data=job.data
    )
    with output_set(job.plot, job.metrics_path) as (tmp_plot, tmp_metrics):
        write_success_rates(tmp_plot, per_run)
        write_metrics(tmp_metrics, identity | metrics)
    write_timings(job.metrics_path, identity, timings)
    print(
        f"{job.label}: success {metrics['success_rate_max']:.1f}% (max over checkpoints), "
        f"{metrics['success_rate_last']:.1f}% (last checkpoint) -> {job.metrics_path}"
    )
