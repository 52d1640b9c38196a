"""Policy evaluation: rollouts from evaluation seeds that no generation attempt or source
demo uses, run in blocks on rebuilt scenes (like generation) so results do not depend on
the number of worker processes."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from mimicgen_pipe.errors import InputError
from mimicgen_pipe.executors import Executor, map_blocks
from mimicgen_pipe.generation import Env
from mimicgen_pipe.observations import low_dim_observation

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


class Policy(Protocol):
    def reset(self, seed: int) -> None: ...
    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray: ...


@dataclass(frozen=True)
class Rollout:
    seed: int
    success: bool
    steps: int


def rollout(
    env: Env, policy: Policy, seed: int, variant: str, horizon: int, objects: Sequence[str]
) -> Rollout:
    """One episode: reset the scene from ``seed``, act until the task succeeds or ``horizon``
    steps have run."""
    env.reset(seed=seed, variant=variant)
    policy.reset(seed)
    for t in range(horizon):
        obs = low_dim_observation(env.eef_pose(), env.gripper_state(), env.object_poses(), objects)
        env.step(policy.act(obs))
        if env.is_success():
            return Rollout(seed, True, t + 1)
    return Rollout(seed, False, horizon)


@dataclass(frozen=True)
class EvalJob:
    """Everything a worker needs: how to make its env and to load a policy by name."""

    make_env: Callable[[], Env]
    load_policy: Callable[[str], Policy]
    variant: str
    horizon: int
    objects: tuple[str, ...]


_WORKER: tuple[EvalJob, Env] | None = None


def _init_worker(job: EvalJob) -> None:
    global _WORKER
    import torch

    torch.set_num_threads(1)  # one process per core; a small LSTM gains nothing from threads
    _WORKER = (job, job.make_env())


def _run_block(task: tuple[str, list[int]]) -> tuple[str, list[Rollout]]:
    assert _WORKER is not None
    job, env = _WORKER
    name, seeds = task
    policy = job.load_policy(name)
    env.rebuild()
    return name, [rollout(env, policy, s, job.variant, job.horizon, job.objects) for s in seeds]


def run_evaluation(
    job: EvalJob, policies: Sequence[str], seeds: Sequence[int], executor: Executor
) -> Iterator[tuple[str, list[Rollout]]]:
    """Roll out every policy (by name) from every seed; yields (policy, rollouts of one
    block) as blocks finish, in order."""
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
