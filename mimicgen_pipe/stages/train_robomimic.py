"""train_robomimic: robomimic 0.3.0's own BC-RNN trained on our robomimic export, at the size
and schedule of our active training profile (params train.<profile>: LSTM width and layers,
window, batch, learning rate, epochs x steps), one run of its first seed, with a checkpoint
every evaluate.every_epochs epochs, so that ``evaluate_external`` rolls its checkpoints out
beside our own learner's on the same demos. The rest of the config is the one given
(configs/robomimic/bc_rnn_low_dim.json: GMM of 5 modes, MimicGen's observation keys).
robomimic runs in the learners' Python (.venv-learners, made by scripts/setup.sh), through
mimicgen_pipe/formats/external/_robomimic_train.py, which also makes its observation normalisation
(--obs normalized) work on sequence datasets."""

from __future__ import annotations

import argparse
import copy
import csv
import json
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

from mimicgen_pipe.core.errors import InputError, StageError
from mimicgen_pipe.core.jsonfile import read_json
from mimicgen_pipe.data.metrics import metrics_identity, write_metrics, write_timings
from mimicgen_pipe.data.outputs import claim, directory_kind, output_set
from mimicgen_pipe.data.params import Params, TrainProfile
from mimicgen_pipe.formats.exporters.robomimic import check_finite
from mimicgen_pipe.formats.external import (
    DEFAULT_PYTHON,
    _robomimic_train,
    check_python,
    format_module,
)
from mimicgen_pipe.sources import robomimic_source
from mimicgen_pipe.stages import add_selection_arguments, stage_params

TRAINER = Path(_robomimic_train.__file__)  # run by path in robomimic's Python
CONFIG = Path(__file__).resolve().parents[2] / "configs/robomimic/bc_rnn_low_dim.json"
CHECKPOINTS = directory_kind("robomimic run", r"model_epoch_\d+\.pth")
# robomimic's log: "Train Epoch <N>" then that epoch's training statistics as a JSON object
EPOCH_LOG = re.compile(r"^Train Epoch (\d+)\n(\{\n.*?\n\})$", re.M | re.S)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument("--dataset", required=True, help="our robomimic export (demos.hdf5)")
    p.add_argument(
        "--config",
        default=str(CONFIG),
        help="robomimic config (algo_name bc) whose sizes and schedule are set from params "
        "(default: the repository's configs/robomimic/bc_rnn_low_dim.json)",
    )
    p.add_argument(
        "--obs",
        choices=("raw", "normalized"),
        default="raw",
        help="observations as stored (robomimic's default), or normalized by robomimic "
        "(train.hdf5_normalize_obs: each key to zero mean, unit std over the training demos, "
        "as our own learner does)",
    )
    p.add_argument("--data", default="D0", help="the reset variant the export's store is of")
    p.add_argument("--out", required=True, help="directory for model_epoch_<N>.pth")
    p.add_argument("--metrics", required=True, help="metrics JSON")
    p.add_argument("--plot", required=True, help="training loss per epoch, CSV")
    p.add_argument("--python", help=f"robomimic's Python (default: {DEFAULT_PYTHON})")


def run_config(
    base: dict[str, Any], prof: TrainProfile, every: int, normalize: bool, dataset: Path,
    output_dir: Path,
) -> dict[str, Any]:  # fmt: skip
    """``base`` with our profile's sizes and schedule, its first seed, a checkpoint every
    ``every`` epochs, the dataset and output folder; rollouts and validation off (robomimic
    cannot build our env, and normalises no validation data)."""
    c = copy.deepcopy(base)
    if c.get("algo_name") != "bc" or not c.get("algo", {}).get("rnn"):
        raise InputError("config: expected robomimic's BC-RNN (algo_name bc, algo.rnn)")
    e, t, a = c["experiment"], c["train"], c["algo"]
    e.update(name="run", validate=False, epoch_every_n_steps=prof.steps_per_epoch)
    e["save"] |= {"enabled": True, "every_n_epochs": every, "on_best_validation": False}
    e["rollout"] = {"enabled": False}
    e["logging"] = {"terminal_output_to_txt": True, "log_tb": False, "log_wandb": False}
    t.update(
        data=str(dataset.resolve()), output_dir=str(output_dir), seed=prof.seeds[0],
        num_epochs=prof.epochs, batch_size=prof.batch_size, seq_length=prof.seq_len,
        hdf5_normalize_obs=normalize, hdf5_filter_key="train", cuda=False,
    )  # fmt: skip
    a["rnn"] |= {"horizon": prof.seq_len, "hidden_dim": prof.hidden, "num_layers": prof.layers}
    a.setdefault("optim_params", {}).setdefault("policy", {})["learning_rate"] = {
        "initial": prof.lr, "decay_factor": 0.1, "epoch_schedule": [],
    }  # fmt: skip
    return c


def epoch_losses(log: str) -> list[tuple[int, float]]:
    """(epoch, mean training loss) of each epoch robomimic logged."""
    return [(int(n), float(json.loads(body)["Loss"])) for n, body in EPOCH_LOG.findall(log)]


def train(python: str, config: dict[str, Any], work: Path) -> tuple[Path, float]:
    """robomimic's training of ``config`` under ``python``, its output (each epoch's
    statistics, its progress bars) passed through: its run folder and wall time [s];
    StageError when it fails."""
    path = work / "config.json"
    path.write_text(json.dumps(config, indent=1))
    t0 = time.perf_counter()
    res = subprocess.run([python, str(TRAINER), "--config", str(path)], check=False)
    if res.returncode != 0:
        raise StageError(
            f"robomimic's training failed (exit {res.returncode}; its output is above)"
        )
    (run,) = (work / "runs/run").iterdir()  # robomimic's <time stamp> folder
    return run, time.perf_counter() - t0


def run(args: argparse.Namespace) -> None:
    params: Params = stage_params(args)
    prof, every = params.train.active, params.evaluate.every_epochs
    if prof.cameras:
        raise InputError(f"train.profile {params.train.profile!r}: an image profile; expected a "
                         "low-dim one")  # fmt: skip
    dataset, out, normalize = Path(args.dataset), Path(args.out), args.obs == "normalized"
    # checked here, in our process: robomimic would follow the file's links to other files
    robomimic_source.check_training_file(dataset)
    check_finite(dataset)  # before robomimic reads it
    base = read_json(args.config, "robomimic config (JSON)")
    if not isinstance(base, dict):
        raise InputError(f"--config {args.config}: expected a JSON object (a robomimic config)")
    python = check_python(args.python or str(DEFAULT_PYTHON))
    claim((out, CHECKPOINTS), Path(args.metrics), Path(args.plot), inputs=[dataset])
    with output_set(out, args.metrics, args.plot) as (tmp_out, tmp_metrics, tmp_plot):
        with tempfile.TemporaryDirectory(prefix=f".{out.name}.work-", dir=tmp_out.parent) as w:
            work = Path(w).resolve()
            config = run_config(base, prof, every, normalize, dataset, work / "runs")
            print(f"train_robomimic: {prof.epochs} epochs x {prof.steps_per_epoch} steps, "
                  f"2x{prof.hidden} LSTM, normalize_obs {normalize} -> {out}")  # fmt: skip
            folder, seconds = train(python, config, work)
            shutil.copytree(folder / "models", tmp_out)
            losses = epoch_losses((folder / "logs/log.txt").read_text())
        with open(tmp_plot, "w", newline="") as f:
            csv.writer(f).writerows([("epoch", "loss"), *losses])
        fmt = format_module("robomimic")
        saved = [fmt.checkpoint_epoch(p) for p in fmt.run_checkpoints(tmp_out)]
        identity = metrics_identity("train", params.task, params.backend,
                                    params.generate.robot, data=args.data)  # fmt: skip
        write_metrics(tmp_metrics, identity | {
            "profile": f"robomimic 0.3.0 ({params.train.profile} size)",
            "normalize_obs": normalize, "seeds": 1, "seed": prof.seeds[0],
            "epochs": prof.epochs, "gradient_steps": prof.epochs * prof.steps_per_epoch,
            "checkpoint_epochs": saved, "final_loss": losses[-1][1] if losses else None,
            "dataset": str(dataset),
        })  # fmt: skip
    write_timings(args.metrics, identity, {"wall_seconds": seconds})
    print(f"train_robomimic: checkpoints of epochs {saved} -> {out}")
