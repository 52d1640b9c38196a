"""generate: MimicGen data generation for one reset variant."""

from __future__ import annotations

import argparse
import dataclasses
import functools
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from mimicgen_pipe import backends
from mimicgen_pipe.core.contracts import BatchEnv
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.taskspec import TaskSpec, arm_key, check_task_version, version_record
from mimicgen_pipe.core.transit import TRANSITS
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.metrics import split_timings, write_metrics, write_timings
from mimicgen_pipe.data.outputs import claim, output_set, run_id, store_digest, store_kind
from mimicgen_pipe.data.params import Params, data_params, range_error
from mimicgen_pipe.data.store import EpisodeStore, read_store
from mimicgen_pipe.method.generation import GenerationConfig
from mimicgen_pipe.method.pose_noise import check_store_noise, pose_noise_level
from mimicgen_pipe.run.executors import stage_executor
from mimicgen_pipe.run.runner import (
    AttemptJob,
    AttemptSeeds,
    GenerateJob,
    check_workspace,
    generate,
    open_work_dir,
    source_demos,
    write_generated,
)
from mimicgen_pipe.stages import add_selection_arguments, output_path, stage_params


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p, robot=True)
    p.add_argument("--variant", required=True, help="reset variant, e.g. D0 or D1")
    p.add_argument(
        "--parsed",
        help="parsed source store as the pose_noise stage wrote it (default: "
        "data/pose_noise/<task>.zarr, or data/parsed/<task>.zarr in a pipeline without a "
        "pose_noise stage); a clean parsed store is accepted at level none",
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
    p.add_argument(
        "--num-demos",
        type=int,
        help="run until this many attempts succeed (guarantee mode, capped by "
        "generate.max_attempts), whatever generate.mode and num_demos say",
    )
    p.add_argument(
        "--max-attempts",
        type=int,
        help="most attempts before guarantee mode gives up, in place of generate.max_attempts",
    )
    p.add_argument(
        "--transit",
        choices=TRANSITS,
        help="linear or planned transit, in place of generate.transit",
    )


def resolve(args: argparse.Namespace) -> GenerateJob:
    """The generate run that ``args`` (the stage's parsed command line) and its params file
    ask for, frozen and fully checked, before any work and before any output is claimed;
    nothing after this reads params or the command line again. Every refusal is raised
    here, one line naming what is wrong (InputError, exit status 2), in this order:

    1. the params file: keys, types, ranges, variant lists, obs keys, and --backend, --task,
       --robot (mimicgen_pipe.stages.stage_params);
    2. the options --attempts, --num-demos, --max-attempts, --action-noise against their
       keys' ranges, and against each other (:func:`with_generate_options`);
    3. the reset variant (backends.check_variant);
    4. the robot (backends.check_robot), a planned transit (backends.check_transit), a batch
       of generate.num_envs scenes (:func:`batch_maker`, backends.check_batched) and the
       executor's settings (mimicgen_pipe.run.executors.Executor);
    5. the parsed store: whole and sound (store.read_store), with the pose noise params ask
       for (pose_noise.check_store_noise), recorded on this back end with its controller
       and the task's objects (:func:`check_source_attrs`);
    6. the workspace: the arm reaches the source segments in a few sampled scenes
       (runner.check_workspace; the one check that starts a simulator)."""
    params, spec, note = generate_params(args)
    g = params.generate
    backends.check_robot(params.backend, g.robot)
    backends.check_transit(params.backend, g.robot, g.transit, len(spec.arms))
    make_batch = batch_maker(params)  # refuses a batch it cannot run
    executor = stage_executor(params, "generate")  # refuses unsafe Ray settings
    parsed_path = Path(args.parsed or layout.generate_input(params.task))
    out = output_path(args.out, layout.generated_store(params.task, args.variant))
    metrics_path = output_path(
        args.metrics, layout.metrics_file("generate", params.task, args.variant)
    )
    backend = backends.backend_package(params.backend)
    store = parsed_store(params, spec, parsed_path)
    check_source_attrs(store.attrs, parsed_path, params.backend, spec, backend.CONTROL)
    make_env = functools.partial(
        backends.make_env, params.backend, params.task, g.robot, params.maniskill.lean_step
    )
    sources = source_demos(store, spec.objects, spec.arms)
    config = generation_config(params)
    attempts = AttemptJob(make_env, sources, spec, config, args.variant, make_batch, g.num_envs)
    seeds = AttemptSeeds(g.seed, args.variant, g.max_attempts)  # each computed when needed
    check_workspace(attempts, seeds, g.robot)
    run = generation_run_id(params, args.variant, store)
    return GenerateJob(
        spec=spec,
        backend_name=params.backend,
        backend=backend,
        variant=args.variant,
        generate=g,
        note=note,
        parsed_path=parsed_path,
        out=out,
        failed_out=layout.failed_store(out),
        metrics_path=metrics_path,
        executor=executor,
        attempts=attempts,
        seeds=seeds,
        run_id=run,
        attrs=generated_attrs(run, params, args.variant, spec, store.attrs),
    )


def run(job: GenerateJob) -> None:
    if job.note is not None:
        print(f"generate: {job.note}")
    # one run per output set (fails at once if taken); never over an input or anything else
    claim(
        (job.out, store_kind("generated")),
        (job.failed_out, store_kind("failed")),
        job.metrics_path,
        inputs=[job.parsed_path],
    )
    work = open_work_dir(job.out, job.run_id, job.seeds, job.attempts.block_size)
    result = generate(job, work)
    # written aside, then renamed failed store, metrics, kept store: a reader that finds the
    # new kept store finds the rest of its run beside it
    outs = (job.failed_out, job.metrics_path, job.out)
    identity = job.identity | {"run_id": job.run_id} | version_record(job.spec)
    metrics, timings = split_timings(result.metrics)
    with output_set(*outs) as (tmp_failed, tmp_metrics, tmp_out):
        write_generated(tmp_out, tmp_failed, result, job.spec, job.attrs)
        write_metrics(tmp_metrics, identity | metrics)
    work.remove()
    write_timings(job.metrics_path, identity, timings)
    print(
        f"generate: {metrics['successes']}/{metrics['attempts']} attempts succeeded "
        f"(DGR {metrics['dgr']:.1f}%, {metrics['ik_failures']} IK failures, "
        f"median {timings['seconds_per_attempt_median']:.3f} s/attempt)"
        f" -> {job.out}"
    )


def generate_params(args: argparse.Namespace) -> tuple[Params, TaskSpec, str | None]:
    """The params a generate run goes by: the params file with the command line's options in
    place of the keys they stand for, each held to its key's range, and the action noise
    capped at the task's; the task's spec, with the reset variant checked; and the line
    that says the cap (None when uncapped)."""
    options = (args.attempts, args.action_noise, args.transit, args.num_demos, args.max_attempts)
    params = with_generate_options(stage_params(args), *options)
    spec = backends.task_spec(params.backend, params.task)
    backends.check_variant(spec, args.variant)
    params, note = capped_action_noise(params, spec)
    return params, spec, note


def with_generate_options(
    params: Params,
    attempts: int | None,
    action_noise: float | None,
    transit: str | None = None,
    num_demos: int | None = None,
    max_attempts: int | None = None,
) -> Params:
    """``params`` with the generate stage's options in place of the keys they stand for:
    ``attempts``, exactly that many attempts (generate.mode fixed_attempts, max_attempts);
    ``action_noise``, generate.action_noise; ``transit``, generate.transit; ``num_demos``,
    until that many succeed (generate.mode guarantee, num_demos); ``max_attempts``, the
    cap of guarantee mode (generate.max_attempts). Each is held to its key's range:
    InputError naming the option otherwise."""
    g = params.generate
    if attempts is not None and num_demos is not None:
        raise InputError("--attempts and --num-demos: one of them (fixed attempts or demos)")
    if attempts is not None and max_attempts is not None:
        raise InputError("--attempts and --max-attempts: one of them (--attempts is the count)")
    for flag, key, value in (
        ("--attempts", "generate.max_attempts", attempts),
        ("--action-noise", "generate.action_noise", action_noise),
        ("--num-demos", "generate.num_demos", num_demos),
        ("--max-attempts", "generate.max_attempts", max_attempts),
    ):
        why = range_error(key, value) if value is not None else None
        if why:
            raise InputError(f"{flag} {value}: {why}")
    if attempts is not None:
        g = dataclasses.replace(g, mode="fixed_attempts", max_attempts=attempts)
    if action_noise is not None:
        g = dataclasses.replace(g, action_noise=action_noise)
    if transit is not None:
        g = dataclasses.replace(g, transit=transit)
    if num_demos is not None:
        g = dataclasses.replace(g, mode="guarantee", num_demos=num_demos)
    if max_attempts is not None:
        g = dataclasses.replace(g, max_attempts=max_attempts)
    return dataclasses.replace(params, generate=g)


def capped_action_noise(params: Params, spec: TaskSpec) -> tuple[Params, str | None]:
    """``params`` with generate.action_noise capped at the task's max_action_noise (its task
    file), and a line saying so (None when the noise is within it)."""
    g = params.generate
    sigma = spec.action_noise(g.action_noise)
    if sigma == g.action_noise:
        return params, None
    note = (
        f"action noise sigma {sigma}, not {g.action_noise}: "
        f"{params.task}'s max_action_noise (its task file)"
    )
    return dataclasses.replace(params, generate=dataclasses.replace(g, action_noise=sigma)), note


def batch_maker(params: Params) -> Callable[[], BatchEnv] | None:
    """What makes each generate worker's batch of generate.num_envs scenes, checked
    (backends.check_batched) before any work; None to run one attempt at a time (one scene, and
    no GPU simulation asked for: maniskill.sim_backend physx_cpu)."""
    g = params.generate
    sim_backend = params.maniskill.sim_backend if params.backend == "maniskill" else None
    if g.num_envs == 1 and sim_backend != "physx_cuda":
        return None
    backends.check_batched(params.backend, params.task, g.robot, g.num_envs, sim_backend, g.transit)
    return functools.partial(
        backends.make_batch_env, params.backend, params.task, g.robot, g.num_envs, sim_backend
    )


def parsed_store(params: Params, spec: TaskSpec, path: Path) -> EpisodeStore:
    """The parsed source demos at ``path``, read whole and checked: the arrays the generator
    reads for ``spec``'s arms and objects, and the pose noise params ask for."""
    store = read_store(
        path,
        required=[arm_key(k, a) for k in ("target_pose", "gripper") for a in spec.arms]
        + [f"object_poses/{o}" for o in spec.objects],
        task=params.task,
        kind="parsed",
        required_episodes=["subtask_term_index"],
    )
    noise = pose_noise_level(params.pose_noise.level)
    check_store_noise(store.attrs, noise, params.pose_noise.seed, path)
    return store


def check_source_attrs(
    attrs: Mapping[str, Any], path: Path, backend: str, spec: TaskSpec, control: tuple[str, int]
) -> None:
    """InputError naming the store and attribute where the parsed store at ``path`` was not
    recorded on ``backend`` with its ``control`` (mode, rate [Hz]), ``spec``'s objects and
    one of the back end's robots: these attributes shape the data, and the generated store
    records them."""
    expected = {
        "backend": backend,
        "control_mode": control[0],
        "control_freq": control[1],
        "objects": list(spec.objects),
    }
    for key, want in expected.items():
        if attrs.get(key) != want:
            raise InputError(
                f"{path}: attrs.{key} is {attrs.get(key)!r}, expected {want!r} (its demos were "
                f"not recorded for {spec.name} on {backend}; re-run the stages that made it)"
            )
    check_task_version(attrs, spec, str(path))
    robot = attrs.get("robot")  # recorded as the generated stores' source_robot
    known = backends.backend_package(backend).ROBOTS
    if not isinstance(robot, str) or robot not in known:
        raise InputError(
            f"{path}: attrs.robot is {robot!r}, expected a robot of {backend} "
            f"({', '.join(known)}); re-run the stages that made it"
        )


def generation_config(params: Params) -> GenerationConfig:
    """The generation engine's knobs from the generate and pose_noise params."""
    g = params.generate
    return GenerationConfig(
        g.action_noise,
        g.n_interp,
        g.n_fixed,
        g.selection,
        g.nn_k,
        g.per_subtask,
        pose_noise_level(params.pose_noise.level),
        g.transit,
        g.planner,
    )


def generation_run_id(params: Params, variant: str, store: EpisodeStore) -> str:
    """The id of a generate run: the same for the same data-shaping params and parsed
    ``store``, whatever the worker count, so that the stores stay byte-identical; readers
    check that kept, failed and metrics agree."""
    return run_id(
        {"task": params.task, "variant": variant, "backend": params.backend}
        | data_params(params, "generate"),
        store_digest(store),
    )


def generated_attrs(
    run: str, params: Params, variant: str, spec: TaskSpec, source_attrs: Mapping[str, Any]
) -> dict[str, Any]:
    """The attributes of a generate run's kept and failed stores: run ``run`` of ``variant``
    as ``params`` say, from source demos whose store has ``source_attrs``."""
    return {
        "run_id": run,
        "task": params.task,
        "variant": variant,
        "backend": params.backend,
        "robot": params.generate.robot,
        "source_robot": source_attrs.get("robot"),
        "control_mode": source_attrs.get("control_mode"),
        "control_freq": source_attrs.get("control_freq"),
        "objects": list(spec.objects),
        "subtasks": [s.name for s in spec.subtasks],
        "params": data_params(params, "generate"),
        **version_record(spec),
    }
