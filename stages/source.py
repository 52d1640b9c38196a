"""source: record source demos on D0 (the back end's demonstrator, or a trajectory file)."""

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
from mimicgen_pipe.outputs import claim, output_set
from mimicgen_pipe.params import data_params
from stages import add_selection_arguments, stage_params


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument("--out", help="output store (default: data/source/<task>.zarr)")
    p.add_argument("--metrics", help="metrics JSON (default: metrics/source_<task>.json)")


# the demonstrator draws seeds until num_demos demos replay to success, at most this many
# seeds per demo asked for (plug_charger, the hardest planner here, needs about 4.5)
SEEDS_PER_DEMO = 20


def run(args: argparse.Namespace) -> None:
    params = stage_params(args)
    spec = envs.task_spec(params.backend, params.task)
    p = params.source
    envs.check_robot(params.backend, p.robot)
    out = Path(args.out or layout.source_store(params.task))
    metrics_path = Path(args.metrics or layout.metrics_file("source", params.task))
    claim(out, metrics_path)  # fails at once if another run writes them
    env = envs.make_env(params.backend, params.task, p.robot, params.maniskill.fast_step)
    kept, seeds, init_poses = [], [], []
    demonstrator_failures = replay_failures = seeds_tried = 0
    print(f"source: {p.num_demos} demos of {params.task} on {params.backend} (D0)")
    # demos that fail on replay are replaced by more from the demonstrator's next seeds
    while seeds_tried < SEEDS_PER_DEMO * p.num_demos:
        # beside the output, named as its temporaries, so that the next run removes it if
        # this one is killed before it can
        with tempfile.TemporaryDirectory(prefix=f".{out.name}.tmp-", dir=out.parent) as tmp:
            episodes, failures, tried = envs.source_episodes(
                params.backend,
                env,
                p.num_demos - len(kept),
                p.seed + seeds_tried,
                p.from_file,
                Path(tmp),
            )
        demonstrator_failures += failures
        seeds_tried += tried
        for ep in tqdm(episodes, desc="source: replaying demos", unit="demo"):
            env.set_state(ep.initial_state)
            obj = env.object_poses()
            steps, success = replay_actions(env, ep.initial_state, ep.actions, spec.objects)
            if not success:
                replay_failures += 1
                continue
            kept.append(steps)
            seeds.append(ep.seed)
            init_poses.append(np.stack([obj[o] for o in spec.objects]))
        if len(kept) == p.num_demos or tried == 0:  # done, or a file: nothing more to draw
            break
    if not kept:
        raise InputError(f"{p.from_file or params.task}: no source demo succeeded when replayed")
    if len(kept) < p.num_demos and p.from_file is None:
        raise InputError(
            f"{params.task}: the demonstrator gave {len(kept)} of source.num_demos = "
            f"{p.num_demos} demos that succeed on replay in {seeds_tried} seeds from "
            f"source.seed = {p.seed} ({demonstrator_failures} failed plans, {replay_failures} "
            "failed replays); ask for fewer demos or look at the demonstrator"
        )
    from mimicgen_pipe.store import write_store

    # store and metrics written aside, then renamed together (the store last)
    with output_set(metrics_path, out) as (tmp_metrics, tmp_out):
        write_store(
            tmp_out,
            "source",
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
                "robot": p.robot,
                "control_mode": env.control_mode,
                "control_freq": env.control_freq,
                "objects": list(spec.objects),
                "source_file": str(p.from_file or "demonstrator"),
                "params": data_params(params, "source"),
            },
        )
        write_metrics(
            tmp_metrics,
            {
                "demos": len(kept),
                "dropped_planner": int(demonstrator_failures),
                "dropped_replay": int(replay_failures),
                "mean_length": float(np.mean([len(s["actions"]) for s in kept])),
                "demonstrator_seeds": int(seeds_tried),
            },
        )
    print(
        f"source: {len(kept)} demos -> {out} ({demonstrator_failures} demonstrator and "
        f"{replay_failures} replay failures dropped)"
    )
