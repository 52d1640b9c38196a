"""source: record source demos on D0 (ManiSkill's motion planners, or a trajectory file)."""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from tqdm import tqdm

import envs
from mimicgen_pipe import layout
from mimicgen_pipe.errors import InputError
from mimicgen_pipe.generation import replay_actions
from mimicgen_pipe.metrics import write_metrics
from mimicgen_pipe.params import as_dict, load_params


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--params", default="params.yaml", help="params file (default: params.yaml)")
    p.add_argument("--out", help="output store (default: data/source/<task>.zarr)")
    p.add_argument("--metrics", help="metrics JSON (default: metrics/source_<task>.json)")


def run(args: argparse.Namespace) -> None:
    params = load_params(args.params)
    spec = envs.task_spec(params.backend, params.task)
    out = Path(args.out or layout.source_store(params.task))
    metrics_path = Path(args.metrics or layout.metrics_file("source", params.task))
    from envs.maniskill import source as ms_source

    p = params.source
    with tempfile.TemporaryDirectory(prefix="mimicgen-source-") as tmp:
        if p.from_file is not None:
            traj_file, planner_failures = Path(p.from_file), 0
        else:
            print(f"source: motion planning {p.num_demos} demos of {params.task} (D0)")
            traj_file, planner_failures = ms_source.run_motion_planner(
                params.task, params.robot, p.num_demos, p.seed, Path(tmp), 10 * p.num_demos
            )
        episodes = ms_source.read_trajectory_file(traj_file, params.task)[: p.num_demos]
        env = envs.make_env(params.backend, params.task, params.robot)
        kept, seeds, init_poses = [], [], []
        replay_failures = 0
        for ep in tqdm(episodes, desc="source: replaying demos", unit="demo"):
            state = ms_source.initial_state(env, ep)
            obj = env.object_poses()
            steps, success = replay_actions(env, state, ep.actions, spec.objects)
            if not success:
                replay_failures += 1
                continue
            kept.append(steps)
            seeds.append(ep.seed)
            init_poses.append(np.stack([obj[o] for o in spec.objects]))
    if not kept:
        raise InputError(f"{traj_file}: no episode succeeded when replayed")
    from mimicgen_pipe.store import write_store

    write_store(
        out,
        kept,
        {
            "seed": np.asarray(seeds, np.int64),
            "success": np.ones(len(kept), bool),
            "initial_object_poses": np.stack(init_poses),
        },
        {
            "task": params.task,
            "variant": "D0",
            "backend": params.backend,
            "robot": params.robot,
            "control_mode": env.control_mode,
            "control_freq": env.control_freq,
            "objects": list(spec.objects),
            "source_file": str(p.from_file or "motion_planning"),
            "params": as_dict(params),
        },
    )
    write_metrics(
        metrics_path,
        {
            "demos": len(kept),
            "dropped_planner": int(planner_failures),
            "dropped_replay": int(replay_failures),
            "mean_length": float(np.mean([len(s["actions"]) for s in kept])),
        },
    )
    print(
        f"source: {len(kept)} demos -> {out} ({planner_failures} planner and "
        f"{replay_failures} replay failures dropped)"
    )
