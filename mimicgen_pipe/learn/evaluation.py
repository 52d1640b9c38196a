"""Policy evaluation: which checkpoints of a training run are rolled out (each checked
first), and their rollouts from evaluation seeds that no generation attempt or source demo
uses, run in blocks on rebuilt scenes (like generation) so results do not depend on the
number of worker processes."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from mimicgen_pipe.core.contracts import Env
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.interrupts import Interrupted
from mimicgen_pipe.core.observations import arms_observation_values, low_dim_observation
from mimicgen_pipe.core.taskspec import ARM, TaskSpec, check_task_version
from mimicgen_pipe.data.outputs import check_same_run
from mimicgen_pipe.data.params import EvaluateParams
from mimicgen_pipe.learn.training import check_meta, find_checkpoints, load_checkpoint
from mimicgen_pipe.method.generation import arm_envs
from mimicgen_pipe.run.executors import Executor, map_blocks
from mimicgen_pipe.run.rollout_progress import StepCounter, StepProgress

EVAL_SEED_BASE = 1 << 30  # generation and source seeds are < 2**30 (runner.attempt_seed)
EPISODES_PER_BLOCK = 10


def evaluation_seed(seed: int, variant: str, episode: int) -> int:
    """Reset seed of one evaluation episode, in [2**30, 2**31): disjoint from every seed
    the source and generate stages use."""
    ss = np.random.SeedSequence([seed, int.from_bytes(variant.encode(), "little"), episode, 7])
    return EVAL_SEED_BASE + int(ss.generate_state(1, np.uint32)[0] % EVAL_SEED_BASE)


def evaluated_checkpoints(epochs: Sequence[int], every_epochs: int) -> list[int]:
    """Indices of the checkpoints (their epochs, in training order) that are rolled out: each
    one whose epoch is a multiple of ``every_epochs``, and the last, so that the last success
    rate is the end of training's. Raises InputError when a multiple up to the last epoch has
    no checkpoint: the selection would skip it silently."""
    have = set(epochs)
    missing = [e for e in range(every_epochs, epochs[-1] + 1, every_epochs) if e not in have]
    if missing:
        raise InputError(
            f"evaluate.every_epochs is {every_epochs}, but there is no checkpoint of epoch "
            f"{missing[0]} (checkpoints: epochs {list(epochs)}); expected a multiple of the "
            "training's checkpoint_every"
        )
    last = len(epochs) - 1
    return [i for i, e in enumerate(epochs) if e % every_epochs == 0 or i == last]


@dataclass(frozen=True)
class Checkpoints:
    """The checkpoints of one training run that an evaluation rolls out: ``runs``, training
    seed -> its checkpoints in epoch order; ``epochs``, each checkpoint's epoch;
    ``data_run_id``, the generate run of the training data (None for source demos);
    ``cameras``, those an image policy sees (none: a low-dim policy), rendered at
    ``image_size`` (height, width) [px]."""

    runs: dict[int, list[Path]]
    epochs: dict[Path, int]
    data_run_id: Any
    cameras: tuple[str, ...] = ()
    image_size: tuple[int, int] | None = None

    @property
    def paths(self) -> list[Path]:
        return [c for ckpts in self.runs.values() for c in ckpts]


def checkpoints_to_evaluate(
    directory: Path,
    spec: TaskSpec,
    obs_keys: Sequence[str],
    every_epochs: int,
    made_by: str = "",
) -> Checkpoints:
    """The checkpoints of policy directory ``directory`` that are rolled out
    (:func:`evaluated_checkpoints`), every checkpoint there loaded and checked first: its
    meta, its task (``spec``'s, at the version its file has now), its observation layout
    (widths as the task's observation_dims; keys ``obs_keys``, params' train.obs_keys) and
    its training run (one for all). Raises InputError naming the file otherwise; for a
    directory without checkpoints, one that ends with ``made_by`` (what writes them, e.g.
    "; written by ...")."""
    task, obs_dims = spec.name, spec.observation_dims
    try:
        runs = find_checkpoints(directory)
    except InputError as exc:
        raise InputError(f"{exc}{made_by}") from None
    epochs: dict[Path, int] = {}
    data_run_ids: dict[str, object] = {}
    images: dict[tuple, Path] = {}  # (image keys, size) -> the first checkpoint of them
    for ckpt in (c for ckpts in runs.values() for c in ckpts):
        model, meta = load_checkpoint(ckpt)
        check_meta(ckpt, meta)
        layout = dict(zip(model.config.obs_keys, model.config.obs_dims, strict=True))
        wrong = {k: d for k, d in layout.items() if obs_dims.get(k) != d}
        if meta.get("task") != task or wrong:
            raise InputError(
                f"{ckpt}: observation layout {layout} (task {meta.get('task')!r}) does not fit "
                f"task {task!r}, whose observations are {obs_dims}"
            )
        check_task_version(meta, spec, str(ckpt))
        if list(model.config.obs_keys) != list(obs_keys):
            raise InputError(
                f"{ckpt}: trained on observation keys {list(model.config.obs_keys)}, but "
                f"params train.obs_keys is {list(obs_keys)}"
            )
        epochs[ckpt] = int(meta["epoch"])
        data_run_ids[str(ckpt)] = meta.get("data_run_id")
        c = model.config
        images.setdefault((c.image_keys, c.image_size if c.image_keys else None), ckpt)
    check_same_run(data_run_ids, "train")  # checkpoints of one training run only
    if len(images) > 1:
        (a, first), (b, other) = list(images.items())[:2]
        raise InputError(
            f"{directory}: {other} sees images {b[0] or 'none'} at {b[1]}, {first} sees "
            f"{a[0] or 'none'} at {a[1]}; expected the checkpoints of one training run"
        )
    (image_keys, image_size) = next(iter(images))
    try:
        chosen = {
            seed: [
                ckpts[i] for i in evaluated_checkpoints([epochs[c] for c in ckpts], every_epochs)
            ]
            for seed, ckpts in runs.items()
        }
    except InputError as exc:
        raise InputError(f"{directory}: {exc}") from None
    cameras = tuple(k.removesuffix("_image") for k in image_keys)
    return Checkpoints(chosen, epochs, next(iter(data_run_ids.values())), cameras, image_size)


def policy_inputs(
    checkpoints: Checkpoints, obs_keys: Sequence[str], obs_dims: Mapping[str, int]
) -> dict[str, tuple[tuple[int, ...], str]]:
    """What the checkpoints' policy reads, key -> (shape, dtype): each low-dim key of
    ``obs_keys`` (every checkpoint was checked to read them, of the task's widths
    ``obs_dims``) and, for an image policy, each camera's ``<camera>_image``."""
    inputs = {k: ((obs_dims[k],), "float32") for k in obs_keys}
    if checkpoints.cameras and checkpoints.image_size is not None:
        h, w = checkpoints.image_size
        inputs |= {f"{c}_image": ((h, w, 3), "uint8") for c in checkpoints.cameras}
    return inputs


class ClosedLoopPolicy(Protocol):
    """A policy acting in closed loop, one step at a time: ``reset(seed)`` at each episode
    start, then ``act(obs)``, the action for the observation dict of
    mimicgen_pipe.core.observations (mimicgen_pipe.learn.policy.RolloutPolicy is one; so is
    mimicgen_pipe.formats.external.ExternalPolicy, which also has a ``close()`` that the evaluator
    calls when it is done with it)."""

    def reset(self, seed: int) -> None: ...
    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray: ...


@dataclass(frozen=True)
class Rollout:
    """One episode: its reset seed, success, steps run, and, where asked for, the step at
    which each subtask ended, as parse finds subtask ends in a demo: the first rise of its term
    signal after the subtask before it ended (-1: never; the last subtask, which ends with the
    task, has none). Step t is the state after t actions."""

    seed: int
    success: bool
    steps: int
    subtask_ends: tuple[int, ...] = ()


def policy_observation(
    env: Env, objects: Sequence[str], arms: Sequence[str] = (ARM,)
) -> dict[str, np.ndarray]:
    """The low-dim observation of the env's current state as the generator records it
    (float32, mimicgen_pipe.core.observations): for a task of several ``arms``, each arm's keys
    prefixed with its name."""
    if len(arms) == 1:
        return low_dim_observation(env.eef_pose(), env.gripper_state(), env.object_poses(), objects)
    each = arm_envs(env, tuple(arms))
    values = arms_observation_values(
        {a: e.eef_pose() for a, e in each.items()},
        {a: e.gripper_state() for a, e in each.items()},
        env.object_poses(),
        objects,
    )
    return {k: np.asarray(v, np.float32) for k, v in values.items()}


def rollout(
    env: Env,
    policy: ClosedLoopPolicy,
    seed: int,
    variant: str,
    horizon: int,
    objects: Sequence[str],
    cameras: Any = None,
    term_signals: Sequence[str] = (),
    arms: Sequence[str] = (ARM,),
) -> Rollout:
    """One episode: reset the scene from ``seed``, act until the task succeeds or ``horizon``
    steps have run. ``cameras``: for a policy that reads images, a renderer of the env's
    state (mimicgen_pipe.core.contracts.Renderer), whose images join the observation as
    ``<camera>_image``, the store's ``obs/<camera>_image`` (the same picture of the same
    state as the observe stage takes). ``term_signals``: the term signals of the subtasks
    but the last, in order, whose ends the rollout records in its ``subtask_ends``. ``arms``:
    the task's arms (spec.arms), whose end effectors the observation reads."""
    env.reset(seed=seed, variant=variant)
    policy.reset(seed)
    ends: list[int] = []
    before = env.subtask_signals() if term_signals else {}
    for t in range(horizon):
        obs = policy_observation(env, objects, arms)
        if cameras is not None:
            obs |= {f"{c}_image": im for c, im in cameras.images(env.get_state()).items()}
        env.step(policy.act(obs))
        if len(ends) < len(term_signals):  # one subtask at most ends at a step
            held, name = env.subtask_signals(), term_signals[len(ends)]
            if held[name] and not before[name]:
                ends.append(t + 1)
            before = held
        if env.is_success():
            return Rollout(seed, True, t + 1, _padded(ends, term_signals))
    return Rollout(seed, False, horizon, _padded(ends, term_signals))


def _padded(ends: list[int], term_signals: Sequence[str]) -> tuple[int, ...]:
    return (*ends, *[-1] * (len(term_signals) - len(ends)))


@dataclass(frozen=True)
class EvalJob:
    """Everything a worker needs: how to make its env and to load a policy by name; for a
    policy that reads images, how to make its cameras' renderer; the term signals whose
    subtask ends each rollout records and the task's arms (see :func:`rollout`);
    ``progress``: the directory where each worker keeps its step counts
    (mimicgen_pipe.run.rollout_progress; :func:`evaluate_policies` sets it)."""

    make_env: Callable[[], Env]
    load_policy: Callable[[str], ClosedLoopPolicy]
    variant: str
    horizon: int
    objects: tuple[str, ...]
    make_cameras: Callable[[], Any] | None = None
    term_signals: tuple[str, ...] = ()
    arms: tuple[str, ...] = (ARM,)
    progress: str | None = None


@dataclass
class _Worker:
    """A worker's env, the policy it rolled out last (kept for its next block: an
    external policy's server starts once per worker, not once per block), and its step
    counter (None: it reports no steps)."""

    job: EvalJob
    env: Env
    cameras: Any = None
    policy: tuple[str, ClosedLoopPolicy] | None = None
    counter: StepCounter | None = None

    def load(self, name: str) -> ClosedLoopPolicy:
        if self.policy is None or self.policy[0] != name:
            self.close_policy()
            self.policy = (name, self.job.load_policy(name))
        return self.policy[1]

    def close_policy(self) -> None:
        if self.policy is not None:
            close = getattr(self.policy[1], "close", None)
            self.policy = None
            if close is not None:
                close()


@dataclass
class _Counted:
    """``policy``, whose episodes and steps ``counter`` counts as a rollout runs: its reset
    starts an episode, each action it chooses is one step (the step that action is for)."""

    policy: ClosedLoopPolicy
    counter: StepCounter

    def reset(self, seed: int) -> None:
        self.policy.reset(seed)
        self.counter.step()  # the call that follows a reset counts no step

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        action = self.policy.act(obs)
        self.counter.step()
        return action


_WORKER: _Worker | None = None


def _init_worker(job: EvalJob) -> None:
    global _WORKER
    import torch

    torch.set_num_threads(1)  # one process per core; a small LSTM gains nothing from threads
    # the renderer of the cameras the policy reads (EvalJob.make_cameras), none for others
    cameras = job.make_cameras() if job.make_cameras is not None else None
    _WORKER = _Worker(job, job.make_env(), cameras, counter=StepCounter.open(job.progress))


def _run_block(task: tuple[str, list[int]]) -> tuple[str, list[Rollout]]:
    assert _WORKER is not None
    job, env, cameras, counter = _WORKER.job, _WORKER.env, _WORKER.cameras, _WORKER.counter
    name, seeds = task
    policy = _WORKER.load(name)
    env.rebuild()
    out = []
    for s in seeds:
        t0 = time.perf_counter()
        counted = policy if counter is None else _Counted(policy, counter)
        r = rollout(env, counted, s, job.variant, job.horizon, job.objects, cameras,
                    job.term_signals, job.arms)  # fmt: skip
        if counter is not None:
            counter.episode(r.steps, time.perf_counter() - t0)
        out.append(r)
    return name, out


def run_evaluation(
    job: EvalJob, policies: Sequence[str], seeds: Sequence[int], executor: Executor
) -> Iterator[tuple[str, list[Rollout]]]:
    """Roll out every policy (by name) from every seed; yields (policy, rollouts of one
    block) as blocks finish, in order. Policies with a ``close()`` are closed once done."""
    tasks = [
        (name, list(seeds[i : i + EPISODES_PER_BLOCK]))
        for name in policies
        for i in range(0, len(seeds), EPISODES_PER_BLOCK)
    ]
    results = map_blocks(_run_block, tasks, executor, _init_worker, (job,))
    try:
        yield from results
    finally:
        results.close()
        if _WORKER is not None:  # the blocks ran in this process (one worker)
            _WORKER.close_policy()


def evaluate_policies(
    job: EvalJob, names: Sequence[str], seeds: Sequence[int], executor: Executor, label: str
) -> tuple[dict[str, list[Rollout]], float]:
    """Roll out every policy (by name, loaded by ``job.load_policy``) from every seed
    (:func:`run_evaluation`) under a progress bar of steps named ``label``, which says an
    estimate of the total time once an episode has finished
    (mimicgen_pipe.run.rollout_progress). Returns each policy's rollouts in seed order and the
    wall time [s]; an Interrupted on the way up says how many episodes had run."""
    out: dict[str, list[Rollout]] = {n: [] for n in names}
    t0 = time.perf_counter()
    blocks = len(names) * -(-len(seeds) // EPISODES_PER_BLOCK)
    episodes = len(names) * len(seeds)
    parallel = min(executor.workers, blocks)
    with StepProgress(label, episodes, job.horizon, parallel) as progress:
        job = dataclasses.replace(job, progress=progress.directory)
        results = run_evaluation(job, names, seeds, executor)
        try:
            for name, rollouts in results:
                out[name] += rollouts
                progress.returned(len(rollouts))
        except Interrupted as exc:
            exc.detail = f"after {progress.episodes_returned} of {episodes} episodes"
            raise
        finally:
            results.close()
    return out, time.perf_counter() - t0


def rollout_plan(
    label: str,
    inputs: Mapping[str, tuple[Sequence[int], str]],
    cameras: Sequence[str],
    size: tuple[int, int] | None,
    policies: int,
    episodes: int,
    horizon: int,
    workers: int,
    noun: str = "policy",
) -> list[str]:
    """The lines an evaluation prints before its rollouts: what the policy reads
    (``inputs``, key -> (shape, dtype)), the ``cameras`` rendered for it at ``size``
    (height, width) [px], and the work: ``policies`` (of ``noun``, e.g. checkpoint) x
    ``episodes`` x ``horizon`` steps on ``workers`` workers."""
    reads = ", ".join(f"{k} {tuple(shape)} {dtype}" for k, (shape, dtype) in inputs.items())
    if cameras and size is not None:
        seen = f"cameras {', '.join(cameras)}, rendered at {size[0]}x{size[1]} (HxW) every step"
    else:
        seen = "no cameras (low-dim observations only)"
    kind = noun if policies == 1 else ("policies" if noun == "policy" else f"{noun}s")
    return [
        f"{label}: the policy reads {reads}",
        f"{label}: {seen}",
        f"{label}: {policies} {kind} x {episodes} episodes x {horizon} steps at most = "
        f"{policies * episodes * horizon} steps, on {workers} worker{'s' if workers > 1 else ''}",
    ]


@dataclass(frozen=True)
class EvaluateJob:
    """One evaluate run, checked (mimicgen_pipe.stages.evaluate.resolve): the checkpoints
    ``checkpoints`` of the policy directory ``policies`` (trained on ``data``), each loaded
    and checked, rolled out with arm ``robot`` on task ``task`` of back end ``backend`` in
    reset variant ``variant``, one episode from each of ``seeds``. ``rollouts`` is what every
    worker of ``executor`` is sent; ``inputs`` what the policy reads, key -> (shape, dtype);
    ``evaluate`` the evaluate params. Written as the success rate per checkpoint ``plot``
    (CSV) and the metrics JSON ``metrics_path``."""

    task: str
    backend: str
    robot: str
    data: str
    variant: str
    policies: Path
    checkpoints: Checkpoints
    inputs: Mapping[str, tuple[Sequence[int], str]]
    seeds: tuple[int, ...]
    evaluate: EvaluateParams
    executor: Executor
    rollouts: EvalJob
    metrics_path: Path
    plot: Path

    @property
    def label(self) -> str:
        """The run's name in its messages and progress bar."""
        return f"evaluate {self.data}_on_{self.variant}"

    def plan(self) -> list[str]:
        """The lines printed before the rollouts (:func:`rollout_plan`)."""
        c, e = self.checkpoints, self.evaluate
        return rollout_plan(self.label, self.inputs, c.cameras, c.image_size, len(c.paths),
                            e.episodes, self.rollouts.horizon, e.workers, "checkpoint")  # fmt: skip


def evaluate_checkpoints(job: EvaluateJob) -> tuple[dict[int, list[tuple[int, float]]], float]:
    """Roll out every checkpoint of ``job`` from every seed (:func:`evaluate_policies`, each
    checkpoint loaded by ``job.rollouts.load_policy`` from its path). Returns the success
    rates [%], training seed -> [(epoch, rate)] in epoch order, and the wall time [s]."""
    checkpoints = job.checkpoints
    rollouts, wall = evaluate_policies(
        job.rollouts, [str(c) for c in checkpoints.paths], job.seeds, job.executor, job.label
    )
    per_run = {
        seed: [(checkpoints.epochs[c], success_rate(rollouts[str(c)])) for c in ckpts]
        for seed, ckpts in checkpoints.runs.items()
    }
    return per_run, wall


def run_metrics(job: EvaluateJob, wall: float) -> dict[str, Any]:
    """How an evaluation ran, for its metrics: the training data's generate run, episodes,
    checkpoint rate, horizon [steps], wall time [s] and per episode, workers and executor;
    for an image policy, its cameras and image size [px] (low-dim policies' metrics keep
    their keys)."""
    checkpoints, params = job.checkpoints, job.evaluate
    out: dict[str, Any] = {
        "data_run_id": checkpoints.data_run_id,
        "episodes": params.episodes,
        "every_epochs": params.every_epochs,
        "horizon": job.rollouts.horizon,
        "wall_seconds": wall,
        "seconds_per_episode": wall / (len(checkpoints.paths) * params.episodes),
        "workers": params.workers,
        "executor": params.executor,
    }
    if checkpoints.cameras and checkpoints.image_size is not None:
        out |= {"cameras": list(checkpoints.cameras), "image_size": list(checkpoints.image_size)}
    return out


@dataclass(frozen=True)
class EvaluateExternalJob:
    """One evaluate_external run, checked (mimicgen_pipe.stages.evaluate_external.resolve):
    the checkpoints ``checkpoints`` of one training run elsewhere, in training order, of
    format ``policy_format`` (robomimic, LeRobot; trained on our export of ``data``), each
    probed by its server, rolled out with arm ``robot`` on task ``task`` of back end
    ``backend`` in reset variant ``variant``, one episode from each of ``seeds``. Checkpoint
    i is served as ``names[i]``, its rollouts sent to every worker of ``executor`` as
    ``rollouts[i]``; ``epochs[i]``, how far its training had got (in ``epoch_unit``; None
    where its path does not say). What the first reads: ``inputs``, key -> (shape, dtype),
    of them the ``cameras`` rendered at ``size`` (height, width) [px]. ``policy_sha256``:
    the last checkpoint's digest; ``evaluate``: the evaluate params. Written as one row per
    episode ``plot`` (CSV) and the metrics JSON ``metrics_path``."""

    task: str
    backend: str
    robot: str
    data: str
    variant: str
    policy_format: str
    checkpoints: tuple[Path, ...]
    names: tuple[str, ...]
    rollouts: tuple[EvalJob, ...]
    epochs: tuple[int | None, ...]
    epoch_unit: str
    inputs: Mapping[str, tuple[Sequence[int], str]]
    cameras: tuple[str, ...]
    size: tuple[int, int] | None
    policy_sha256: str
    seeds: tuple[int, ...]
    evaluate: EvaluateParams
    executor: Executor
    metrics_path: Path
    plot: Path

    @property
    def label(self) -> str:
        """The run's name in its messages and progress bars."""
        return f"evaluate {self.data}_on_{self.variant}_{self.policy_format}"

    @property
    def horizon(self) -> int:
        return self.rollouts[0].horizon

    def plan(self) -> list[str]:
        """The lines printed before the rollouts (:func:`rollout_plan`)."""
        episodes = len(self.seeds) * len(self.checkpoints)
        return rollout_plan(self.label, self.inputs, self.cameras, self.size, 1, episodes,
                            self.horizon, self.evaluate.workers)  # fmt: skip


def evaluate_external(
    job: EvaluateExternalJob,
) -> tuple[list[tuple[int | None, list[Rollout]]], float]:
    """Each checkpoint of ``job`` rolled out from its seeds, in training order
    (:func:`evaluate_policies`): (its epoch, its rollouts) each, and the wall time [s]."""
    results, wall = [], 0.0
    for name, rollouts, epoch in zip(job.names, job.rollouts, job.epochs, strict=True):
        done, seconds = evaluate_policies(rollouts, [name], job.seeds, job.executor, job.label)
        results.append((epoch, done[name]))
        wall += seconds
    return results, wall


def success_rate(rollouts: Sequence[Rollout]) -> float:
    """Share of successful episodes [%]."""
    return 100.0 * float(np.mean([r.success for r in rollouts]))
