"""The batched attempt engine (mimicgen_pipe.method.batched) on a CPU lockstep batch of ManiSkill
StackCube envs: the same attempts as the one-at-a-time path for the same seeds, every slot
at its own place in its own segments, ended attempts handed back and their slot alone
reset; and the batch size refused before any work when it is not a positive integer."""

from __future__ import annotations

import numpy as np
import pytest

from mimicgen_pipe.core.contracts import check_batch_size
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.method.batched import LockstepBatch, replay_batched, run_batched
from mimicgen_pipe.method.generation import GenerationConfig, run_attempt
from mimicgen_pipe.run.runner import attempt_seed, source_demos
from tests.conftest import same_attempt

N_SEEDS, N_SLOTS = 7, 3


class Logged:
    """An env that logs the seeds it is reset with and the steps it takes, in order."""

    def __init__(self, env) -> None:
        self.env, self.resets, self.steps = env, [], 0

    def __getattr__(self, name: str):
        return getattr(self.env, name)

    def reset(self, seed: int, variant: str) -> None:
        self.resets.append(seed)
        self.env.reset(seed=seed, variant=variant)

    def step(self, action: np.ndarray) -> None:
        self.steps += 1
        self.env.step(action)


@pytest.fixture(scope="module")
def setting(pipeline):
    from mimicgen_pipe import backends

    spec = backends.task_spec("maniskill", "stack_cube")
    sources = source_demos(read_store(pipeline / "data/parsed/stack_cube.zarr"), spec.objects)
    slots = [Logged(backends.make_env("maniskill", "stack_cube")) for _ in range(N_SLOTS)]
    yield spec, sources, slots
    for env in slots:
        env.close()


@pytest.mark.sim
def test_a_lockstep_batch_makes_the_attempts_one_at_a_time_makes(setting):
    """Every slot's attempts, run again one at a time on that slot's env rebuilt, in the
    order the slot ran them, are the same bit for bit: interleaving the attempts step by step
    changes nothing in any of them. (ManiSkill's CPU physics carries contact history from one
    reset to the next, so an attempt's last bits depend on what its scene ran before it: the
    reference runs each slot's seeds in that slot's order.)"""
    spec, sources, slots = setting
    config = GenerationConfig(action_noise=0.05)
    seeds = [attempt_seed(11, "D0", i) for i in range(N_SEEDS)]
    batch = LockstepBatch(tuple(slots))
    batch.rebuild()
    for env in slots:
        env.resets, env.steps = [], 0
    got = dict(run_batched(batch, sources, spec, config, "D0", seeds))
    assert sorted(got) == list(range(N_SEEDS))
    # each slot began with its own seed, and every seed was run once, on one slot
    assert [env.resets[0] for env in slots] == seeds[:N_SLOTS]
    assert sorted(s for env in slots for s in env.resets) == sorted(seeds)
    assert max(len(env.resets) for env in slots) >= 2  # a freed slot took the next seed
    # lockstep: a slot steps once per step of the attempts it ran, no more
    assert [env.steps for env in slots] == [
        sum(len(got[seeds.index(s)].steps.get("actions", ())) for s in env.resets) for env in slots
    ]
    for env in slots:
        ran, env.resets = env.resets, []
        env.rebuild()
        for seed in ran:
            alone = run_attempt(env, sources, spec, config, "D0", seed)
            assert same_attempt(alone, got[seeds.index(seed)]), f"seed {seed}"


@pytest.mark.sim
def test_what_an_attempt_draws_does_not_depend_on_its_slot(setting):
    """The scene, the source demos followed, and every step up to the first contact are
    the seed's alone: one at a time on one env and in a batch, the same."""
    spec, sources, slots = setting
    config = GenerationConfig(action_noise=0.05)
    seeds = [attempt_seed(5, "D1", i) for i in range(N_SLOTS + 2)]
    slots[0].rebuild()
    alone = [run_attempt(slots[0], sources, spec, config, "D1", s) for s in seeds]
    batch = LockstepBatch(tuple(slots[:2]))
    batch.rebuild()
    together = dict(run_batched(batch, sources, spec, config, "D1", seeds))
    for i, a in enumerate(alone):
        b = together[i]
        assert np.array_equal(a.initial_state, b.initial_state)
        assert np.array_equal(a.initial_object_poses, b.initial_object_poses)
        assert np.array_equal(a.source_demo[:1], b.source_demo[:1])
        assert np.array_equal(a.steps["actions"][:20], b.steps["actions"][:20])


@pytest.mark.parametrize("size", [0, -2, 1.5, True, "4"])
def test_a_batch_size_that_is_not_a_positive_integer_is_refused(size):
    with pytest.raises(InputError, match=r"batch size num_envs must be an integer >= 1, not "):
        check_batch_size(size)


def test_an_empty_lockstep_batch_is_refused():
    with pytest.raises(InputError, match="not 0"):
        LockstepBatch(())


class CountingBatch:
    """A batch without a simulator: each slot's state is the sum of the actions it stepped
    since its state was set; an episode succeeds when it ends where the sum of its own
    actions says it should."""

    def __init__(self, num_envs: int) -> None:
        self.num_envs = num_envs
        self.sums = np.zeros((num_envs, 7))
        self.slots = [CountingSlot(self, k) for k in range(num_envs)]

    def slot(self, k: int) -> CountingSlot:
        return self.slots[k]

    def step(self, actions: np.ndarray, active: np.ndarray) -> None:
        self.sums[active] += actions[active]


class CountingSlot:
    def __init__(self, batch: CountingBatch, k: int) -> None:
        self.batch, self.k, self.goal = batch, k, None

    def set_state(self, state: np.ndarray) -> None:
        self.batch.sums[self.k] = 0.0
        self.goal = state

    def is_success(self) -> bool:
        return bool(np.allclose(self.batch.sums[self.k], self.goal))


def test_replay_runs_episodes_of_any_length_num_envs_at_a_time():
    rng = np.random.default_rng(0)
    episodes = []
    for n in (5, 1, 9, 3, 7):  # lengths differ within each group of 2
        actions = rng.standard_normal((n, 7)).astype(np.float32)
        goal = actions.astype(np.float64).sum(axis=0)
        episodes.append((goal if n != 3 else goal + 1.0, actions))  # the 3-step one misses
    assert replay_batched(CountingBatch(2), episodes) == [True, True, True, False, True]
    assert replay_batched(CountingBatch(8), episodes) == [True, True, True, False, True]
