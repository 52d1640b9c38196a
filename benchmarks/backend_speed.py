"""Seconds per generation attempt on Stack, PyBullet vs ManiSkill, measured in one run.

Both back ends generate from their own Panda source demos (the stores `dvc repro` writes),
one process, in alternating blocks so that machine load falls on both alike; each block
starts on a rebuilt scene as in the generate stage. Also times raw stepping (the same
env stepping a still action) to separate the simulator's cost from the generator's.

    python benchmarks/backend_speed.py --attempts 64
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from mimicgen_pipe import backends
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.method.generation import GenerationConfig, run_attempt
from mimicgen_pipe.run.runner import ATTEMPTS_PER_BLOCK, attempt_seed, source_demos

BACKENDS = {
    "maniskill": ("stack_cube", "data/pose_noise/stack_cube.zarr"),
    "pybullet": ("stack", "data/parsed/stack.zarr"),
}


def raw_step_ms(env, steps: int = 200) -> float:
    still = np.zeros(7, np.float32)
    still[-1] = 1.0
    env.reset(seed=0, variant="D0")
    t0 = time.perf_counter()
    for _ in range(steps):
        env.step(still)
    return 1e3 * (time.perf_counter() - t0) / steps


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--attempts", type=int, default=64, help="attempts per back end")
    p.add_argument("--variant", default="D0")
    args = p.parse_args()
    runs = {}
    for backend, (task, store_path) in BACKENDS.items():
        env = backends.make_env(backend, task, "panda")
        store = read_store(store_path, ["target_pose"])
        runs[backend] = (env, source_demos(store, env.spec.objects), [], [], [])
    seeds = [attempt_seed(0, args.variant, i) for i in range(args.attempts)]
    for b in range(0, len(seeds), ATTEMPTS_PER_BLOCK):
        for env, sources, seconds, steps, ok in runs.values():
            env.rebuild()
            for seed in seeds[b : b + ATTEMPTS_PER_BLOCK]:
                t0 = time.perf_counter()
                a = run_attempt(env, sources, env.spec, GenerationConfig(), args.variant, seed)
                seconds.append(time.perf_counter() - t0)
                steps.append(len(a.steps.get("actions", ())))
                ok.append(a.success)
    print(f"Stack {args.variant}, {args.attempts} attempts per back end, one process")
    print(
        "backend    | s/attempt (median) | steps/attempt | ms/step in generation |"
        " raw ms/step | DGR %"
    )
    med = {}
    for backend, (env, _, seconds, steps, ok) in runs.items():
        med[backend] = float(np.median(seconds))
        per_step = 1e3 * float(np.sum(seconds)) / max(1, int(np.sum(steps)))
        print(
            f"{backend:10} | {med[backend]:18.3f} | {np.mean(steps):13.1f} | "
            f"{per_step:21.2f} | {raw_step_ms(env):11.2f} | {100 * np.mean(ok):5.1f}"
        )
    print(f"pybullet / maniskill seconds per attempt: {med['pybullet'] / med['maniskill']:.2f}")


if __name__ == "__main__":
    main()
