"""evaluate_external: roll out a policy trained elsewhere (robomimic or LeRobot, on our
export) in one reset variant, from the scenes the evaluate stage rolls our checkpoints out
from, with the same metrics. Its framework runs in its own Python (mimicgen_pipe.external).
No pipeline stage: a command for policies trained outside it."""

from __future__ import annotations

import argparse
import csv
import functools
from pathlib import Path

import envs
from mimicgen_pipe import layout
from mimicgen_pipe.evaluation import (
    EvalJob,
    Rollout,
    evaluate_policies,
    evaluation_seed,
    rollout_plan,
    success_rate,
)
from mimicgen_pipe.executors import stage_executor
from mimicgen_pipe.exporters import task_description
from mimicgen_pipe.external import (
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
from mimicgen_pipe.metrics import evaluation_metrics, metrics_identity, write_metrics
from mimicgen_pipe.outputs import claim, output_set
from mimicgen_pipe.params import Params
from mimicgen_pipe.taskspec import TaskSpec
from stages import (
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
        help="robomimic:<checkpoint .pth> or lerobot:<policy directory> (its pretrained_model)",
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


def write_episodes(path: Path, rollouts: list[Rollout]) -> None:
    """One row per episode: its reset seed, success and steps run."""
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["episode", "seed", "success", "steps"])
        writer.writerows((i, r.seed, int(r.success), r.steps) for i, r in enumerate(rollouts))


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


def print_plan(label: str, probed: Probed, episodes: int, horizon: int, workers: int) -> None:
    """What the policy reads, the cameras rendered for it, and the work, before any rollout."""
    inputs = {k: (v["shape"], v["dtype"]) for k, v in probed.observations.items()}
    for line in rollout_plan(label, inputs, probed.cameras, probed.size, 1, episodes, horizon,
                             workers):  # fmt: skip
        print(line)


def eval_job(
    params: Params, spec: TaskSpec, robot: str, policy: PolicySpec, variant: str, probed: Probed
) -> EvalJob:
    """The rollouts' job: ``policy`` (served in its own interpreter) acting with ``robot`` in
    ``variant``, given the cameras it reads (``probed``) rendered in the workers."""
    return EvalJob(
        make_env=functools.partial(
            envs.make_env, params.backend, params.task, robot, params.maniskill.lean_step
        ),
        load_policy=functools.partial(load_external_policy, policy),
        variant=variant,
        horizon=spec.horizon,
        objects=spec.objects,
        arms=spec.arms,
        make_cameras=camera_renderer(params, robot, probed.cameras, probed.size),
    )


def run(args: argparse.Namespace) -> None:
    params = stage_params(args)
    spec = envs.task_spec(params.backend, params.task)
    envs.check_variant(spec, args.variant)
    check_data(params, args.data, named=False)
    fmt, path = parse_policy(args.policy)
    e = params.evaluate
    episodes = e.episodes if args.episodes is None else args.episodes
    name = f"{args.data}_on_{args.variant}_{fmt}"
    default_metrics, default_plot = layout.external_evaluation_files(params.task, name)
    metrics_path = Path(args.metrics or default_metrics)
    plot_path = Path(args.plot or default_plot)
    claim(metrics_path, plot_path, inputs=[path])  # fails at once if another run writes them
    executor = stage_executor(params, "evaluate")  # refuses unsafe Ray settings before any work
    # a policy acts with the arm its training data was recorded with
    robot = params.source.robot if args.data == "source" else params.generate.robot
    envs.check_robot(params.backend, robot)
    python = check_python(args.python or str(DEFAULT_PYTHON))
    policy = PolicySpec(
        fmt, str(path.resolve()), python, tuple(params.train.obs_keys), task_description(spec)
    )
    known = envs.backend_package(params.backend).cameras(robot)
    env_kwargs = {"backend": params.backend, "task": params.task, "robot": robot}
    probed = probe(policy, spec.observation_dims, env_kwargs, known, spec.action_dim)
    job = eval_job(params, spec, robot, policy, args.variant, probed)
    seeds = [evaluation_seed(e.seed, args.variant, i) for i in range(episodes)]
    label = f"evaluate {name}"
    epoch, unit = checkpoint_epoch(fmt, path, label)
    print_plan(label, probed, episodes, spec.horizon, e.workers)
    results, wall = evaluate_policies(job, [policy.name], seeds, executor, label)
    rollouts = results[policy.name]
    # in the terms of our own evaluation: one training run, one checkpoint, of its epoch
    metrics = evaluation_metrics({0: [(epoch, success_rate(rollouts))]})
    metrics.update(
        epoch_unit=unit,
        policy_format=fmt,
        policy=str(path),
        policy_sha256=policy_digest(path),
        data_run_id=None,
        episodes=episodes,
        horizon=spec.horizon,
        cameras=",".join(probed.cameras),
        wall_seconds=wall,
        seconds_per_episode=wall / episodes,
        workers=e.workers,
        executor=e.executor,
    )
    with output_set(plot_path, metrics_path) as (tmp_plot, tmp_metrics):
        write_episodes(tmp_plot, rollouts)
        identity = metrics_identity(
            "evaluate", params.task, params.backend, robot, variant=args.variant, data=args.data
        )
        write_metrics(tmp_metrics, identity | metrics)
    print(f"evaluate {name}: success {metrics['success_rate_max']:.1f}% -> {metrics_path}")
