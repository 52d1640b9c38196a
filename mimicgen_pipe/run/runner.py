"""Running many generation attempts, on any executor (mimicgen_pipe.run.executors): a generate
run (``GenerateJob``), what every worker is sent (``AttemptJob``), the loop (``generate``),
and what it writes (``write_generated``). The generate stage resolves its request into a
job, checked, once (mimicgen_pipe.stages.generate.resolve); nothing here reads params or the
command line.

Every attempt's seed is derived from (stage seed, variant, attempt index), and results are
consumed in attempt order. A simulator carries history from one episode to the next (PhysX
keeps contact caches across resets), so attempts run in fixed blocks of
``ATTEMPTS_PER_BLOCK``, each on a freshly rebuilt scene: the dataset is then the same on one
worker or many, whichever worker runs a block. A worker with a batch of N scenes
(generate.num_envs, mimicgen_pipe.method.batched) runs blocks of N times as many, its slots in
lockstep.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast, overload

import numpy as np
from tqdm import tqdm

from mimicgen_pipe.core.contracts import Backend, BatchEnv, Env
from mimicgen_pipe.core.errors import InputError, StageError
from mimicgen_pipe.core.interrupts import Interrupted
from mimicgen_pipe.core.taskspec import ARM, TaskSpec, arm_key
from mimicgen_pipe.data.metrics import GENERATE_PURPOSE, generation_metrics, metrics_identity
from mimicgen_pipe.data.store import EpisodeStore, write_store
from mimicgen_pipe.method.batched import run_batched
from mimicgen_pipe.method.generation import (
    Attempt,
    GenerationConfig,
    SourceDemos,
    reachable_scenes,
    run_attempt,
)
from mimicgen_pipe.run.executors import Executor, map_blocks
from mimicgen_pipe.run.resume import BadBlock, WorkDir, code_digest

if TYPE_CHECKING:  # a job holds the generate params; the runner reads no params file
    from mimicgen_pipe.data.params import GenerateParams

ATTEMPTS_PER_BLOCK = 16  # rebuilding a ManiSkill scene costs ~0.1 s, ~3% of a block


def attempt_seed(seed: int, variant: str, attempt: int) -> int:
    """A reset seed for one attempt, in [0, 2**30): simulators take int32 seeds, and
    [2**30, 2**31) is kept for policy evaluation (mimicgen_pipe.learn.evaluation)."""
    ss = np.random.SeedSequence([seed, int.from_bytes(variant.encode(), "little"), attempt])
    return int(ss.generate_state(1, np.uint32)[0] & 0x3FFFFFFF)


class AttemptSeeds(Sequence[int]):
    """The reset seeds of attempts 0 .. ``count`` - 1 (:func:`attempt_seed`), each computed
    when read: a run may allow millions of attempts and stop after a few hundred, and holds
    none of them up front (``list(seeds)`` is the eager list)."""

    def __init__(self, seed: int, variant: str, count: int) -> None:
        self.seed, self.variant, self.count = seed, variant, count

    def __len__(self) -> int:
        return self.count

    @overload
    def __getitem__(self, i: int) -> int: ...

    @overload
    def __getitem__(self, i: slice) -> list[int]: ...

    def __getitem__(self, i: int | slice) -> int | list[int]:
        if isinstance(i, slice):
            return [attempt_seed(self.seed, self.variant, k) for k in range(self.count)[i]]
        return attempt_seed(self.seed, self.variant, range(self.count)[i])

    def __iter__(self) -> Iterator[int]:
        return (attempt_seed(self.seed, self.variant, k) for k in range(self.count))

    def __repr__(self) -> str:
        return f"AttemptSeeds({self.seed}, {self.variant!r}, {self.count})"


@dataclass(frozen=True)
class AttemptJob:
    """Everything a worker needs, sent once per worker. make_batch: the worker's batch of
    ``num_envs`` scenes (the back end's batched form), None to run one attempt at a time on
    an env from make_env (which also checks the workspace before any work)."""

    make_env: Callable[[], Env]
    sources: SourceDemos
    spec: TaskSpec
    config: GenerationConfig
    variant: str
    make_batch: Callable[[], BatchEnv] | None = None
    num_envs: int = 1

    @property
    def block_size(self) -> int:
        """Attempts per block: ATTEMPTS_PER_BLOCK for each scene a worker steps."""
        return ATTEMPTS_PER_BLOCK * self.num_envs


@dataclass(frozen=True)
class GenerateJob:
    """One generate run, checked (mimicgen_pipe.stages.generate.resolve): ``variant`` of task
    ``spec`` on ``backend`` (the back end's package, contracts.Backend; ``backend_name`` its
    name in params), as ``generate`` says: the generate params in effect, the command line's
    options in place of their keys and action_noise capped at the task's max_action_noise,
    ``note`` the line that says so (None when uncapped). It reads the parsed store at
    ``parsed_path`` and writes the kept store ``out``, the failed store ``failed_out`` and
    the metrics JSON ``metrics_path``, under run id ``run_id``; ``attrs``, the kept and
    failed stores' attributes. ``attempts`` is what every worker of ``executor`` is sent
    (envs, batches, source demos, the engine's config); ``seeds`` the reset seeds of every
    attempt it may run, in order."""

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


def open_work_dir(
    out: Path, run: str, seeds: Sequence[int], block_size: int = ATTEMPTS_PER_BLOCK
) -> WorkDir:
    """The work directory beside the output ``out`` where run ``run``'s finished blocks of
    ``block_size`` attempts go as they come back; a killed run started again with the same
    params, input and code resumes there. Says what it discarded and what it resumes."""
    work = WorkDir.open(
        out,
        f"{run}/{block_size}/{code_digest('mimicgen_pipe')}",
        AttemptBlockCodec(seeds, block_size),
    )
    for line in work.discarded:
        print(f"generate: {line}")
    if work.resumed:
        print(f"generate: resuming: {len(work.resumed)} finished blocks of attempts in {work.path}")
    return work


BlockResult = list[tuple[int, Attempt, float]]  # a block's (seed, attempt, seconds)
_WORKER: tuple[AttemptJob, Env | BatchEnv] | None = None


def _init_worker(job: AttemptJob) -> None:
    global _WORKER
    _WORKER = (job, job.make_batch() if job.make_batch else job.make_env())


def _run_block(seeds: list[int]) -> BlockResult:
    """Attempts of one block, on a freshly rebuilt scene; seconds include the rebuild share
    (on a batch, each attempt's seconds are the block's over its attempts)."""
    assert _WORKER is not None
    job, env = _WORKER
    t0 = time.perf_counter()
    env.rebuild()
    if job.make_batch is not None:
        batch = cast(BatchEnv, env)
        ended = dict(run_batched(batch, job.sources, job.spec, job.config, job.variant, seeds))
        seconds = (time.perf_counter() - t0) / max(1, len(seeds))
        return [(seed, ended[i], seconds) for i, seed in enumerate(seeds)]
    env = cast(Env, env)
    share = (time.perf_counter() - t0) / max(1, len(seeds))
    out = []
    for seed in seeds:
        t0 = time.perf_counter()
        attempt = run_attempt(env, job.sources, job.spec, job.config, job.variant, seed)
        out.append((seed, attempt, time.perf_counter() - t0 + share))
    return out


class AttemptBlocks(Sequence[list[int]]):
    """The fixed blocks of ``seeds`` the attempts run in, ``size`` each (a resumed run must
    cut them the same way); a block's seeds are read from ``seeds`` when the block is."""

    def __init__(self, seeds: Sequence[int], size: int = ATTEMPTS_PER_BLOCK) -> None:
        self.seeds, self.size = seeds, size

    def __len__(self) -> int:
        return -(-len(self.seeds) // self.size)

    @overload
    def __getitem__(self, i: int) -> list[int]: ...

    @overload
    def __getitem__(self, i: slice) -> list[list[int]]: ...

    def __getitem__(self, i: int | slice) -> list[int] | list[list[int]]:
        if isinstance(i, slice):
            return [self[k] for k in range(len(self))[i]]
        start = range(len(self))[i] * self.size
        return list(self.seeds[start : start + self.size])

    def __iter__(self) -> Iterator[list[int]]:
        return (self[k] for k in range(len(self)))


def attempt_blocks(seeds: Sequence[int], size: int = ATTEMPTS_PER_BLOCK) -> AttemptBlocks:
    """The fixed blocks the attempts run in (a resumed run must cut them the same way)."""
    return AttemptBlocks(seeds, size)


class AttemptBlockCodec:
    """A block's results (seed, attempt, seconds) as the plain arrays a work directory keeps
    (mimicgen_pipe.run.resume), and back, exactly: dtypes, shapes, the order of each attempt's
    step arrays, Python scalars. A block's arrays are accepted only for the block index
    whose seeds they hold (``attempt_blocks(seeds)[index]``)."""

    # per-attempt scalars, stored as one (n,) array each: name -> (dtype, Python type)
    SCALARS = {
        "seed": (np.int64, int),
        "seconds": (np.float64, float),
        "success": (np.bool_, bool),
        "failed_subtask": (np.int64, int),
        "ik_failed": (np.bool_, bool),
        "planner_failed": (np.bool_, bool),
    }
    ARRAYS = ("source_demo", "initial_state", "initial_object_poses")  # per attempt, as is

    def __init__(self, seeds: Sequence[int], block_size: int = ATTEMPTS_PER_BLOCK) -> None:
        self.blocks = attempt_blocks(seeds, block_size)

    def encode(self, index: int, result: BlockResult) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        columns: dict[str, list] = {name: [] for name in self.SCALARS}
        for k, (seed, attempt, seconds) in enumerate(result):
            if attempt.seed != seed:
                raise ValueError(f"attempt {k} of block {index}: seed {attempt.seed} != {seed}")
            row = (
                seed,
                seconds,
                attempt.success,
                attempt.failed_subtask,
                attempt.ik_failed,
                attempt.planner_failed,
            )
            for name, value in zip(self.SCALARS, row, strict=True):
                columns[name].append(value)
            for name in self.ARRAYS:
                out[f"{k}/{name}"] = np.asarray(getattr(attempt, name))
            # step arrays by position: their names (obs/..., object_poses/...) stay data
            out[f"{k}/step_keys"] = np.array(list(attempt.steps), dtype=np.str_)
            for j, value in enumerate(attempt.steps.values()):
                out[f"{k}/steps/{j}"] = np.asarray(value)
        for name, (dtype, _) in self.SCALARS.items():
            out[name] = np.array(columns[name], dtype=dtype)
        return out

    def decode(self, index: int, arrays: Mapping[str, np.ndarray]) -> BlockResult:
        if not 0 <= index < len(self.blocks):
            raise BadBlock(f"no block {index} in a run of {len(self.blocks)} blocks")
        seeds = self.blocks[index]
        n = len(seeds)
        for name, (dtype, _) in self.SCALARS.items():
            a = arrays[name]
            if a.dtype != dtype or a.shape != (n,):
                raise BadBlock(f"{name}: {a.dtype} {a.shape}, expected {np.dtype(dtype)} ({n},)")
        if arrays["seed"].tolist() != seeds:
            raise BadBlock(f"holds other seeds than block {index}'s")
        out = []
        for k in range(n):
            scalars = {name: cast(arrays[name][k]) for name, (_, cast) in self.SCALARS.items()}
            keys = arrays[f"{k}/step_keys"]
            if keys.dtype.kind != "U" or keys.ndim != 1:
                raise BadBlock(f"{k}/step_keys: {keys.dtype} {keys.shape}")
            steps = {str(key): arrays[f"{k}/steps/{j}"] for j, key in enumerate(keys)}
            attempt = Attempt(
                seed=scalars["seed"],
                steps=steps,
                success=scalars["success"],
                failed_subtask=scalars["failed_subtask"],
                ik_failed=scalars["ik_failed"],
                planner_failed=scalars["planner_failed"],
                **{name: arrays[f"{k}/{name}"] for name in self.ARRAYS},
            )
            out.append((scalars["seed"], attempt, scalars["seconds"]))
        return out


def run_attempts(
    job: AttemptJob, seeds: Sequence[int], executor: Executor, work: WorkDir | None = None
) -> Iterator[tuple[int, Attempt, float]]:
    """Yield (seed, attempt, seconds) in the order of ``seeds``; with ``work`` (opened with
    an :class:`AttemptBlockCodec` of the same seeds), finished blocks are saved there and
    those an earlier run saved are reused. Stop consuming to stop early: the workers are
    gone when the generator is closed (or an exception, such as an interrupt, goes through
    it)."""
    blocks = attempt_blocks(seeds, job.block_size)
    results = map_blocks(_run_block, blocks, executor, _init_worker, (job,), work)
    try:
        for block in results:
            yield from block
    finally:
        results.close()


IK_ABORT_AFTER = 50  # stop when this many attempts in a row, from the first, all failed at IK


@dataclass
class GenerationResult:
    """A generation run: kept (successful) and failed attempts in attempt order (failed ones
    stopped at IK before their first step have no steps and are left out), and its metrics
    (mimicgen_pipe.data.metrics.generation_metrics plus wall_seconds and steps)."""

    kept: list[Attempt]
    failed: list[Attempt]
    metrics: dict


@dataclass
class AttemptTally:
    """A run's attempts so far, in attempt order: kept (successful) and failed ones, and a
    row per attempt: success, failed subtask, seconds, IK failure, planner failure."""

    kept: list[Attempt] = dataclasses.field(default_factory=list)
    failed: list[Attempt] = dataclasses.field(default_factory=list)
    rows: list[tuple[bool, int, float, bool, bool]] = dataclasses.field(default_factory=list)


def generate(job: GenerateJob, work: WorkDir | None = None) -> GenerationResult:
    """Run the job's attempts from its seeds in order: all of them, or (its ``num_demos``,
    the paper's guarantee mode) until that many have succeeded, under a progress bar of the
    demos (guarantee mode) or attempts; with ``work`` (:func:`open_work_dir`), finished
    blocks are saved there and those an earlier run saved are reused.

    Raises InputError when the first IK_ABORT_AFTER attempts all failed at IK (the arm
    cannot reach the task) or when the seeds run out before ``num_demos`` successes; an
    Interrupted on the way up says how far the run got."""
    seeds, num_demos = job.seeds, job.num_demos
    tally = AttemptTally()
    bar = attempts_bar(
        len(seeds) if num_demos is None else num_demos,
        "attempt" if num_demos is None else "demo",
        job.label,
    )
    t0 = time.perf_counter()
    results = run_attempts(job.attempts, seeds, job.executor, work)
    try:
        if num_demos != 0:
            take_attempts(results, tally, bar, num_demos, job.robot)
    except Interrupted as exc:
        exc.detail = (
            f"after {len(tally.rows)} of {len(seeds)} attempts"
            if num_demos is None
            else f"after {len(tally.rows)} attempts ({len(tally.kept)} of {num_demos} demos)"
        )
        if work is not None:
            exc.detail += f"; finished blocks kept in {work.path} (the same command resumes)"
        raise
    except StageError as exc:
        if work is None:
            raise
        raise StageError(
            f"{exc}; {len(tally.rows)} attempts done, their blocks kept in {work.path}: the "
            "same command resumes from them"
        ) from None
    finally:
        results.close()
        bar.close()
    wall = time.perf_counter() - t0
    if num_demos is not None and len(tally.kept) < num_demos:
        too_few_demos(tally, num_demos, work)
    return generation_result(job.attempts, tally, wall)


def attempts_bar(total: int, unit: str, label: str, **kw: Any) -> tqdm:
    """The progress bar ``label`` of a generate run: ``total`` ``unit``s (demos or
    attempts). Attempts come back a block at a time, so the time left is estimated from the
    mean rate so far, not from tqdm's moving average of the last bursts (which swings from
    hours to 0 s); it settles after the first blocks."""
    return tqdm(total=total, desc=label, unit=unit, smoothing=0, **kw)


def take_attempts(
    results: Iterator[tuple[int, Attempt, float]],
    tally: AttemptTally,
    bar: tqdm,
    num_demos: int | None,
    robot: str,
) -> None:
    """Add the attempts of ``results`` to ``tally`` in order, until they run out or (guarantee
    mode) ``num_demos`` have succeeded, counting each on the progress ``bar``. Raises
    InputError when the first IK_ABORT_AFTER all failed at IK (``robot`` cannot reach the
    targets)."""
    for _, attempt, sec in results:
        tally.rows.append(
            (
                attempt.success,
                attempt.failed_subtask,
                sec,
                attempt.ik_failed,
                attempt.planner_failed,
            )
        )
        rows = tally.rows
        if len(rows) == IK_ABORT_AFTER and all(r[3] for r in rows):
            raise InputError(
                f"all of the first {IK_ABORT_AFTER} attempts failed at IK "
                f"(robot {robot!r} cannot reach the targets); nothing was written"
            )
        (tally.kept if attempt.success else tally.failed).append(attempt)
        bar.update(1 if (attempt.success or num_demos is None) else 0)
        bar.set_postfix(attempts=len(rows), dgr=f"{100 * len(tally.kept) / len(rows):.1f}%")
        if num_demos is not None and len(tally.kept) == num_demos:
            break


def too_few_demos(tally: AttemptTally, num_demos: int, work: WorkDir | None) -> None:
    """Raise InputError for a guarantee-mode run whose attempts ran out before ``num_demos``
    succeeded, removing its ``work`` directory: its blocks would only resume this same run
    to the same cap (max_attempts is part of the run id), so nothing is kept."""
    n = len(tally.rows)
    if work is not None:
        work.remove()
    raise InputError(
        f"{len(tally.kept)} of {num_demos} demos after generate.max_attempts={n} "
        f"attempts (DGR {100 * len(tally.kept) / max(1, n):.1f}%); raise generate.max_attempts "
        "(--max-attempts) or check the source demos; nothing was written"
    )


def generation_result(job: AttemptJob, tally: AttemptTally, wall: float) -> GenerationResult:
    """The run's result from its ``tally`` and wall time [s]: its metrics, and the failed
    attempts that have steps (one stopped at IK before its first step is counted in the
    metrics only)."""
    rows = tally.rows
    metrics = generation_metrics(
        np.array([r[0] for r in rows], bool),
        np.array([r[1] for r in rows]),
        np.array([r[2] for r in rows]),
        [s.name for s in job.spec.subtasks],
        np.array([r[3] for r in rows], bool),
        np.array([r[4] for r in rows], bool) if job.config.transit == "planned" else None,
    )
    failed = [a for a in tally.failed if len(a.steps)]
    kept = tally.kept
    metrics.update(
        wall_seconds=wall, steps=int(sum(len(a.steps["actions"]) for a in kept + failed))
    )
    return GenerationResult(kept, failed, metrics)


def source_demos(
    store: EpisodeStore, objects: tuple[str, ...], arms: tuple[str, ...] = (ARM,)
) -> SourceDemos:
    """A parsed store's arrays in the generator's form (4x4 world poses), for a task with
    these objects and arms."""
    return SourceDemos(
        target_poses={a: store.poses(arm_key("target_pose", a)) for a in arms},
        gripper={a: np.asarray(store.data[arm_key("gripper", a)], np.float64) for a in arms},
        object_poses={o: store.poses(f"object_poses/{o}") for o in objects},
        episode_ends=store.episode_ends,
        term_index=np.asarray(store.episodes["subtask_term_index"], np.int64),
    )


def write_generated(
    kept: Path, failed: Path, result: GenerationResult, spec: TaskSpec, attrs: Mapping[str, Any]
) -> None:
    """The kept store at ``kept`` and the failed store at ``failed`` of a generate run."""
    planned = "planner_failures" in result.metrics
    for attempts, path, kind in (
        (result.kept, kept, "generated"),
        (result.failed, failed, "failed"),
    ):
        steps = [a.steps for a in attempts]
        write_store(path, kind, steps, episode_fields(attempts, spec, planned), attrs)


def episode_fields(
    attempts: list[Attempt], spec: TaskSpec, planned: bool = False
) -> dict[str, np.ndarray]:
    """meta/episodes of a generated (or failed) store, shaped also when it has none; with
    ``planned`` (planned transit), each episode's planner failure too."""
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
    } | ({"planner_failure": np.asarray([a.planner_failed for a in attempts], bool)}
         if planned else {})  # fmt: skip


WORKSPACE_SCENES = 8  # scenes sampled to check that the arm can reach the workspace


def check_workspace(job: AttemptJob, seeds: Sequence[int], robot: str) -> None:
    """InputError when the arm can reach the source segments in none of the first
    WORKSPACE_SCENES scenes of ``seeds`` (generation.reachable_scenes), before any work."""
    env = job.make_env()
    try:
        scenes = reachable_scenes(env, job.sources, job.spec, job.variant, seeds[:WORKSPACE_SCENES])
    finally:
        env.close()
    if scenes == 0:
        raise InputError(
            f"robot {robot!r} cannot reach the {job.variant} workspace of {job.spec.name}: in "
            f"none of {WORKSPACE_SCENES} sampled scenes does it have IK solutions for the "
            "source demo's segments. Nothing was generated."
        )
