"""The batched attempt engine: many generation attempts advancing in lockstep in one batch of
envs, each at its own place in its own sequence of transformed segments.

Every attempt is :func:`mimicgen_pipe.method.generation.attempt_actions`, the coroutine the
one-at-a-time path runs, on one slot of the batch: each step gathers the action every busy
slot's attempt yields, steps the batch once, and resumes those attempts; an attempt that
ends (success, failure, IK or planner stop) is handed back and its slot alone is reset for
the next seed. What an attempt draws (scene, source demos, offsets, noise) comes from its
seed alone, so the same seeds give the same attempts as one at a time, whichever slot runs
them; the physics each slot steps is its back end's.

A back end's batched form is a :class:`mimicgen_pipe.core.contracts.BatchEnv`.
:class:`LockstepBatch` makes one of any envs of the env protocol, stepped one after the other
(on CPUs, where each simulator holds one scene); a GPU simulation holding N scenes in one
batch is another.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from mimicgen_pipe.core.contracts import BatchEnv, Env, check_batch_size
from mimicgen_pipe.core.taskspec import TaskSpec
from mimicgen_pipe.method.generation import (
    Attempt,
    AttemptActions,
    GenerationConfig,
    SourceDemos,
    attempt_actions,
)


@dataclass(frozen=True)
class LockstepBatch:
    """A batch of separate envs (one scene each), stepped one after the other."""

    envs: tuple[Env, ...]

    def __post_init__(self) -> None:
        check_batch_size(len(self.envs))

    @property
    def num_envs(self) -> int:
        return len(self.envs)

    def slot(self, k: int) -> Env:
        return self.envs[k]

    def step(self, actions: np.ndarray, active: np.ndarray) -> None:
        for env, action, on in zip(self.envs, actions, active, strict=True):
            if on:
                env.step(action)

    def rebuild(self) -> None:
        for env in self.envs:
            env.rebuild()

    def close(self) -> None:
        for env in self.envs:
            env.close()


def run_batched(
    batch: BatchEnv,
    sources: SourceDemos,
    spec: TaskSpec,
    config: GenerationConfig,
    variant: str,
    seeds: Sequence[int],
) -> Iterator[tuple[int, Attempt]]:
    """(index into ``seeds``, attempt) for every seed, as the attempts end (not in seed
    order), on the slots of ``batch`` in lockstep. Slot k starts with seed k; a slot whose
    attempt ends takes the next seed not started, and idles once there is none."""
    pending = iter(enumerate(seeds))
    running: list[tuple[int, AttemptActions] | None] = [None] * batch.num_envs
    actions = np.zeros((batch.num_envs, 7), dtype=np.float32)

    def start(k: int) -> Iterator[tuple[int, Attempt]]:
        """Start seeds on slot k until one yields its first action; yield those that end
        before any (stopped at IK or by the planner)."""
        running[k] = None
        for index, seed in pending:
            attempt = attempt_actions(batch.slot(k), sources, spec, config, variant, seed)
            try:
                actions[k] = next(attempt)
            except StopIteration as done:
                yield index, done.value
                continue
            running[k] = (index, attempt)
            return

    for k in range(batch.num_envs):
        yield from start(k)
    while any(r is not None for r in running):
        batch.step(actions, np.array([r is not None for r in running]))
        for k, slot in enumerate(running):
            if slot is None:
                continue
            index, attempt = slot
            try:
                actions[k] = next(attempt)
            except StopIteration as done:
                yield index, done.value
                yield from start(k)


def replay_batched(
    batch: BatchEnv, episodes: Sequence[tuple[np.ndarray, np.ndarray]]
) -> list[bool]:
    """Whether each episode, (initial state (the back end's get_state()), actions (T, 7)),
    succeeds when its actions are replayed from its state, ``batch.num_envs`` episodes at a
    time on the slots of ``batch``: the task's success after each episode's last action."""
    out: list[bool] = []
    for start in range(0, len(episodes), batch.num_envs):
        group = episodes[start : start + batch.num_envs]
        for k, (state, _) in enumerate(group):
            batch.slot(k).set_state(state)
        lengths = [len(a) for _, a in group]
        success = [False] * len(group)
        actions = np.zeros((batch.num_envs, 7), dtype=np.float32)
        for t in range(max(lengths, default=0)):
            active = np.zeros(batch.num_envs, dtype=bool)
            for k, (_, a) in enumerate(group):
                if t < lengths[k]:
                    actions[k], active[k] = a[t], True
            batch.step(actions, active)
            for k in range(len(group)):
                if t == lengths[k] - 1:
                    success[k] = bool(batch.slot(k).is_success())
        out += success
    return out
