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
import csv
import shutil
import tempfile
from pathlib import Path

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.jsonfile import read_json
from mimicgen_pipe.data.metrics import metrics_identity, write_metrics, write_timings
from mimicgen_pipe.data.outputs import claim, directory_kind, output_set
from mimicgen_pipe.formats.exporters.robomimic import check_finite
from mimicgen_pipe.formats.external import (
    DEFAULT_PYTHON,
    TrainRobomimicJob,
    check_bc_rnn,
    check_python,
    epoch_losses,
    format_module,
    train_robomimic,
)
from mimicgen_pipe.sources import robomimic_source
from mimicgen_pipe.stages import add_selection_arguments, stage_params

CONFIG = Path(__file__).resolve().parents[2] / "configs/robomimic/bc_rnn_low_dim.json"
CHECKPOINTS = directory_kind("robomimic run", r"model_epoch_\d+\.pth")


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


def resolve(args: argparse.Namespace) -> TrainRobomimicJob:
    """The train_robomimic run ``args`` ask for: the params (a low-dim profile), the
    dataset checked, the config read (robomimic's BC-RNN) and robomimic's Python; writes
    nothing."""
    params = stage_params(args)
    prof = params.train.active
    if prof.cameras:
        raise InputError(f"train.profile {params.train.profile!r}: an image profile; expected a "
                         "low-dim one")  # fmt: skip
    dataset = Path(args.dataset)
    # checked here, in our process: robomimic would follow the file's links to other files
    robomimic_source.check_training_file(dataset)
    check_finite(dataset)  # before robomimic reads it
    base = read_json(args.config, "robomimic config (JSON)")
    if not isinstance(base, dict):
        raise InputError(f"--config {args.config}: expected a JSON object (a robomimic config)")
    python = check_python(args.python or str(DEFAULT_PYTHON))
    check_bc_rnn(base)
    return TrainRobomimicJob(
        task=params.task,
        backend=params.backend,
        robot=params.generate.robot,
        data=args.data,
        profile_name=params.train.profile,
        profile=prof,
        every_epochs=params.evaluate.every_epochs,
        normalize=args.obs == "normalized",
        dataset=dataset,
        config=base,
        python=python,
        out=Path(args.out),
        metrics_path=Path(args.metrics),
        plot=Path(args.plot),
    )


def run(job: TrainRobomimicJob) -> None:
    prof, out = job.profile, job.out
    claim((out, CHECKPOINTS), job.metrics_path, job.plot, inputs=[job.dataset])
    with output_set(out, job.metrics_path, job.plot) as (tmp_out, tmp_metrics, tmp_plot):
        with tempfile.TemporaryDirectory(prefix=f".{out.name}.work-", dir=tmp_out.parent) as w:
            print(f"train_robomimic: {prof.epochs} epochs x {prof.steps_per_epoch} steps, "
                  f"2x{prof.hidden} LSTM, normalize_obs {job.normalize} -> {out}")  # fmt: skip
            folder, seconds = train_robomimic(job, Path(w).resolve())
            shutil.copytree(folder / "models", tmp_out)
            losses = epoch_losses((folder / "logs/log.txt").read_text())
        with open(tmp_plot, "w", newline="") as f:
            csv.writer(f).writerows([("epoch", "loss"), *losses])
        fmt = format_module("robomimic")
        saved = [fmt.checkpoint_epoch(p) for p in fmt.run_checkpoints(tmp_out)]
        identity = metrics_identity("train", job.task, job.backend, job.robot, data=job.data)
        write_metrics(tmp_metrics, identity | {
            "profile": f"robomimic 0.3.0 ({job.profile_name} size)",
            "normalize_obs": job.normalize, "seeds": 1, "seed": prof.seeds[0],
            "epochs": prof.epochs, "gradient_steps": prof.epochs * prof.steps_per_epoch,
            "checkpoint_epochs": saved, "final_loss": losses[-1][1] if losses else None,
            "dataset": str(job.dataset),
        })  # fmt: skip
    write_timings(job.metrics_path, identity, {"wall_seconds": seconds})
    print(f"train_robomimic: checkpoints of epochs {saved} -> {out}")
