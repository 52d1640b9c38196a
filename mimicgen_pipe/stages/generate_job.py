"""A generate request resolved once: :func:`resolve` turns the generate stage's command line
and its params file into a :class:`GenerateJob`, frozen and fully checked, before any work
and before any output is claimed. The stage then claims the job's outputs, runs it and
writes it (mimicgen_pipe/stages/generate.py); nothing after :func:`resolve` reads params or the
command line again.

Every refusal of a generate run is raised here, one line naming what is wrong (InputError,
exit status 2), in this order:

1. the params file: keys, types, ranges, variant lists, obs keys, and --backend, --task,
   --robot (mimicgen_pipe.stages.stage_params);
2. the options --attempts, --num-demos, --max-attempts, --action-noise against their keys'
   ranges, and against each other (:func:`with_generate_options`);
3. the reset variant (backends.check_variant);
4. the robot (backends.check_robot), a planned transit (backends.check_transit), a batch of
   generate.num_envs scenes (:func:`batch_maker`, backends.check_batched) and the executor's
   settings (mimicgen_pipe.run.executors.Executor);
5. the parsed store: whole and sound (store.read_store), with the pose noise params ask for
   (pose_noise.check_store_noise), recorded on this back end with its controller and the
   task's objects (:func:`check_source_attrs`);
6. the workspace: the arm reaches the source segments in a few sampled scenes
   (runner.check_workspace; the one check that starts a simulator).

The job's type lives here, beside the one function that builds it: resolving needs the
back ends, which no layer below the stages imports. The runner takes the job's parts: its
:class:`~mimicgen_pipe.run.runner.AttemptJob` (what every worker is sent, picklable: no back-end
package in it), seeds, executor and counts.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mimicgen_pipe import backends
from mimicgen_pipe.core.contracts import Backend, BatchEnv
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.taskspec import TaskSpec, arm_key
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.metrics import GENERATE_PURPOSE, metrics_identity
from mimicgen_pipe.data.outputs import run_id, store_digest
from mimicgen_pipe.data.params import GenerateParams, Params, data_params, range_error
from mimicgen_pipe.data.store import EpisodeStore, read_store
from mimicgen_pipe.method.generation import GenerationConfig
from mimicgen_pipe.method.pose_noise import check_store_noise, pose_noise_level
from mimicgen_pipe.run.executors import Executor, stage_executor
from mimicgen_pipe.run.runner import AttemptJob, AttemptSeeds, check_workspace, source_demos
from mimicgen_pipe.stages import output_path, stage_params


@dataclass(frozen=True)
class GenerateJob:
    """One generate run, checked: ``variant`` of task ``spec`` on ``backend`` (the back end's
    package, contracts.Backend; ``backend_name`` its name in params), as ``generate`` says:
    the generate params in effect, the command line's options in place of their keys and
    action_noise capped at the task's max_action_noise, ``note`` the line that says so (None
    when uncapped). It reads the parsed store at ``parsed_path`` and writes the kept store
    ``out``, the failed store ``failed_out`` and the metrics JSON ``metrics_path``, under
    run id ``run_id``; ``attrs``, the kept and failed stores' attributes. ``attempts`` is
    what every worker of ``executor`` is sent (envs, batches, source demos, the engine's
    config); ``seeds`` the reset seeds of every attempt it may run, in order."""

    spec: TaskSpec
    backend_name: str
    backend: Backend
    variant: str
    generate: GenerateParams
    note: str | None
    parsed_path: Path
    out: Path
    failed_out: Path
    metrics_path: Path
    executor: Executor
    attempts: AttemptJob
    seeds: AttemptSeeds
    run_id: str
    attrs: Mapping[str, Any]

    @property
    def robot(self) -> str:
        """The arm generated with (generate.robot, or --robot)."""
        return self.generate.robot

    @property
    def config(self) -> GenerationConfig:
        """The generation engine's knobs, as every worker has them."""
        return self.attempts.config

    @property
    def make_batch(self) -> Callable[[], BatchEnv] | None:
        """What makes each worker's batch of generate.num_envs scenes; None: one attempt at a
        time on an env of ``attempts.make_env``."""
        return self.attempts.make_batch

    @property
    def num_demos(self) -> int | None:
        """Demos to keep (guarantee mode); None: every attempt of ``seeds`` (fixed_attempts)."""
        return self.generate.num_demos if self.generate.mode == "guarantee" else None

    @property
    def label(self) -> str:
        """The name of the run's progress bar."""
        return f"generate {self.spec.name} {self.variant}"

    @property
    def identity(self) -> dict[str, Any]:
        """The identity fields of its metrics file (mimicgen_pipe.data.metrics)."""
        return metrics_identity(
            "generate",
            self.spec.name,
            self.backend_name,
            self.robot,
            variant=self.variant,
            purpose=GENERATE_PURPOSE[self.generate.mode],
        )


def resolve(args: argparse.Namespace) -> GenerateJob:
    """The generate run that ``args`` (the stage's parsed command line) ask for, every check
    of the module's docstring done in its order; writes nothing."""
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
    }
