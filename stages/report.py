"""report: report.md and report.html from every metric present, beside the paper's numbers."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import envs
from mimicgen_pipe import layout
from mimicgen_pipe.errors import InputError
from mimicgen_pipe.outputs import atomic_directory, claim, directory_kind, recover_in
from mimicgen_pipe.params import load_params
from mimicgen_pipe.report import (
    Run,
    build_report,
    check_run_ids,
    load_paper_results,
    render_html,
    render_markdown,
    suite_ablation_blocks,
    suite_blocks,
    suite_policy_blocks,
    transfer_blocks,
    transfer_table,
    video_blocks,
)
from stages import add_selection_arguments, stage_params

# the report and the heat maps copied beside it
REPORT_DIR = directory_kind("report directory", r"report\.(md|html)|[^/]+\.png")


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_selection_arguments(p)
    p.add_argument("--metrics", default="metrics", help="metrics folder (default: metrics)")
    p.add_argument(
        "--ablations",
        help="saved ablation runs, one folder each with params.yaml and metrics JSON files "
        "(default: metrics/ablations)",
    )
    p.add_argument("--plots", default="plots", help="folder of the heat maps (default: plots)")
    p.add_argument(
        "--paper",
        default="reference/paper_results.yaml",
        help="the paper's numbers (default: reference/paper_results.yaml)",
    )
    p.add_argument("--out", help="report folder (default: report)")


def read_metrics(folder: Path) -> dict[str, dict[str, Any]]:
    """Every flat metrics JSON directly in ``folder``: file stem -> metrics; InputError when
    two of them describe different generate runs (see check_run_ids)."""
    out = {}
    recover_in(folder)  # commits that killed runs left half done
    for path in sorted(folder.glob("*.json")):
        try:
            value = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise InputError(f"{path}: not valid JSON ({exc})") from exc
        if not isinstance(value, dict):
            raise InputError(f"{path}: expected a flat JSON object")
        out[path.stem] = value
    check_run_ids(out, folder)  # generate, coverage and training metrics of one run
    return out


def read_runs(folder: Path) -> list[Run]:
    """The saved runs in ``folder``: one sub-folder each, with its params.yaml and metrics."""
    runs = []
    for sub in sorted(p for p in folder.glob("*") if p.is_dir()):
        if not (sub / "params.yaml").exists():
            raise InputError(f"{sub}: params.yaml missing (an ablation run saves its params)")
        runs.append(Run(sub.name, load_params(sub / "params.yaml"), read_metrics(sub)))
    return runs


def run(args: argparse.Namespace) -> None:
    params = stage_params(args)
    metrics_dir = Path(args.metrics)
    ablations_dir = Path(args.ablations or metrics_dir / layout.ablations_dir().name)
    out = Path(args.out or layout.report_dir())
    # fails at once if another run writes the report, or if out holds anything else
    claim((out, REPORT_DIR), inputs=[metrics_dir])
    paper = load_paper_results(args.paper)
    if not metrics_dir.is_dir():
        raise InputError(f"{metrics_dir}: metrics folder not found")
    this_run = Run("this run", params, read_metrics(metrics_dir))
    ablations = read_runs(ablations_dir)
    variants = list(params.generate.variants)
    images, heatmaps = {}, {}
    for v in variants:
        png = Path(args.plots) / layout.heatmap_file(params.task, v).name
        if png.exists():
            images[png.name], heatmaps[v] = png.read_bytes(), png.name
    spec = envs.task_spec(params.backend, params.task)
    blocks = build_report(
        params.task, spec.paper_task, variants, this_run, ablations, paper, heatmaps
    )
    t, m = params.transfer, this_run.metrics
    blocks += transfer_blocks(
        [
            transfer_table(t.tasks, t.variants, t.robots, m),
            transfer_table([params.task], variants, ["panda", *t.maniskill_robots], m),
        ]
    )
    u = params.suite
    specs = [envs.task_spec(u.backend, task) for task in u.tasks]
    # O1 rows for the tasks generated on their object-transfer variant (the others lack it)
    variants_shown = [*u.variants, *(["O1"] if u.object_transfer else [])]
    blocks += suite_blocks(specs, variants_shown, this_run.metrics, paper, u.action_noise)
    blocks += suite_policy_blocks(specs, this_run.metrics, paper)
    # ablation runs on suite tasks: metrics/suite_ablations/<task>/<run>/
    for task in u.tasks:
        runs = read_runs(metrics_dir / "suite_ablations" / task)
        if runs:
            blocks += suite_ablation_blocks(envs.task_spec(u.backend, task), runs, paper)
    media = {}
    for v in variants:
        folder = layout.media_dir(params.task, v)
        if folder.is_dir():
            metrics = this_run.metrics.get(layout.metrics_file("render", params.task, v).stem, {})
            media[v] = {"files": {p.name for p in folder.iterdir()}, **metrics}
    # the report's folder refers to the videos where the render stage keeps them
    blocks += video_blocks(params.task, variants, media, f"../{layout.MEDIA}")
    with atomic_directory(out) as tmp:
        # the heat maps are copied beside report.md so that the folder stands on its own
        (tmp / "report.md").write_text(render_markdown(blocks))
        (tmp / "report.html").write_text(render_html(blocks, images, f"MimicGen on {params.task}"))
        for name, data in images.items():
            (tmp / name).write_bytes(data)
    print(
        f"report: {len(this_run.metrics)} metrics files, {len(ablations)} ablation runs, "
        f"{len(images)} heat maps -> {out}/report.md, {out}/report.html"
    )
