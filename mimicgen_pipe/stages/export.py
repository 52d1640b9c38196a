"""export: a generated (or source) store as robomimic HDF5, a LeRobot dataset and ManiSkill
trajectory files (export.formats), all in one output directory."""

from __future__ import annotations

import argparse
import functools
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.metrics import metrics_identity, split_timings, write_metrics, write_timings
from mimicgen_pipe.data.outputs import claim, free_space_error, output_set
from mimicgen_pipe.data.store import EpisodeStore, store_cameras
from mimicgen_pipe.formats import exporters
from mimicgen_pipe.formats.exporters import ExportJob
from mimicgen_pipe.run.executors import Executor, map_blocks
from mimicgen_pipe.stages import add_selection_arguments, output_path, stage_params

REPLAYS_PER_BLOCK = 8  # episodes replayed on one scene (ManiSkill trajectory format)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument("--variant", help="export data/generated/<task>_<variant>.zarr")
    p.add_argument("--store", help="the store to export instead (generated, failed or source)")
    p.add_argument("--out", help="output directory (default: data/export/<store name>)")
    p.add_argument("--formats", help="comma-separated formats (default: export.formats)")
    p.add_argument("--metrics", help="metrics JSON (default: metrics/export_<store name>.json)")


def resolve(args: argparse.Namespace) -> ExportJob:
    """The export run ``args`` ask for: the params, the formats, the store read (but for
    its images) and checked for every format, and its success after every step where the
    back end gives it; writes nothing."""
    params = stage_params(args)
    if (args.store is None) == (args.variant is None):
        raise InputError("give either --variant (a generated store) or --store")
    store_path = Path(args.store or layout.generated_store(params.task, args.variant))
    formats = args.formats.split(",") if args.formats else list(params.export.formats)
    for fmt in formats:
        exporters.exporter(fmt)  # InputError naming the formats for an unknown one
    store = exporters.read(store_path, params.task)  # images stay on disk, read per episode
    name = store_path.name.removesuffix(".zarr")
    out = output_path(args.out, layout.export_dir(name))
    metrics_path = output_path(args.metrics, layout.metrics_file("export", name))
    spec = backends.task_spec(store.attrs["backend"], params.task)
    info = exporters.export_info(
        store.attrs, spec, params.train.obs_keys, params.train.val_fraction
    )
    for fmt in formats:  # every format's check before anything is written
        exporters.check(store, fmt, info)
    step_success = _step_success(store) if params.export.step_success else None
    replays = functools.partial(
        _maniskill_replays, store, params.export.workers, params.maniskill.lean_step
    )
    return ExportJob(
        task=params.task,
        store_path=store_path,
        store=store,
        formats=tuple(formats),
        info=info,
        step_success=step_success,
        maniskill_replays=replays if "maniskill" in formats else None,
        out=out,
        metrics_path=metrics_path,
    )


def run(job: ExportJob) -> None:
    store, out = job.store, job.out
    claim((out, exporters.export_dir_kind()), job.metrics_path, inputs=[job.store_path])
    # HDF5 cannot be stopped cleanly on a full disk (it may crash the process): make sure
    # beforehand that every format's arrays fit uncompressed (once claiming has removed
    # what killed runs left beside the output)
    arrays = [*store.data.values(), *store.episodes.values()]
    pixels = sum(h * w for h, w in store_cameras(store.attrs).values())
    images = int(store.lengths.sum()) * pixels * 3
    error = free_space_error(out, len(job.formats) * (sum(a.nbytes for a in arrays) + images))
    if error is not None:
        raise error
    a = store.attrs
    identity = metrics_identity(
        "export", job.task, a["backend"], a.get("robot"), variant=a.get("variant")
    )
    with output_set(job.metrics_path, out) as (tmp_metrics, tmp_out):
        metrics, timings = split_timings(exporters.export(job, tmp_out))
        write_metrics(tmp_metrics, identity | metrics)
    write_timings(job.metrics_path, identity, timings)
    print(f"export: {store.n_episodes} episodes of {job.store_path} -> {out}")


def _step_success(store: EpisodeStore) -> np.ndarray | None:
    """(N_steps,) bool: the task's success after every step, on a back end that restores
    states cheaply (contracts.Backend's RESTORES_CHEAPLY): each stored state but an episode's
    first set in an env and checked, the last step's the episode's ``success``; None on
    another back end. InputError for states of another width than the env's."""
    a = store.attrs
    if not getattr(backends.backend_package(a["backend"]), "RESTORES_CHEAPLY", False):
        return None
    env = backends.make_env(a["backend"], a["task"], a["robot"])
    states = store.data["env_state"]
    width = int(np.size(env.get_state()))
    if states.shape[1:] != (width,):
        env.close()
        raise InputError(
            f"{store.path}: data/env_state has {states.shape[1:]} values a step, expected "
            f"({width},) (the {a['backend']} {a['task']} env's state); export.step_success: "
            "false exports it without the success of every step"
        )
    success = np.zeros(len(states), bool)
    ends = store.episode_ends
    episode_success = store.episodes.get("success", np.ones(store.n_episodes, bool))
    for i in tqdm(range(store.n_episodes), desc="export: success of every step", unit="episode"):
        for row in range(int(store.episode_starts[i]) + 1, int(ends[i])):
            env.set_state(states[row])
            success[row - 1] = env.is_success()
        success[ends[i] - 1] = episode_success[i]
    env.close()
    return success


def _maniskill_replays(store: EpisodeStore, workers: int, lean_step: bool) -> dict[str, Any]:
    """The replays, state layout and env_info that the ManiSkill format writes."""
    from mimicgen_pipe.backends.maniskill import trajectory

    env = backends.make_env("maniskill", store.attrs["task"], store.attrs["robot"])
    state_layout = trajectory.state_layout(env)
    env_info = trajectory.env_info(env, env.spec.horizon)
    env.close()
    episodes = [
        (ep["env_state"][0], ep["actions"]) for ep in map(store.episode, range(store.n_episodes))
    ]
    job = trajectory.ReplayJob(store.attrs["task"], store.attrs["robot"], lean_step)
    # each block replays on a freshly rebuilt scene, as generation's
    blocks = [
        episodes[i : i + REPLAYS_PER_BLOCK] for i in range(0, len(episodes), REPLAYS_PER_BLOCK)
    ]
    results = map_blocks(
        trajectory.replay_block, blocks, Executor("local", workers), trajectory.init_worker, (job,)
    )
    replays = []
    with tqdm(total=len(episodes), desc="export: replaying in ManiSkill", unit="episode") as bar:
        try:
            for block in results:
                replays += block
                bar.update(len(block))
        finally:
            results.close()
    return {"replays": replays, "layout": state_layout, "env_info": env_info}
