"""The batched attempt engine (mimicgen_pipe.method.batched) against the one-at-a-time path, on the
CPU: the same StackCube attempts run one at a time on one env and on a lockstep batch of
``--num-envs`` CPU envs in one process, alternating block by block on rebuilt scenes so that
machine load falls on both alike; seconds per attempt, their ratio, and whether every
attempt drew the same scene and source demo. Written to metrics/benchmarks/batched_engine.json.

    python benchmarks/batched_engine.py [--attempts 64] [--num-envs 4] [--variant D0]

On CPUs a lockstep batch steps its scenes one after the other, so it cannot be faster than
one env: the ratio measures what the engine's bookkeeping costs (the gather, the per-slot
coroutines, the partial resets). A GPU batch steps all its scenes in one call.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from _machine import figures_path, machine

from mimicgen_pipe import backends
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.method.batched import LockstepBatch, run_batched
from mimicgen_pipe.method.generation import GenerationConfig, run_attempt
from mimicgen_pipe.run.runner import ATTEMPTS_PER_BLOCK, attempt_seed, source_demos

TASK = "stack_cube"
OUT = figures_path(__file__)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--attempts", type=int, default=64)
    p.add_argument("--num-envs", type=int, default=4)
    p.add_argument("--variant", default="D0")
    p.add_argument("--parsed", default=f"data/pose_noise/{TASK}.zarr")
    args = p.parse_args()
    spec = backends.task_spec("maniskill", TASK)
    sources = source_demos(read_store(args.parsed, ["target_pose"]), spec.objects)
    config = GenerationConfig()
    one = backends.make_env("maniskill", TASK)
    batch = LockstepBatch(tuple(backends.make_env("maniskill", TASK) for _ in range(args.num_envs)))
    seeds = [attempt_seed(0, args.variant, i) for i in range(args.attempts)]
    seconds = {"one_at_a_time": 0.0, "batched": 0.0}
    alone, together = [], []
    block = ATTEMPTS_PER_BLOCK * args.num_envs  # one block per slot, as a worker would
    for b in range(0, len(seeds), block):
        chunk = seeds[b : b + block]
        one.rebuild()
        t0 = time.perf_counter()
        alone += [run_attempt(one, sources, spec, config, args.variant, s) for s in chunk]
        seconds["one_at_a_time"] += time.perf_counter() - t0
        batch.rebuild()
        t0 = time.perf_counter()
        got = dict(run_batched(batch, sources, spec, config, args.variant, chunk))
        seconds["batched"] += time.perf_counter() - t0
        together += [got[i] for i in range(len(chunk))]
    same_draws = all(
        np.array_equal(a.initial_state, b.initial_state)
        and np.array_equal(a.source_demo, b.source_demo)
        for a, b in zip(alone, together, strict=True)
    )
    n = len(seeds)
    dgr = {
        "one_at_a_time": 100 * np.mean([a.success for a in alone]),
        "batched": 100 * np.mean([a.success for a in together]),
    }
    row = {
        "task": TASK,
        "variant": args.variant,
        "attempts": n,
        "num_envs": args.num_envs,
        **machine(),
        "seconds_per_attempt_one_at_a_time": round(seconds["one_at_a_time"] / n, 4),
        "seconds_per_attempt_batched": round(seconds["batched"] / n, 4),
        "batched_over_one_at_a_time": round(seconds["batched"] / seconds["one_at_a_time"], 3),
        "dgr_one_at_a_time": round(dgr["one_at_a_time"], 1),
        "dgr_batched": round(dgr["batched"], 1),
        "same_scenes_and_source_demos": same_draws,
    }
    for key, value in row.items():
        print(f"{key:36s} {value}")
    OUT.write_text(json.dumps(row, indent=1) + "\n")
    print(f"-> {OUT}")
    one.close()
    batch.close()


if __name__ == "__main__":
    main()
