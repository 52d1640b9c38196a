"""evaluate_external: roll out a policy trained elsewhere (robomimic or LeRobot, on our
export) in one reset variant, from the scenes the evaluate stage rolls our checkpoints out
from, with the same metrics. Its framework runs in its own Python (mimicgen_pipe.formats.external).
Given several checkpoints of one training run (in training order), each is rolled out on
the same scenes, and the metrics are its max and last as for our own runs."""

from __future__ import annotations

import argparse
import csv
import functools
from pathlib import Path

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.taskspec import TaskSpec
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.metrics import (
    evaluation_metrics,
    metrics_identity,
    split_timings,
    write_metrics,
    write_timings,
)
from mimicgen_pipe.data.outputs import claim, output_set
from mimicgen_pipe.data.params import Params
from mimicgen_pipe.formats.exporters import task_description
from mimicgen_pipe.formats.external import (
    DEFAULT_PYTHON,
    PolicySpec,
    Probed,
    check_python,
    format_module,
    load_external_policy,
    parse_policy,
    policy_digest,
    probe,
)
from mimicgen_pipe.learn.evaluation import (
    EvalJob,
    EvaluateExternalJob,
    Rollout,
    evaluate_external,
    evaluation_seed,
    success_rate,
)
from mimicgen_pipe.run.executors import stage_executor
from mimicgen_pipe.stages import (
    add_selection_arguments,
    camera_renderer,
    check_data,
    episode_count,
    stage_params,
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument(
        "--policy",
        required=True,
        nargs="+",
        help="robomimic:<checkpoint .pth> or lerobot:<policy directory> (its pretrained_model);"
        " several: checkpoints of one training run, in training order; robomimic:<folder>: its "
        "model_epoch_<N>.pth by epoch",
    )
    p.add_argument(
        "--data",
        required=True,
        help='what it was trained on: "source" or a variant (the store whose export it read)',
    )
    p.add_argument("--variant", required=True, help="reset variant to evaluate in, e.g. D1")
    p.add_argument(
        "--python",
        help=f"the Python its framework is installed in (default: {DEFAULT_PYTHON}, which "
        "scripts/setup.sh makes)",
    )
    p.add_argument(
        "--episodes", type=episode_count, help="episodes (default: params evaluate.episodes)"
    )
    p.add_argument(
        "--metrics",
        help="metrics JSON (default: metrics/external/evaluate_<task>_<data>_on_<variant>_"
        "<format>.json)",
    )
    p.add_argument(
        "--plot",
        help="one row per episode: seed, success, steps (default: plots/external/<same>.csv)",
    )


def write_episodes(path: Path, rollouts: list[tuple[int | None, list[Rollout]]]) -> None:
    """One row per checkpoint and episode: the checkpoint's epoch (empty where unknown), the
    episode's reset seed, success and steps run."""
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["epoch", "episode", "seed", "success", "steps"])
        for epoch, runs in rollouts:
            e = "" if epoch is None else epoch
            writer.writerows((e, i, r.seed, int(r.success), r.steps) for i, r in enumerate(runs))


def checkpoint_epoch(fmt: str, path: Path, label: str) -> tuple[int | None, str]:
    """How far the policy's training had got when it was saved, and in what unit (robomimic:
    the epoch of model_epoch_<N>.pth; LeRobot: the step of checkpoints/<step>/), as the
    metrics' seed0_best_epoch and epoch_unit; says so where the path does not tell."""
    module = format_module(fmt)
    epoch = module.checkpoint_epoch(path)
    if epoch is None:
        print(f"{label}: {path} does not say its training {module.EPOCH_UNIT} (not named as "
              f"{fmt} names its checkpoints): seed0_best_epoch is null")  # fmt: skip
    return epoch, module.EPOCH_UNIT


def eval_job(
    params: Params, spec: TaskSpec, robot: str, policy: PolicySpec, variant: str, probed: Probed
) -> EvalJob:
    """The rollouts' job: ``policy`` (served in its own interpreter) acting with ``robot`` in
    ``variant``, given the cameras it reads (``probed``) rendered in the workers."""
    return EvalJob(
        make_env=functools.partial(
            backends.make_env, params.backend, params.task, robot, params.maniskill.lean_step
        ),
        load_policy=functools.partial(load_external_policy, policy),
        variant=variant,
        horizon=spec.horizon,
        objects=spec.objects,
        arms=spec.arms,
        make_cameras=camera_renderer(params, robot, probed.cameras, probed.size),
    )


def run_policies(texts: list[str]) -> tuple[str, list[Path]]:
    """--policy's format and checkpoints (a robomimic folder: its checkpoints by epoch), in
    training order; InputError where they are of more than one format."""
    given = [
        (fmt, checkpoint)
        for fmt, path in map(parse_policy, texts)
        for checkpoint in format_module(fmt).run_checkpoints(path)
    ]
    fmt = given[0][0]
    if any(f != fmt for f, _ in given):
        raise InputError(f"--policy: checkpoints of one run, of one format (got {fmt} and more)")
    return fmt, [path for _, path in given]


def probe_policies(
    params: Params, spec: TaskSpec, robot: str, policies: list[PolicySpec]
) -> list[Probed]:
    """What each policy reads, its server started and asked (formats.external.probe):
    InputError where our env with ``robot`` cannot give it its inputs or take its actions."""
    known = backends.backend_package(params.backend).cameras(robot)
    env_kwargs = {"backend": params.backend, "task": params.task, "robot": robot}
    return [probe(p, spec.observation_dims, env_kwargs, known, spec.action_dim) for p in policies]


def resolve(args: argparse.Namespace) -> EvaluateExternalJob:
    """The evaluate_external run ``args`` ask for: the params, the checkpoints, the
    executor's settings, the robot, the framework's Python and every checkpoint's server
    probed; writes nothing."""
    params = stage_params(args)
    spec = backends.task_spec(params.backend, params.task)
    backends.check_variant(spec, args.variant)
    check_data(params, args.data, named=False)
    fmt, given = run_policies(args.policy)
    e = params.evaluate
    episodes = e.episodes if args.episodes is None else args.episodes
    name = f"{args.data}_on_{args.variant}_{fmt}"
    default_metrics, default_plot = layout.external_evaluation_files(params.task, name)
    executor = stage_executor(params, "evaluate")  # refuses unsafe Ray settings
    # a policy acts with the arm its training data was recorded with
    robot = params.source.robot if args.data == "source" else params.generate.robot
    backends.check_robot(params.backend, robot)
    python = check_python(args.python or str(DEFAULT_PYTHON))
    policies = [
        PolicySpec(
            fmt, str(path.resolve()), python, tuple(params.train.obs_keys), task_description(spec)
        )
        for path in given
    ]
    probed = probe_policies(params, spec, robot, policies)
    epochs = [checkpoint_epoch(fmt, Path(p.path), f"evaluate {name}") for p in policies]
    first = probed[0]
    return EvaluateExternalJob(
        task=params.task,
        backend=params.backend,
        robot=robot,
        data=args.data,
        variant=args.variant,
        policy_format=fmt,
        checkpoints=tuple(given),
        names=tuple(p.name for p in policies),
        rollouts=tuple(
            eval_job(params, spec, robot, p, args.variant, pr)
            for p, pr in zip(policies, probed, strict=True)
        ),
        epochs=tuple(epoch for epoch, _ in epochs),
        epoch_unit=epochs[-1][1],
        inputs={k: (v["shape"], v["dtype"]) for k, v in first.observations.items()},
        cameras=first.cameras,
        size=first.size,
        policy_sha256=policy_digest(given[-1]),
        seeds=tuple(evaluation_seed(e.seed, args.variant, i) for i in range(episodes)),
        evaluate=e,
        executor=executor,
        metrics_path=Path(args.metrics or default_metrics),
        plot=Path(args.plot or default_plot),
    )


def run(job: EvaluateExternalJob) -> None:
    # fails at once if another run writes them
    claim(job.metrics_path, job.plot, inputs=job.checkpoints)
    for line in job.plan():
        print(line)
    results, wall = evaluate_external(job)
    # in the terms of our own evaluation: one training run, its checkpoints in order
    metrics = evaluation_metrics({0: [(epoch, success_rate(r)) for epoch, r in results]})
    episodes, e = len(job.seeds), job.evaluate
    metrics.update(
        epoch_unit=job.epoch_unit,
        policy_format=job.policy_format,
        policy=str(job.checkpoints[-1]),
        policy_sha256=job.policy_sha256,
        data_run_id=None,
        episodes=episodes,
        horizon=job.horizon,
        cameras=",".join(job.cameras),
        wall_seconds=wall,
        seconds_per_episode=wall / (episodes * len(job.checkpoints)),
        workers=e.workers,
        executor=e.executor,
    )
    metrics, timings = split_timings(metrics)
    identity = metrics_identity(
        "evaluate", job.task, job.backend, job.robot, variant=job.variant, data=job.data
    )
    with output_set(job.plot, job.metrics_path) as (tmp_plot, tmp_metrics):
        write_episodes(tmp_plot, results)
        write_metrics(tmp_metrics, identity | metrics)
    write_timings(job.metrics_path, identity, timings)
    print(f"{job.label}: success {metrics['success_rate_max']:.1f}% -> {job.metrics_path}")
