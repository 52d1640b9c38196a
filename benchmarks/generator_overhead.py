"""Generator overhead: generate attempts in one process, then step the same env with the
same actions from the same initial states, and print the ratio of the two wall times.

    python benchmarks/generator_overhead.py [--parsed data/parsed/stack_cube.zarr]
        [--variant D1] [--attempts 100]

Both runs happen in one process, one after the other, so the ratio is robust to the
machine's speed; seconds per attempt are absolute and noisier.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import envs
from mimicgen_pipe.generation import GenerationConfig, run_attempt
from mimicgen_pipe.runner import attempt_seed
from mimicgen_pipe.store import read_store
from stages.generate import source_demos


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--parsed", default="data/parsed/stack_cube.zarr")
    p.add_argument("--variant", default="D1")
    p.add_argument("--attempts", type=int, default=100)
    args = p.parse_args()
    spec = envs.task_spec("maniskill", "stack_cube")
    sources = source_demos(read_store(args.parsed), spec.objects)
    env = envs.make_env("maniskill", "stack_cube")
    seeds = [attempt_seed(0, args.variant, i) for i in range(args.attempts)]
    run_attempt(env, sources, spec, GenerationConfig(), args.variant, seeds[0])  # warm-up

    t0 = time.perf_counter()
    attempts = [run_attempt(env, sources, spec, GenerationConfig(), args.variant, s) for s in seeds]
    t_gen = time.perf_counter() - t0

    step = env.unwrapped.step
    t_reset = t_step = 0.0
    for s, a in zip(seeds, attempts, strict=False):
        t0 = time.perf_counter()
        env.reset(seed=s, variant=args.variant)
        t1 = time.perf_counter()
        for action in a.steps["actions"]:
            step(action)
        t2 = time.perf_counter()
        t_reset, t_step = t_reset + t1 - t0, t_step + t2 - t1
    n_steps = sum(len(a.steps["actions"]) for a in attempts)
    dgr = 100 * np.mean([a.success for a in attempts])
    print(f"attempts {args.attempts} ({args.variant}), steps {n_steps}, DGR {dgr:.1f}%")
    print(
        f"generator: {t_gen:.2f} s, {t_gen / args.attempts:.3f} s/attempt, "
        f"{1e3 * t_gen / n_steps:.2f} ms/step"
    )
    print(
        f"raw env: reset {1e3 * t_reset / args.attempts:.2f} ms/attempt, "
        f"step {1e3 * t_step / n_steps:.2f} ms/step"
    )
    print(f"overhead ratio (generator / raw stepping): {t_gen / t_step:.3f}")
    print(f"overhead ratio (generator / raw resets + stepping): {t_gen / (t_reset + t_step):.3f}")


if __name__ == "__main__":
    main()
