"""Seconds per planned transit (generate.transit: planned) on ManiSkill, the planner's share
of an attempt, and steps per transit; written to metrics/benchmarks/planned_transit.json.

Attempts run as the generate stage runs them (a rebuilt scene per block of 16), on the
transit pipeline's parsed source demos (``dvc repro transit/dvc.yaml`` writes them), with
every call of the env's planner timed: the scene synced into the collision model, IK for
the approach, the search and the path's points.

    python benchmarks/planned_transit.py --attempts 32
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
from _machine import figures_path

from mimicgen_pipe import backends
from mimicgen_pipe.core.transit import PlannerSettings
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.method.generation import GenerationConfig, run_attempt
from mimicgen_pipe.run.runner import ATTEMPTS_PER_BLOCK, attempt_seed, source_demos

CELLS = (("stack_cube_wall", "wall"), ("stack_cube_wall", "D0"), ("pull_cube_tool", "D0"))
OUT = figures_path(__file__)


def measure(task: str, variant: str, attempts: int) -> dict:
    env = backends.make_env("maniskill", task, "panda")
    store = read_store(f"data/transit/parsed/{task}.zarr", ["target_pose"])
    sources = source_demos(store, env.spec.objects)
    plan = env.plan_transit
    calls: list[tuple[float, int]] = []  # seconds, steps (0: no path)

    def timed(*args, **kwargs):
        t0 = time.perf_counter()
        path, why = plan(*args, **kwargs)
        calls.append((time.perf_counter() - t0, 0 if path is None else len(path)))
        return path, why

    env.plan_transit = timed
    config = GenerationConfig(action_noise=0.025, transit="planned", planner=PlannerSettings())
    seconds = []
    for k in range(attempts):
        if k % ATTEMPTS_PER_BLOCK == 0:
            env.rebuild()
        t0 = time.perf_counter()
        run_attempt(env, sources, env.spec, config, variant, attempt_seed(0, variant, k))
        seconds.append(time.perf_counter() - t0)
    env.close()
    t = np.array([c[0] for c in calls])
    steps = np.array([c[1] for c in calls if c[1]])
    return {
        "task": task,
        "variant": variant,
        "attempts": attempts,
        "transits": len(calls),
        "no_path": int(sum(c[1] == 0 for c in calls)),
        "seconds_per_transit_mean": round(float(t.mean()), 4),
        "seconds_per_transit_median": round(float(np.median(t)), 4),
        "seconds_per_transit_max": round(float(t.max()), 4),
        "planner_share_of_attempt": round(float(t.sum() / sum(seconds)), 3),
        "steps_per_transit_mean": round(float(steps.mean()), 1) if len(steps) else None,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--attempts", type=int, default=32, help="attempts per cell")
    args = p.parse_args()
    rows = []
    for task, variant in CELLS:
        row = measure(task, variant, args.attempts)
        print(
            f"{task} ({variant}): {row['transits']} transits, "
            f"{row['seconds_per_transit_mean']:.3f} s mean / "
            f"{row['seconds_per_transit_median']:.3f} s median / "
            f"{row['seconds_per_transit_max']:.3f} s max per transit, "
            f"{100 * row['planner_share_of_attempt']:.0f}% of the attempts' time, "
            f"{row['steps_per_transit_mean']} steps per transit, {row['no_path']} without path"
        )
        rows.append(row)
    out = {"cpus": os.cpu_count(), "load_average_1min": round(os.getloadavg()[0], 2)}
    OUT.write_text(json.dumps(out | {"cells": rows}, indent=1) + "\n")
    print(f"-> {OUT}")


if __name__ == "__main__":
    main()
