"""report: report.md and report.html from the metrics present, beside the paper's numbers:
the default pipeline's (metrics/, plots/, media/ -> report/, with summary.json, its headline
numbers, and the figures of its policies over training) or, with --suite, the task suite's
(suite/metrics/ -> suite/report/), with --transit, linear vs planned transit's
(transit/metrics/ -> transit/report/), with --transfer, robot transfer's
(transfer/metrics/ -> transfer/report/), or, with --images, the image agents'
(images/metrics/ -> images/report/). Each writes its headline numbers to summary.json."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from mimicgen_pipe import backends
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.outputs import atomic_directory, claim, directory_kind
from mimicgen_pipe.data.params import Params
from mimicgen_pipe.report import (
    ReportJob,
    build_images_report,
    build_report,
    build_suite_report,
    build_transfer_report,
    build_transit_report,
    write_report,
)
from mimicgen_pipe.report.blocks import Block
from mimicgen_pipe.report.curves import FIGURES, draw_curves, read_curves
from mimicgen_pipe.report.inputs import (
    MetricsSet,
    link,
    read_heatmaps,
    read_media,
    read_metrics_folder,
    read_runs,
)
from mimicgen_pipe.report.machines import machine_blocks, read_machines
from mimicgen_pipe.report.outside import ROBOMIMIC
from mimicgen_pipe.report.paper import PaperResults, load_paper_results
from mimicgen_pipe.report.profiles import read_made_by, read_profile_runs
from mimicgen_pipe.report.scaling import DATASET_SIZE, SCALING, draw_dataset_size
from mimicgen_pipe.report.summary import (
    SUMMARY,
    headline_numbers,
    images_headline_numbers,
    suite_headline_numbers,
    transfer_headline_numbers,
    transit_headline_numbers,
)
from mimicgen_pipe.stages import add_selection_arguments, output_path, stage_params

REPORT_FILES = ("report.md", "report.html", SUMMARY, *FIGURES, DATASET_SIZE)
# what the stage writes; heat-map copies (coverage_*.png) in a report folder are replaced
# with it, not refused
REPORT_DIR = directory_kind(
    "report directory", "|".join(map(re.escape, REPORT_FILES)) + r"|coverage_[^/]+\.png"
)
SUITE = Path("suite")  # the task suite's metrics/ and report/ (suite/dvc.yaml)
TRANSIT = Path("transit")  # linear vs planned transit's (transit/dvc.yaml)
TRANSFER = Path("transfer")  # robot transfer's (transfer/dvc.yaml)
IMAGES = Path("images")  # the image agents' (images/dvc.yaml)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    which = p.add_mutually_exclusive_group()
    which.add_argument(
        "--suite",
        action="store_true",
        help="the task suite's report (params suite.*: DGR, object transfer, policies, "
        "ablations) instead of the default pipeline's",
    )
    which.add_argument(
        "--transit",
        action="store_true",
        help="linear vs planned transit's report (params planned_transit.*) instead",
    )
    which.add_argument(
        "--transfer",
        action="store_true",
        help="robot transfer's report (params transfer.*: DGR per arm, policies) instead",
    )
    which.add_argument(
        "--images",
        action="store_true",
        help="the image agents' report (source and generated D0 demos, beside the paper's "
        "Fig. 4) instead",
    )
    p.add_argument(
        "--metrics",
        help="metrics folder (default: metrics, or suite/, transit/, transfer/ or images/metrics)",
    )
    p.add_argument(
        "--ablations",
        help="ablation runs, one folder each with params.yaml and metrics JSON files "
        "(default: <metrics>/ablations; with --suite one folder of runs per task in it)",
    )
    p.add_argument(
        "--plots",
        help="folder of the coverage heat maps and the train and evaluate CSVs (default: "
        "plots, beside the params file's metrics; the suite's report has none)",
    )
    p.add_argument(
        "--paper",
        default="reference/paper_results.yaml",
        help="the paper's numbers (default: reference/paper_results.yaml)",
    )
    p.add_argument(
        "--out",
        help="report folder (default: report, or suite/, transit/, transfer/ or images/report)",
    )


def resolve(args: argparse.Namespace) -> ReportJob:
    """The report ``args`` ask for, composed: the params, the paper's numbers, the metrics,
    plots, media and ablation runs read and checked, its blocks, figures and headline
    numbers made; writes nothing."""
    params = stage_params(args)
    suite, transit, transfer, images_ = args.suite, args.transit, args.transfer, args.images
    homes = ((suite, SUITE), (transit, TRANSIT), (transfer, TRANSFER), (images_, IMAGES))
    home = next((h for chosen, h in homes if chosen), None)  # None: the default pipeline's
    metrics_dir = Path(args.metrics or (home / "metrics" if home else layout.metrics_dir()))
    plots_dir = Path(args.plots or layout.plots_dir())
    ablations_dir = Path(args.ablations or metrics_dir / layout.ablations_dir().name)
    out = output_path(args.out, home / "report" if home else layout.report_dir())
    paper = load_paper_results(args.paper)
    ms = read_metrics_folder(metrics_dir)
    images: dict[str, bytes] = {}  # image path in the report -> PNG bytes embedded in the HTML
    figures: dict[str, bytes] = {}  # figure file written beside the report -> PNG bytes
    if transfer:
        t = params.transfer
        specs = [backends.task_spec(t.backend, task) for task in t.policy_tasks]
        blocks = build_transfer_report(params, specs, ms, paper)
        summary = transfer_headline_numbers(params, ms)
        title, runs = "Robot transfer", 0
    elif images_:
        spec = backends.task_spec(params.backend, params.task)
        blocks = build_images_report(params, spec, ms, paper)
        summary = images_headline_numbers(params, ms)
        title, runs = f"Image agents on {params.task}", 0
    elif transit:
        blocks = build_transit_report(params, ms)
        summary = transit_headline_numbers(params, ms)
        title, runs = "Linear vs planned transit", 0
    elif suite:
        blocks, figures, summary, runs = _suite(params, ms, metrics_dir, ablations_dir, paper)
        images, title = dict(figures), "MimicGen task suite"
    else:
        variants = params.generate.variants
        heatmaps = read_heatmaps(plots_dir, params.task, variants)
        # referred to where the coverage stage writes them, embedded in the HTML
        names = {v: link(png, out) for v, png in heatmaps.items()}
        figures = draw_curves(params.task, *read_curves(ms, params, plots_dir))
        images = {names[v]: png.read_bytes() for v, png in heatmaps.items()} | figures
        media = read_media(ms, params.task, params.backend, variants)
        spec = backends.task_spec(params.backend, params.task)
        ablations_run = read_runs(ablations_dir)
        blocks = build_report(params, spec, ms, ablations_run, paper, names, media, list(figures))
        summary = headline_numbers(params, ms)
        title, runs = f"MimicGen on {params.task}", len(ablations_run)
    # last, in every report: the CPU types its results were made on (their timings files,
    # which no stage declares: they change at every run)
    blocks = [*blocks, *machine_blocks(read_machines(metrics_dir))]
    return ReportJob(title, tuple(blocks), images, figures, summary, len(ms.files), runs,
                     metrics_dir, plots_dir, out)  # fmt: skip


def run(job: ReportJob) -> None:
    # fails at once if another run writes the report, or if out holds anything else
    claim((job.out, REPORT_DIR), inputs=[job.metrics_dir, job.plots_dir])
    with atomic_directory(job.out) as tmp:
        write_report(job, tmp)
    heatmaps = len(job.images) - len(job.figures)
    print(
        f"report: {job.metrics_files} metrics files, {job.ablation_runs} ablation runs, "
        f"{heatmaps} heat maps, {len(job.figures)} figures -> {job.out}"
    )


def _suite(
    params: Params, ms: MetricsSet, metrics_dir: Path, ablations_dir: Path, paper: PaperResults
) -> tuple[list[Block], dict[str, bytes], dict[str, float], int]:
    """The suite's report blocks, its figures, headline numbers and number of ablation runs."""
    u = params.suite
    specs = [backends.task_spec(u.backend, task) for task in u.tasks]
    ablations = {task: read_runs(ablations_dir / task) for task in u.tasks}
    scaling_dir = metrics_dir / SCALING
    scaling = read_metrics_folder(scaling_dir) if scaling_dir.is_dir() else MetricsSet(())
    figures = draw_dataset_size(params, scaling)
    # the main task's policies beside the suite's, when trained under other profiles
    main = params.task not in u.tasks and params.backend == u.backend
    own = [backends.task_spec(u.backend, params.task)] if main else []
    profiles = ([*own, *specs], read_profile_runs(metrics_dir), read_made_by(metrics_dir))
    outside_dir = metrics_dir / ROBOMIMIC
    outside = read_metrics_folder(outside_dir) if outside_dir.is_dir() else MetricsSet(())
    blocks = build_suite_report(
        params, specs, ms, ablations, paper, scaling, figures, profiles, outside
    )
    runs = sum(len(r) for r in ablations.values())
    return blocks, figures, suite_headline_numbers(params, ms), runs
