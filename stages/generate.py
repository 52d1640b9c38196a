"""generate: MimicGen data generation for one reset variant."""

from __future__ import annotations

import argparse
import dataclasses
import functools
from pathlib import Path

from tqdm import tqdm

import envs
from mimicgen_pipe import layout
from mimicgen_pipe.errors import InputError
from mimicgen_pipe.generation import Attempt, GenerationConfig
from mimicgen_pipe.metrics import write_metrics
from mimicgen_pipe.outputs import claim, output_set, run_id, store_digest, store_kind
from mimicgen_pipe.params import data_params, range_error, stage_executor
from mimicgen_pipe.pose_noise import check_store_noise, pose_noise_level
from mimicgen_pipe.resume import WorkDir, code_digest
from mimicgen_pipe.runner import (
    ATTEMPTS_PER_BLOCK,
    AttemptBlockCodec,
    AttemptJob,
    AttemptSeeds,
    check_workspace,
    episode_fields,
    generate,
    source_demos,
)
from mimicgen_pipe.store import read_store, write_store
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
    p.add_argument(
        "--action-noise",
        type=float,
        help="sigma of the action noise, in place of generate.action_noise (the suite's own)",
    )


def run(args: argparse.Namespace) -> None:
    params = stage_params(args)
    g = params.generate
    # the options stand in for params keys, and are held to the same ranges
    for flag, key, value in (
        ("--attempts", "generate.max_attempts", args.attempts),
        ("--action-noise", "generate.action_noise", args.action_noise),
    ):
        why = range_error(key, value) if value is not None else None
        if why:
            raise InputError(f"{flag} {value}: {why}")
    if args.attempts is not None:
        g = dataclasses.replace(g, mode="fixed_attempts", max_attempts=args.attempts)
        params = dataclasses.replace(params, generate=g)
    if args.action_noise is not None:
        g = dataclasses.replace(g, action_noise=args.action_noise)
        params = dataclasses.replace(params, generate=g)
    spec = envs.task_spec(params.backend, params.task)
    envs.check_variant(spec, args.variant)
    sigma = spec.action_noise(g.action_noise)
    if sigma != g.action_noise:
        print(
            f"generate: action noise sigma {sigma}, not {g.action_noise}: "
            f"{params.task}'s max_action_noise (its task file)"
        )
        g = dataclasses.replace(g, action_noise=sigma)
        params = dataclasses.replace(params, generate=g)
    envs.check_robot(params.backend, g.robot)
    executor = stage_executor(params, "generate")  # refuses unsafe Ray settings before any work
    parsed_path = Path(args.parsed or layout.pose_noise_store(params.task))
    out = Path(args.out or layout.generated_store(params.task, args.variant))
    failed_out = layout.failed_store(out)
    metrics_path = Path(args.metrics or layout.metrics_file("generate", params.task, args.variant))
    # one run per output set (fails at once if taken); never over an input or anything else
    claim(
        (out, store_kind("generated")),
        (failed_out, store_kind("failed")),
        metrics_path,
        inputs=[parsed_path],
    )
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
        make_env=functools.partial(
            envs.make_env, params.backend, params.task, g.robot, params.maniskill.fast_step
        ),
        sources=source_demos(store, spec.objects),
        spec=spec,
        config=config,
        variant=args.variant,
    )
    seeds = AttemptSeeds(g.seed, args.variant, g.max_attempts)  # each computed when needed
    check_workspace(job, seeds, g.robot)
    # the same id for the same data-shaping params and input, whatever the worker count, so
    # that the stores stay byte-identical; readers check that kept, failed and metrics agree
    run = run_id(
        {"task": params.task, "variant": args.variant, "backend": params.backend}
        | data_params(params, "generate"),
        store_digest(store),
    )
    # finished blocks of this run go to a work directory beside the output as they come
    # back; a killed run started again with the same params, input and code resumes there
    work = WorkDir.open(
        out,
        f"{run}/{ATTEMPTS_PER_BLOCK}/{code_digest('mimicgen_pipe', 'envs')}",
        AttemptBlockCodec(seeds),
    )
    for line in work.discarded:
        print(f"generate: {line}")
    if work.resumed:
        print(f"generate: resuming: {len(work.resumed)} finished blocks of attempts in {work.path}")
    guarantee = g.mode == "guarantee"
    bar = tqdm(
        total=g.num_demos if guarantee else g.max_attempts,
        desc=f"generate {params.task} {args.variant}",
        unit="demo" if guarantee else "attempt",
    )

    def progress(attempt: Attempt, attempts: int, kept: int) -> None:
        bar.update(1 if (attempt.success or not guarantee) else 0)
        bar.set_postfix(attempts=attempts, dgr=f"{100 * kept / attempts:.1f}%")

    try:
        result = generate(
            job, seeds, executor, work, g.num_demos if guarantee else None, progress, g.robot
        )
    finally:
        bar.close()
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
    metrics = result.metrics
    # written aside, then renamed failed store, metrics, kept store: a reader that finds the
    # new kept store finds the rest of its run beside it
    with output_set(failed_out, metrics_path, out) as (tmp_failed, tmp_metrics, tmp_out):
        for attempts, path, kind in (
            (result.kept, tmp_out, "generated"),
            (result.failed, tmp_failed, "failed"),
        ):
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
