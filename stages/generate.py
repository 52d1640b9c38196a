"""generate: MimicGen data generation for one reset variant."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

import envs
from mimicgen_pipe import layout
from mimicgen_pipe.errors import InputError
from mimicgen_pipe.generation import Attempt, GenerationConfig, SourceDemos, reachable_scenes
from mimicgen_pipe.interrupts import Interrupted
from mimicgen_pipe.metrics import generation_metrics, write_metrics
from mimicgen_pipe.outputs import claim, output_set, run_id, store_digest
from mimicgen_pipe.params import data_params, stage_executor
from mimicgen_pipe.pose_noise import check_store_noise, pose_noise_level
from mimicgen_pipe.resume import WorkDir, code_digest
from mimicgen_pipe.runner import ATTEMPTS_PER_BLOCK, AttemptJob, attempt_seed, run_attempts
from mimicgen_pipe.store import EpisodeStore, read_store, write_store
from mimicgen_pipe.taskspec import TaskSpec
from stages import add_selection_arguments, stage_params


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p, robot=True)
    p.add_argument("--variant", required=True, help="reset variant, e.g. D0 or D1")
    p.add_argument(
        "--parsed",
        help="parsed source store as the pose_noise stage wrote it (default: "
        "data/pose_noise/<task>.zarr); a clean parsed store is accepted at level none",
    )
    p.add_argument(
        "--out",
        help="generated store (default: data/generated/<task>_<variant>.zarr;"
        " failed attempts go to <name>_failed.zarr beside it)",
    )
    p.add_argument(
        "--metrics", help="metrics JSON (default: metrics/generate_<task>_<variant>.json)"
    )
    p.add_argument(
        "--attempts",
        type=int,
        help="run exactly this many attempts (fixed_attempts mode), whatever generate.mode says",
    )


WORKSPACE_SCENES = 8  # scenes sampled to check that the arm can reach the workspace
IK_ABORT_AFTER = 50  # stop when this many attempts in a row all failed at IK


def source_demos(store: EpisodeStore, objects: tuple[str, ...]) -> SourceDemos:
    """The parsed store's arrays in the generator's form (4x4 world poses)."""
    return SourceDemos(
        target_poses=store.poses("target_pose"),
        gripper=np.asarray(store.data["gripper"], np.float64),
        object_poses={o: store.poses(f"object_poses/{o}") for o in objects},
        episode_ends=store.episode_ends,
        term_index=np.asarray(store.episodes["subtask_term_index"], np.int64),
    )


def episode_fields(attempts: list[Attempt], spec: TaskSpec) -> dict[str, np.ndarray]:
    """meta/episodes of a generated (or failed) store, shaped also when it has none."""
    n = len(attempts)
    return {
        "seed": np.asarray([a.seed for a in attempts], np.int64),
        "success": np.asarray([a.success for a in attempts], bool),
        "source_demo": np.asarray([a.source_demo for a in attempts], np.int64).reshape(
            n, len(spec.subtasks)
        ),
        "initial_object_poses": np.asarray([a.initial_object_poses for a in attempts]).reshape(
            n, len(spec.objects), 4, 4
        ),
        "initial_state": np.asarray([a.initial_state for a in attempts], np.float32),
        "failure_reason": np.asarray([a.failed_subtask for a in attempts], np.int64),
        "ik_failure": np.asarray([a.ik_failed for a in attempts], bool),
    }


def run(args: argparse.Namespace) -> None:
    params = stage_params(args)
    g = params.generate
    if args.attempts is not None:
        if args.attempts < 1:
            raise InputError(f"--attempts {args.attempts}: expected a positive number")
        g = dataclasses.replace(g, mode="fixed_attempts", max_attempts=args.attempts)
        params = dataclasses.replace(params, generate=g)
    spec = envs.task_spec(params.backend, params.task)
    envs.check_variant(spec, args.variant)
    envs.check_robot(params.backend, g.robot)
    parsed_path = Path(args.parsed or layout.pose_noise_store(params.task))
    out = Path(args.out or layout.generated_store(params.task, args.variant))
    failed_out = layout.failed_store(out)
    metrics_path = Path(args.metrics or layout.metrics_file("generate", params.task, args.variant))
    claim(out, failed_out, metrics_path)  # one run per output set; fails at once if taken
    store = read_store(
        parsed_path,
        required=["target_pose", "gripper"] + [f"object_poses/{o}" for o in spec.objects],
        task=params.task,
        kind="parsed",
        required_episodes=["subtask_term_index"],
    )
    pose_noise = pose_noise_level(params.pose_noise.level)
    check_store_noise(store.attrs, pose_noise, params.pose_noise.seed, parsed_path)
    config = GenerationConfig(
        g.action_noise, g.n_interp, g.n_fixed, g.selection, g.nn_k, g.per_subtask, pose_noise
    )
    job = AttemptJob(
        make_env=functools.partial(envs.make_env, params.backend, params.task, g.robot),
        sources=source_demos(store, spec.objects),
        spec=spec,
        config=config,
        variant=args.variant,
    )
    seeds = [attempt_seed(g.seed, args.variant, i) for i in range(g.max_attempts)]
    env = job.make_env()
    scenes = reachable_scenes(env, job.sources, spec, args.variant, seeds[:WORKSPACE_SCENES])
    env.close()
    if scenes == 0:
        raise InputError(
            f"robot {g.robot!r} cannot reach the {args.variant} workspace of {params.task}: in "
            f"none of {WORKSPACE_SCENES} sampled scenes does it have IK solutions for the "
            "source demo's segments. Nothing was generated."
        )
    # the same id for the same data-shaping params and input, whatever the worker count, so
    # that the stores stay byte-identical; readers check that kept, failed and metrics agree
    run = run_id(
        {"task": params.task, "variant": args.variant, "backend": params.backend}
        | data_params(params, "generate"),
        store_digest(store),
    )
    # finished blocks of this run go to a work directory beside the output as they come
    # back; a killed run started again with the same params, input and code resumes there
    work = WorkDir.open(out, f"{run}/{ATTEMPTS_PER_BLOCK}/{code_digest('mimicgen_pipe', 'envs')}")
    if work.resumed:
        print(f"generate: resuming: {len(work.resumed)} finished blocks of attempts in {work.path}")
    guarantee = g.mode == "guarantee"
    kept, failed, rows = [], [], []
    t0 = time.perf_counter()
    total = g.num_demos if guarantee else g.max_attempts
    bar = tqdm(
        total=total,
        desc=f"generate {params.task} {args.variant}",
        unit="demo" if guarantee else "attempt",
    )
    results = run_attempts(job, seeds, stage_executor(params, "generate"), work)
    try:
        if not (guarantee and g.num_demos == 0):
            for seed, attempt, seconds in results:
                rows.append(
                    (seed, attempt.success, attempt.failed_subtask, seconds, attempt.ik_failed)
                )
                if len(rows) == IK_ABORT_AFTER and all(r[4] for r in rows):
                    raise RuntimeError(
                        f"generate: all of the first {IK_ABORT_AFTER} attempts failed at IK "
                        f"(robot {g.robot!r} cannot reach the targets); nothing was written"
                    )
                (kept if attempt.success else failed).append(attempt)
                bar.update(1 if (attempt.success or not guarantee) else 0)
                bar.set_postfix(attempts=len(rows), dgr=f"{100 * len(kept) / len(rows):.1f}%")
                if guarantee and len(kept) == g.num_demos:
                    break
    except Interrupted as exc:
        exc.detail = (
            f"after {len(rows)} attempts ({len(kept)} of {g.num_demos} demos)"
            if guarantee
            else f"after {len(rows)} of {g.max_attempts} attempts"
        ) + f"; finished blocks kept in {work.path} (the same command resumes)"
        raise
    finally:
        results.close()
        bar.close()
    wall = time.perf_counter() - t0
    if guarantee and len(kept) < g.num_demos:
        raise RuntimeError(
            f"generate: {len(kept)} of {g.num_demos} demos after generate.max_attempts="
            f"{g.max_attempts} attempts (DGR {100 * len(kept) / max(1, len(rows)):.1f}%); "
            "raise max_attempts or check the source demos. Nothing was written."
        )
    attrs = {
        "run_id": run,
        "task": params.task,
        "variant": args.variant,
        "backend": params.backend,
        "robot": g.robot,
        "source_robot": store.attrs.get("robot"),
        "control_mode": store.attrs.get("control_mode"),
        "control_freq": store.attrs.get("control_freq"),
        "objects": list(spec.objects),
        "subtasks": [s.name for s in spec.subtasks],
        "params": data_params(params, "generate"),
    }
    # an attempt stopped at IK before its first step has no steps to keep; it is counted in
    # the metrics only
    failed = [a for a in failed if len(a.steps)]
    success = np.array([r[1] for r in rows], bool)
    metrics = generation_metrics(
        success,
        np.array([r[2] for r in rows]),
        np.array([r[3] for r in rows]),
        [s.name for s in spec.subtasks],
        np.array([r[4] for r in rows], bool),
    )
    metrics.update(
        wall_seconds=wall, steps=int(sum(len(a.steps["actions"]) for a in kept + failed))
    )
    # written aside, then renamed failed store, metrics, kept store: a reader that finds the
    # new kept store finds the rest of its run beside it
    with output_set(failed_out, metrics_path, out) as (tmp_failed, tmp_metrics, tmp_out):
        for attempts, path, kind in ((kept, tmp_out, "generated"), (failed, tmp_failed, "failed")):
            steps = [a.steps for a in attempts]
            write_store(path, kind, steps, episode_fields(attempts, spec), attrs)
        write_metrics(tmp_metrics, {"run_id": run, **metrics})
    work.remove()
    print(
        f"generate: {metrics['successes']}/{metrics['attempts']} attempts succeeded "
        f"(DGR {metrics['dgr']:.1f}%, {metrics['ik_failures']} IK failures, "
        f"median {metrics['seconds_per_attempt_median']:.3f} s/attempt)"
        f" -> {out}"
    )
