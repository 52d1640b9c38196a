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
from mimicgen_pipe.outputs import claim, output_set, store_kind
from mimicgen_pipe.params import Params, data_params
from stages import add_selection_arguments, stage_params


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument("--out", help="output store (default: data/source/<task>.zarr)")
    p.add_argument("--metrics", help="metrics JSON (default: metrics/source_<task>.json)")


# the demonstrator draws seeds until num_demos demos replay to success, at most this many
# seeds per demo asked for (plug_charger, the hardest planner here, needs about 4.5)
SEEDS_PER_DEMO = 20


def check_source_file(params: Params, params_path: str) -> int:
    """Read and check every episode of ``source.from_file`` (not None) before the simulator
    starts, as the back end's reader will: a robomimic ``.hdf5``/``.hdf`` on either back
    end, a ManiSkill trajectory ``.h5`` with its ``.json`` on maniskill. Returns the number
    of episodes; InputError naming the file and key when it is unreadable or broken, or has
    fewer episodes than source.num_demos (of which the first num_demos are used)."""
    p = params.source
    assert p.from_file is not None
    if Path(p.from_file).suffix.lower() in (".hdf5", ".hdf"):
        from mimicgen_pipe.exporters import robomimic

        n = len(robomimic.read(p.from_file, params.backend, params.task))
    elif params.backend == "maniskill":
        from envs.maniskill.source import read_trajectory_file

        n = len(read_trajectory_file(p.from_file, params.task))
    else:
        raise InputError(
            f"{params_path}: source.from_file: {p.from_file}: ManiSkill trajectory files (.h5) "
            f"are read on the maniskill back end only; on {params.backend} give a robomimic "
            ".hdf5 (as the export stage writes) or null for the scripted demonstrator"
        )
    if n < p.num_demos:
        raise InputError(
            f"{p.from_file}: {n} episode{'s' if n != 1 else ''}, fewer than source.num_demos "
            f"= {p.num_demos} in {params_path}; ask for {n} or fewer, or give a file with more"
        )
    return n


def run(args: argparse.Namespace) -> None:
    params = stage_params(args)
    spec = envs.task_spec(params.backend, params.task)
    p = params.source
    envs.check_robot(params.backend, p.robot)
    if p.from_file is not None:  # read and checked whole before the simulator starts
        check_source_file(params, args.params)
    out = Path(args.out or layout.source_store(params.task))
    metrics_path = Path(args.metrics or layout.metrics_file("source", params.task))
    given = [p.from_file, str(Path(p.from_file).with_suffix(".json"))] if p.from_file else []
    # fails at once if another run writes them, or if they would replace anything else
    claim((out, store_kind("source")), metrics_path, inputs=given)
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
            f"source.seed = {p.seed} ({demonstrator_failures} seeds without a usable demo, "
            f"{replay_failures} demos failed on replay); ask for fewer demos or look at the "
            "demonstrator"
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
