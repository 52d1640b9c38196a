"""The paper's generation ablations as saved runs: for each, pose_noise -> generate ->
coverage with params.yaml plus the run's overrides, a fixed number of attempts on one variant.

    python benchmarks/ablations.py [--variant D1] [--attempts 200] [--workers 1]
        [--only default action_noise_0 ...] [--list]
    python benchmarks/ablations.py --task pull_cube_tool --action-noise 0.025 \
        --save suite/metrics/ablations/pull_cube_tool --work data/suite_ablations/pull_cube_tool

Each run saves its params.yaml and metrics under metrics/ablations/<name>/ (what the report
stage reads, comparing every run with the one that has params.yaml's settings; a suite task's
runs go under suite/metrics/ablations/<task>/, read by `report --suite`) and its stores under
data/ablations/<name>/. Every run uses the same attempt seeds unless it changes
the seed, so runs see the same scenes and their DGRs are compared pair by pair. The same
ablations as experiments of the pipeline: docs/workflow.md.
"""

from __future__ import annotations

import argparse
import copy
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import yaml

from mimicgen_pipe.data import layout
from mimicgen_pipe.data.params import load_params

# name -> (what it measures, params overrides)
RUNS: dict[str, tuple[str, dict[str, Any]]] = {
    "default": ("params.yaml's settings: the base of every delta", {}),
    "action_noise_0": (
        "action noise sigma 0 instead of 0.05 (Table M.1)",
        {"generate": {"action_noise": 0.0}},
    ),
    "nearest_neighbor": (
        "nearest-neighbour selection, once per episode (Table M.2)",
        {"generate": {"selection": "nearest_neighbor"}},
    ),
    "per_subtask": (
        "random selection per subtask (Table M.2)",
        {"generate": {"per_subtask": True}},
    ),
    "nearest_neighbor_per_subtask": (
        "nearest-neighbour selection per subtask, the paper's Stack setting (Table M.2)",
        {"generate": {"selection": "nearest_neighbor", "per_subtask": True}},
    ),
    "nearest_neighbor_robot_distance_per_subtask": (
        "nearest-neighbour selection by the end effector's distance to each segment's start, "
        "per subtask (MimicGen's nearest_neighbor_robot_distance; not in the paper's tables)",
        {"generate": {"selection": "nearest_neighbor_robot_distance", "per_subtask": True}},
    ),
    "interpolation_25_25": (
        "n_interp 25, n_fixed 25 instead of 5, 0 (Appendix G)",
        {"generate": {"n_interp": 25, "n_fixed": 25}},
    ),
    "pose_noise_L1": ("pose noise 5 mm / 5 deg (Table T.1)", {"pose_noise": {"level": "L1"}}),
    "pose_noise_L2": ("pose noise 10 mm / 10 deg (Table T.1)", {"pose_noise": {"level": "L2"}}),
    "seed_1": ("generation seed 1 (Table S.1)", {"generate": {"seed": 1}}),
    "seed_2": ("generation seed 2 (Table S.1)", {"generate": {"seed": 2}}),
}


def merged(base: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merged(out[key], value)
        else:
            out[key] = value
    return out


def stage(*args: str) -> None:
    cmd = [sys.executable, "-m", "mimicgen_pipe.cli", *args]
    print("$ mimicgen-pipe " + " ".join(args), flush=True)
    subprocess.run(cmd, check=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--params", default="params.yaml", help="base params (default: params.yaml)")
    p.add_argument("--task", help="task (default: the params file's)")
    p.add_argument(
        "--action-noise", type=float, help="base action noise (default: the params file's)"
    )
    p.add_argument("--variant", default="D1")
    p.add_argument("--attempts", type=int, default=200, help="attempts per run (default: 200)")
    p.add_argument("--workers", type=int, default=1, help="simulator processes per run")
    p.add_argument("--only", nargs="+", choices=list(RUNS), help="runs to do (default: all)")
    p.add_argument("--parsed", help="clean parsed store (default: data/parsed/<task>.zarr)")
    p.add_argument("--save", default=str(layout.ablations_dir()), help="metrics folder")
    p.add_argument("--work", default="data/ablations", help="stores folder")
    p.add_argument("--list", action="store_true", help="list the runs and exit")
    args = p.parse_args()
    if args.list:
        for name, (what, overrides) in RUNS.items():
            print(f"{name:30s} {what}  {overrides}")
        return
    base = yaml.safe_load(Path(args.params).read_text())
    if args.task:
        base["task"] = args.task
    if args.action_noise is not None:
        base["generate"]["action_noise"] = args.action_noise
    task = base.get("task", load_params(args.params).task)
    parsed = args.parsed or str(layout.parsed_store(task))
    size = {
        "generate": {
            "variants": [args.variant],
            "mode": "fixed_attempts",
            "max_attempts": args.attempts,
            "workers": args.workers,
        }
    }
    for name in args.only or list(RUNS):
        what, overrides = RUNS[name]
        save, work = Path(args.save) / name, Path(args.work) / name
        save.mkdir(parents=True, exist_ok=True)
        params_file = save / "params.yaml"
        params_file.write_text(
            f"# ablation run {name}: {what}\n"
            + yaml.safe_dump(merged(merged(base, overrides), size), sort_keys=False)
        )
        load_params(params_file)  # bad overrides fail here, before any work
        t0 = time.perf_counter()
        store = work / f"{task}_{args.variant}.zarr"
        stage(
            "pose_noise",
            "--params",
            str(params_file),
            "--parsed",
            parsed,
            "--out",
            str(work / "pose_noise.zarr"),
        )
        stage(
            "generate", "--params", str(params_file), "--variant", args.variant,
            "--parsed", str(work / "pose_noise.zarr"), "--out", str(store),
            "--metrics", str(save / f"generate_{task}_{args.variant}.json"),
        )  # fmt: skip
        stage(
            "coverage", "--params", str(params_file), "--variant", args.variant,
            "--generated", str(store),
            "--metrics", str(save / f"coverage_{task}_{args.variant}.json"),
            "--table", str(work / f"coverage_{task}_{args.variant}.csv"),
            "--heatmap", str(work / f"coverage_{task}_{args.variant}.png"),
        )  # fmt: skip
        print(f"ablation {name}: {time.perf_counter() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    main()
