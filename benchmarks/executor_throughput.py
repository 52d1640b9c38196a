"""Executor throughput: the same StackCube attempts on local 1 worker, local 2 workers and
Ray 2 workers, one after the other in one run, as attempts per second and ratios to the
1-worker run; and what the executor path costs over raw stepping of the same actions.

    python benchmarks/executor_throughput.py [--parsed data/parsed/stack_cube.zarr]
        [--variant D0] [--attempts 96]

Each executor runs the real path (blocks on rebuilt scenes, every finished block saved to a
work directory). Worker start-up (spawning, building the simulator) is inside each timing;
starting Ray itself is not (a cluster is normally up already) and is printed apart. All
executors must produce the same attempts, which is checked.
"""

from __future__ import annotations

import argparse
import functools
import tempfile
import time
from pathlib import Path

import envs
from mimicgen_pipe.executors import Executor
from mimicgen_pipe.generation import GenerationConfig
from mimicgen_pipe.resume import WorkDir
from mimicgen_pipe.runner import (
    AttemptBlockCodec,
    AttemptJob,
    attempt_seed,
    run_attempts,
    source_demos,
)
from mimicgen_pipe.store import read_store


def timed(job: AttemptJob, seeds: list[int], executor: Executor, tmp: Path) -> tuple[float, list]:
    work = WorkDir.open(
        tmp / f"{executor.kind}{executor.workers}.zarr", "benchmark", AttemptBlockCodec(seeds)
    )
    t0 = time.perf_counter()
    results = list(run_attempts(job, seeds, executor, work))
    seconds = time.perf_counter() - t0
    work.remove()
    return seconds, results


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--parsed", default="data/parsed/stack_cube.zarr")
    p.add_argument("--variant", default="D0")
    p.add_argument("--attempts", type=int, default=96)
    args = p.parse_args()
    spec = envs.task_spec("maniskill", "stack_cube")
    job = AttemptJob(
        make_env=functools.partial(envs.make_env, "maniskill", "stack_cube", "panda"),
        sources=source_demos(read_store(args.parsed, kind="parsed"), spec.objects),
        spec=spec,
        config=GenerationConfig(),
        variant=args.variant,
    )
    seeds = [attempt_seed(0, args.variant, i) for i in range(args.attempts)]
    import ray

    from mimicgen_pipe.executors.ray import _connect

    t0 = time.perf_counter()
    _connect(2, None)  # the local Ray the executor would start, started ahead of the timing
    ray_start = time.perf_counter() - t0

    runs: dict[str, float] = {}
    reference = None
    with tempfile.TemporaryDirectory() as tmp:
        for name, executor in (
            ("local, 1 worker", Executor("local", 1)),
            ("local, 2 workers", Executor("local", 2)),
            ("ray, 2 workers", Executor("ray", 2)),
        ):
            seconds, results = timed(job, seeds, executor, Path(tmp))
            outcome = [(s, a.success, len(a.steps.get("actions", ()))) for s, a, _ in results]
            assert reference is None or outcome == reference, f"{name}: different attempts"
            reference = outcome
            runs[name] = seconds
            if name.startswith("local, 1"):
                worker_seconds = sum(t for _, _, t in results)
                attempts = [a for _, a, _ in results]
    ray.shutdown()

    # raw stepping of the same actions from the same scenes, in this process
    env = job.make_env()
    step, t_step, n_steps = env.unwrapped.step, 0.0, 0
    for seed, attempt in zip(seeds, attempts, strict=True):
        env.reset(seed=seed, variant=args.variant)
        t0 = time.perf_counter()
        for action in attempt.steps.get("actions", ()):
            step(action)
        t_step += time.perf_counter() - t0
        n_steps += len(attempt.steps.get("actions", ()))
    env.close()

    dgr = 100 * sum(r[1] for r in reference) / len(reference)
    print(f"StackCube {args.variant}: {args.attempts} attempts, {n_steps} steps, DGR {dgr:.1f}%")
    base = runs["local, 1 worker"]
    for name, seconds in runs.items():
        print(
            f"{name:17s} {seconds:7.1f} s  {args.attempts / seconds:6.2f} attempts/s  "
            f"x{base / seconds:.2f} of 1 worker"
        )
    print(
        f"ray 2 / local 2: {runs['local, 2 workers'] / runs['ray, 2 workers']:.2f} "
        f"(throughput); starting the local Ray took {ray_start:.1f} s (not counted)"
    )
    print(
        f"executor path, 1 worker: {base / args.attempts:.3f} s/attempt; attempts alone "
        f"{worker_seconds / args.attempts:.3f} s/attempt; raw stepping "
        f"{t_step / args.attempts:.3f} s/attempt ({1e3 * t_step / n_steps:.2f} ms/step)"
    )
    print(
        f"overhead ratio over raw stepping: attempts on the executor path "
        f"{worker_seconds / t_step:.3f} (generator, resets and scene rebuilds), wall of the "
        f"1-worker run {base / t_step:.3f} (also building the simulator and saving blocks)"
    )


if __name__ == "__main__":
    main()
