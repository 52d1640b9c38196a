"""Generation on ManiSkill's GPU simulation against the CPU path, in one run: per task and
batch size N, demos per hour of one process on one GPU, DGR, seconds per demo and their ratio
to the CPU path's (one process, lean step, the same seeds' first attempts), and the share of
a sample of GPU-generated demos that replay to success on the GPU. Written to
metrics/benchmarks/gpu_generation.json.

    python benchmarks/gpu_generation.py [--tasks stack_cube pull_cube_tool plug_charger]
        [--num-envs 256 1024 4096] [--attempts-per-scene 2] [--cpu-attempts 48]
        [--replays 64] [--sim-backend physx_cuda]

It reads the parsed stores `dvc repro` writes (data/pose_noise/stack_cube.zarr, the
suite's data/parsed/<task>.zarr). ``--sim-backend physx_cpu --num-envs 1`` runs the same
code on a CPU (ManiSkill's stock step, one scene), a check of the script, not a GPU figure:
its JSON says which device gave it.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from _machine import figures_path, machine

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data.params import load_params
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.method.batched import replay_batched, run_batched
from mimicgen_pipe.method.generation import GenerationConfig, run_attempt
from mimicgen_pipe.run.runner import ATTEMPTS_PER_BLOCK, attempt_seed, source_demos

OUT = figures_path(__file__)
VARIANT = "D0"


def parsed_store(task: str) -> Path:
    main = Path(f"data/pose_noise/{task}.zarr")
    return main if main.exists() else Path(f"data/parsed/{task}.zarr")


def config(task: str, spec) -> GenerationConfig:
    """The pipelines' generation settings of ``task``: the main task's action noise, or the
    suite's, capped by the task file."""
    params = load_params()
    noise = params.generate.action_noise if task == params.task else params.suite.action_noise
    return GenerationConfig(action_noise=spec.action_noise(noise))


def cpu_path(task: str, sources, spec, seeds: list[int]) -> dict:
    """The one-at-a-time path: lean step, blocks on rebuilt scenes, as a generate worker."""
    env = backends.make_env("maniskill", task)
    successes, t0 = 0, time.perf_counter()
    for b in range(0, len(seeds), ATTEMPTS_PER_BLOCK):
        env.rebuild()
        for seed in seeds[b : b + ATTEMPTS_PER_BLOCK]:
            successes += run_attempt(env, sources, spec, config(task, spec), VARIANT, seed).success
    seconds = time.perf_counter() - t0
    env.close()
    return {
        "attempts": len(seeds),
        "dgr": round(100 * successes / len(seeds), 1),
        "seconds_per_attempt": round(seconds / len(seeds), 4),
        "seconds_per_demo": round(seconds / max(1, successes), 4),
    }


def batched_path(
    task: str, sources, spec, n: int, sim_backend: str, attempts: int, replays: int
) -> dict:
    """N scenes in one batch: the first ``attempts`` seeds in lockstep, then up to
    ``replays`` kept demos replayed on the same batch."""
    seeds = [attempt_seed(0, VARIANT, i) for i in range(attempts)]
    t0 = time.perf_counter()
    batch = backends.make_batch_env("maniskill", task, "panda", n, sim_backend)
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    ended = dict(run_batched(batch, sources, spec, config(task, spec), VARIANT, seeds))
    seconds = time.perf_counter() - t0
    kept = [ended[i] for i in range(len(seeds)) if ended[i].success]
    sample = [(a.initial_state, a.steps["actions"]) for a in kept[:replays]]
    replayed = replay_batched(batch, sample)
    batch.close()
    steps = sum(len(a.steps.get("actions", ())) for a in ended.values())
    return {
        "num_envs": n,
        "attempts": len(seeds),
        "dgr": round(100 * len(kept) / len(seeds), 1),
        "seconds": round(seconds, 2),
        "build_seconds": round(build, 2),
        "demos_per_hour": round(3600 * len(kept) / seconds),
        "attempts_per_hour": round(3600 * len(seeds) / seconds),
        "scene_steps_per_second": round(steps / seconds),
        "seconds_per_demo": round(seconds / max(1, len(kept)), 5),
        "replayed": len(sample),
        "replayed_to_success": int(sum(replayed)),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", nargs="+", default=["stack_cube", "pull_cube_tool", "plug_charger"])
    p.add_argument("--num-envs", nargs="+", type=int, default=[256, 1024, 4096])
    p.add_argument("--attempts-per-scene", type=int, default=2)
    p.add_argument("--cpu-attempts", type=int, default=48)
    p.add_argument("--replays", type=int, default=64)
    p.add_argument("--sim-backend", default="physx_cuda")
    args = p.parse_args()
    for n in args.num_envs:  # every refusal before any work
        for task in args.tasks:
            backends.check_batched("maniskill", task, "panda", n, args.sim_backend, "linear")
    device = machine()
    if args.sim_backend == "physx_cuda":
        device |= {"device": "cuda", "gpu": torch.cuda.get_device_name(0)}
    rows = []
    for task in args.tasks:
        spec = backends.task_spec("maniskill", task)
        sources = source_demos(read_store(parsed_store(task), ["target_pose"]), spec.objects)
        cpu_seeds = [attempt_seed(0, VARIANT, i) for i in range(args.cpu_attempts)]
        cpu = cpu_path(task, sources, spec, cpu_seeds)
        print(f"{task} CPU path: {cpu}")
        for n in args.num_envs:
            row = batched_path(
                task, sources, spec, n, args.sim_backend, n * args.attempts_per_scene, args.replays
            )
            row |= {
                "task": task,
                "cpu": cpu,
                "cpu_seconds_per_demo_over_batched": round(
                    cpu["seconds_per_demo"] / row["seconds_per_demo"], 2
                ),
                "dgr_batched_minus_cpu": round(row["dgr"] - cpu["dgr"], 1),
            }
            print(json.dumps(row))
            rows.append(row)
    figures = {
        **device,
        "sim_backend": args.sim_backend,
        "variant": VARIANT,
        "measured_on_gpu": args.sim_backend == "physx_cuda",
        "rows": rows,
    }
    OUT.write_text(json.dumps(figures, indent=1) + "\n")
    print(f"-> {OUT}")


if __name__ == "__main__":
    try:
        main()
    except InputError as e:
        raise SystemExit(f"gpu_generation: {e}") from None
