"""What an image-based agent (the paper's Table E.2) costs on this machine, against a
low-dim one (Table E.3): seconds per gradient step of robomimic's BC-RNN with the image
config (configs/robomimic/bc_rnn_image.json: ResNet18 encoder per camera, 2x1000 LSTM,
batch 16) and with the low-dim config (bc_rnn_low_dim.json: 2x400 LSTM, batch 100), both
trained by robomimic's own train.py in the learners' virtualenv on the robomimic export of
the same few observed demos; the observe stage's wall seconds per step for their images
(its ``workers``). From them, the hours the paper's profiles take here: images for 1000
demos, 600 epochs x 500 steps (image) and 2000 x 100 (low-dim) of training per policy.

Then this project's image profile (params.yaml's train.cpu_image) on the same observed
demos: seconds per gradient step of the train stage (the median over epochs 2..), and
seconds per rollout step of the evaluate stage with its cameras rendered in one worker (an
untrained policy's episodes run the whole horizon); from them, the hours of its training
per seed and of rolling out one checkpoint for evaluate.episodes episodes at most.
Written to metrics/benchmarks/image_agent.json.

The demos are the first ``--episodes`` of a generated stack_cube store (default: the
default pipeline's D0 store), observed with the image config's cameras at 84x84. An epoch's
time is robomimic's own (``Time_Epoch``); the first epoch is a warm-up and is not counted.

    python benchmarks/image_agent.py --episodes 4 --epochs 3 --steps 20
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml
from _machine import figures_path, machine

from mimicgen_pipe.data.metrics import timings_file
from mimicgen_pipe.data.store import open_store

REPO = Path(__file__).resolve().parent.parent
LEARNERS = REPO / ".venv-learners" / "bin" / "python"
# the paper's profiles (robomimic's defaults, paper Appendix N): epochs x steps per epoch
PAPER_STEPS = {"image": 600 * 500, "low_dim": 2000 * 100}


def run(*args: str, cwd: Path, env: dict | None = None) -> str:
    """Run a command; its stdout, or a RuntimeError with its last output."""
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(args[:3])}: exit {done.returncode}\n{done.stderr[-2000:]}")
    return done.stdout


def epoch_minutes(stdout: str) -> list[float]:
    """robomimic's Time_Epoch [min] of every epoch train.py printed."""
    blocks = re.findall(r"^Train Epoch \d+\n(\{.*?^\})", stdout, re.M | re.S)
    return [json.loads(b)["Time_Epoch"] for b in blocks]


def seconds_per_step(name: str, dataset: Path, work: Path, epochs: int, steps: int) -> float:
    """Median seconds per gradient step over epochs 2.. of robomimic's train.py with
    configs/robomimic/<name>.json, only its run length and output folder changed."""
    config = json.loads((REPO / "configs/robomimic" / f"{name}.json").read_text())
    config["train"] |= {"output_dir": str(work / name), "num_epochs": epochs}
    config["experiment"]["epoch_every_n_steps"] = steps
    config["experiment"]["save"]["enabled"] = False
    path = work / f"{name}.json"
    path.write_text(json.dumps(config, indent=4))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env |= {"WANDB_MODE": "disabled", "MPLCONFIGDIR": str(work / "mpl")}
    out = run(str(LEARNERS), "-m", "robomimic.scripts.train", "--config", str(path),
              "--dataset", str(dataset), cwd=work, env=env)  # fmt: skip
    minutes = epoch_minutes(out)
    if len(minutes) != epochs:
        raise RuntimeError(f"{name}: {len(minutes)} of {epochs} epochs logged")
    return statistics.median(minutes[1:]) * 60 / steps


def image_keys() -> list[str]:
    """The image config's camera observations (robomimic's ``rgb`` modality)."""
    config = json.loads((REPO / "configs/robomimic/bc_rnn_image.json").read_text())
    return config["observation"]["modalities"]["obs"]["rgb"]


def cpu_image_costs(
    cli: str, work: Path, params: dict, episodes: int, epochs: int, steps: int
) -> dict[str, float]:
    """The train.cpu_image profile's seconds per gradient step (its own threads) and per
    rollout step (cameras rendered, one worker, torch on one thread as in every evaluate
    worker) on ``work``'s observed.zarr, and the hours its full schedule and one checkpoint's
    rollouts take at those rates."""
    profile = params["train"]["cpu_image"]
    run_params = dict(params)
    run_params["train"] = params["train"] | {
        "profile": "cpu_image",
        "num_demos": episodes,
        "val_fraction": 0.0,
        "cpu_image": profile | {"epochs": epochs, "steps_per_epoch": steps,
                                "checkpoint_every": epochs, "seeds": [0]},
    }  # fmt: skip
    run_params["evaluate"] = params["evaluate"] | {"episodes": 1, "every_epochs": epochs,
                                                   "workers": 1}  # fmt: skip
    (work / "cpu_image.yaml").write_text(yaml.safe_dump(run_params))
    common = ("--params", "cpu_image.yaml", "--backend", "maniskill", "--task", "stack_cube")
    run(cli, "train", *common, "--data", "D0_image", "--store", "observed.zarr",
        "--out", "policy", "--metrics", "train.json", "--plot", "train.csv", cwd=work)  # fmt: skip
    timed = json.loads(timings_file(work / "train.json").read_text())
    seconds = [t for _, _, t in timed["epoch_seconds"]]  # one training seed
    per_step = statistics.median(b - a for a, b in zip(seconds, seconds[1:], strict=False)) / steps
    run(cli, "evaluate", *common, "--data", "D0_image", "--variant", "D0", "--policies",
        "policy", "--metrics", "eval.json", "--plot", "eval.csv", cwd=work)  # fmt: skip
    evaluated = json.loads((work / "eval.json").read_text())
    if evaluated["success_rate_max"] > 0:
        raise RuntimeError("the untrained policy succeeded: its episode ran short of the horizon")
    timed = json.loads(timings_file(work / "eval.json").read_text())
    rollout_step = timed["seconds_per_episode"] / evaluated["horizon"]
    total_steps = profile["epochs"] * profile["steps_per_epoch"]
    rollout_episodes = params["evaluate"]["episodes"]
    return {
        "cpu_image_channels": profile["channels"],
        "cpu_image_batch_size": profile["batch_size"],
        "cpu_image_threads": profile["threads"],
        "cpu_image_seconds_per_step": round(per_step, 4),
        "cpu_image_rollout_seconds_per_step": round(rollout_step, 4),
        "hours_cpu_image_profile_per_seed": round(per_step * total_steps / 3600, 2),
        "hours_cpu_image_rollouts_per_checkpoint": round(
            rollout_step * evaluated["horizon"] * rollout_episodes / 3600, 2
        ),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--store", type=Path, default=REPO / "data/generated/stack_cube_D0.zarr")
    ap.add_argument("--episodes", type=int, default=4, help="demos observed and trained on")
    ap.add_argument("--epochs", type=int, default=3, help="epochs per config (first: warm-up)")
    ap.add_argument("--steps", type=int, default=20, help="gradient steps per epoch")
    a = ap.parse_args()
    if not LEARNERS.exists():
        sys.exit(f"{LEARNERS}: missing; scripts/setup.sh makes the learners' virtualenv")
    if a.epochs < 2:
        sys.exit("--epochs: at least 2 (the first is a warm-up)")
    # the demos' length before any work: a store that is not one fails here
    steps_per_demo = float(np.median(open_store(a.store, kind="generated").lengths))
    keys = image_keys()
    cli = str(Path(sys.executable).parent / "mimicgen-pipe")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        params = yaml.safe_load((REPO / "params.yaml").read_text())
        # our camera names: robomimic calls the wrist camera robot0_eye_in_hand (the export)
        cameras = [k.removesuffix("_image").removeprefix("robot0_") for k in keys]
        params["observe"] |= {"cameras": cameras, "height": 84, "width": 84,
                              "episodes": a.episodes}  # fmt: skip
        params["export"]["formats"] = ["robomimic"]
        (work / "params.yaml").write_text(yaml.safe_dump(params))
        run(cli, "observe", "--backend", "maniskill", "--task", "stack_cube", "--variant",
            "D0", "--store", str(a.store), "--out", "observed.zarr", "--metrics",
            "observe.json", cwd=work)  # fmt: skip
        observed = json.loads((work / "observe.json").read_text())
        observed_seconds = json.loads(timings_file(work / "observe.json").read_text())["seconds"]
        run(cli, "export", "--backend", "maniskill", "--task", "stack_cube", "--store",
            "observed.zarr", "--out", "export", "--metrics", "export.json", cwd=work)  # fmt: skip
        dataset = work / "export" / "demos.hdf5"
        per_step = {n: seconds_per_step(f"bc_rnn_{n}", dataset, work, a.epochs, a.steps)
                    for n in PAPER_STEPS}  # fmt: skip
        frames = int(observed["frames"])
        ours = cpu_image_costs(cli, work, params, a.episodes, a.epochs, a.steps)

    render_s = observed_seconds / frames  # the stage's wall time, both workers
    figures = {
        **machine(),
        "episodes": a.episodes,
        "observed_steps": frames,
        "epochs": a.epochs,
        "steps_per_epoch": a.steps,
        "cameras": keys,
        "observe_seconds_per_step": round(render_s, 4),
        "seconds_per_step_image": round(per_step["image"], 4),
        "seconds_per_step_low_dim": round(per_step["low_dim"], 4),
        "image_over_low_dim": round(per_step["image"] / per_step["low_dim"], 1),
        "median_demo_steps": steps_per_demo,
        "hours_observe_1000_demos": round(render_s * steps_per_demo * 1000 / 3600, 1),
        "hours_paper_profile_image": round(per_step["image"] * PAPER_STEPS["image"] / 3600, 1),
        "hours_paper_profile_low_dim": round(
            per_step["low_dim"] * PAPER_STEPS["low_dim"] / 3600, 1
        ),
        **ours,
        "robomimic_image_over_cpu_image": round(
            per_step["image"] / ours["cpu_image_seconds_per_step"], 1
        ),
    }
    for k, v in figures.items():
        print(f"{k}: {v}")
    path = figures_path(__file__)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(figures, indent=1) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
