"""The reports: our metrics beside the paper's numbers, as Markdown and HTML. Imports core
and data.

Built only from what is present: every number in them comes from a metrics file (selected
by the identity fields every stage writes, mimicgen_pipe.data.metrics), an ablation run, or
the paper's numbers file (each with the table it was read from). A metric that was not
produced is written ``missing``; no row is made up. A coverage, training or evaluation of
another generate run than the one shown beside it is marked, never mixed in silently.

The reports: :func:`build_report`, the default pipeline's (the main task, its policies
over training, robot transfer, ablations, videos), :func:`build_suite_report`, the task
suite's, :func:`build_transit_report`, linear vs planned transit's,
:func:`build_transfer_report`, robot transfer's, and :func:`build_images_report`, the image
agents'. Each is a list of
blocks (mimicgen_pipe.report.blocks) rendered as Markdown and HTML. The default pipeline's
report comes with its figures of the policies over training (mimicgen_pipe.report.curves)
and its headline numbers (mimicgen_pipe.report.summary). The report stage composes one into
a :class:`ReportJob` before anything is written, and :func:`write_report` writes it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from mimicgen_pipe.core.taskspec import TaskSpec
from mimicgen_pipe.data.layout import MEDIA
from mimicgen_pipe.data.metrics import write_metrics
from mimicgen_pipe.data.params import Params
from mimicgen_pipe.report import method, suite
from mimicgen_pipe.report.ablations import ablation_blocks, suite_ablation_blocks
from mimicgen_pipe.report.blocks import Block, render_html, render_markdown
from mimicgen_pipe.report.curves import curve_blocks
from mimicgen_pipe.report.images import images_blocks
from mimicgen_pipe.report.inputs import Media, MetricsSet, Run
from mimicgen_pipe.report.outside import outside_learner_blocks
from mimicgen_pipe.report.paper import PaperResults
from mimicgen_pipe.report.profiles import profile_blocks
from mimicgen_pipe.report.scaling import scaling_blocks
from mimicgen_pipe.report.settings import method_settings
from mimicgen_pipe.report.summary import SUMMARY
from mimicgen_pipe.report.transfer import (
    transfer_blocks,
    transfer_policy_blocks,
    transfer_table,
)
from mimicgen_pipe.report.transit import transit_blocks
from mimicgen_pipe.report.videos import video_blocks


def build_report(
    params: Params,
    spec: TaskSpec,
    ms: MetricsSet,
    ablations: Sequence[Run],
    paper: PaperResults,
    heatmaps: Mapping[str, str],
    media: Mapping[str, Media],
    curves: Sequence[str],
) -> list[Block]:
    """The default pipeline's report. ``spec``: the main task's (its paper_task names the
    paper's task ours stands for); ``ms``: the metrics folder; ``ablations``: saved ablation
    runs; ``heatmaps``: variant -> its coverage heat maps as the report refers to them (those
    present); ``media``: variant -> its videos (those present); ``curves``: the figure files
    of mimicgen_pipe.report.curves made beside the report."""
    task, paper_task, variants = params.task, spec.paper_task, params.generate.variants
    settings = method_settings(params)
    return [
        *method.intro_blocks(task, paper_task, settings),
        *method.source_file_blocks(params, ms),
        *method.dgr_blocks(params, spec, settings, ms, paper),
        *method.policy_blocks(params, paper_task, ms, paper),
        *curve_blocks(task, curves),
        *method.coverage_blocks(params, paper_task, ms, paper, heatmaps),
        *ablation_blocks(task, paper_task, settings, ablations, paper),
        # the report's folder refers to the videos where the render stage keeps them
        *video_blocks(task, variants, media, f"../{MEDIA}"),
    ]


def build_suite_report(
    params: Params,
    specs: Sequence[TaskSpec],
    ms: MetricsSet,
    ablations: Mapping[str, Sequence[Run]],
    paper: PaperResults,
    scaling_ms: MetricsSet,
    figures: Mapping[str, bytes],
    profiles: tuple[Sequence[TaskSpec], Mapping[str, MetricsSet], Mapping[str, Mapping[str, str]]],
    robomimic: MetricsSet,
) -> list[Block]:
    """The task suite's report (params suite.*). ``specs``: the suite's tasks; ``ms``: its
    metrics folder; ``ablations``: task -> its ablation runs; ``scaling_ms``: the
    dataset-size comparison's metrics folder, ``figures``: its figure where drawn
    (mimicgen_pipe.report.scaling); ``profiles``: the tasks, run -> metrics folder and
    run -> how it was made, of D0 policies under other training profiles, made outside the
    pipeline and shown last (mimicgen_pipe.report.profiles);
    ``robomimic``: the outside learner's metrics folder (mimicgen_pipe.report.outside)."""
    blocks = [
        *suite.intro_blocks(specs),
        *suite.suite_dgr_blocks(params, specs, ms, paper),
        *suite.object_transfer_blocks(params, specs, ms, paper),
        *suite.suite_policy_blocks(params, specs, ms, paper),
        *suite.paper_geometry_blocks(params, specs, ms, paper),
        *outside_learner_blocks(params, specs, ms, robomimic, paper),
        *suite.long_task_blocks(params, specs, ms, paper),
        *suite.two_arm_blocks(params, specs, ms),
        *scaling_blocks(params, scaling_ms, figures),
    ]
    for spec in specs:
        if ablations.get(spec.name):
            blocks += suite_ablation_blocks(spec.name, spec.paper_task, ablations[spec.name], paper)
    # what no stage makes comes last, saying so
    return blocks + profile_blocks(params, profiles[0], profiles[1], paper, profiles[2])


def build_transfer_report(
    params: Params, specs: Sequence[TaskSpec], ms: MetricsSet, paper: PaperResults
) -> list[Block]:
    """The robot-transfer pipeline's report (params transfer.*): ``specs``, the tasks of
    transfer.policy_tasks; ``ms``, its metrics folder."""
    t, variants = params.transfer, params.generate.variants
    tables = [
        transfer_table(ms, t.backend, t.tasks, t.variants, t.robots),
        transfer_table(ms, params.backend, [params.task], variants, t.maniskill_robots),
    ]
    return [*transfer_blocks(tables, paper), *transfer_policy_blocks(params, specs, ms, paper)]


def build_transit_report(params: Params, ms: MetricsSet) -> list[Block]:
    """The transit pipeline's report (params planned_transit.*): ``ms``, its metrics folder."""
    return transit_blocks(params, ms)


def build_images_report(
    params: Params, spec: TaskSpec, ms: MetricsSet, paper: PaperResults
) -> list[Block]:
    """The image agents' report (images/dvc.yaml): ``spec``, the main task's; ``ms``, the
    pipeline's metrics folder."""
    return images_blocks(params, spec, ms, paper)


@dataclass(frozen=True)
class ReportJob:
    """One report, composed from its inputs (mimicgen_pipe.stages.report.resolve): its
    ``blocks`` under ``title``, the images its HTML embeds (``images``: path in the report
    -> PNG bytes), the ``figures`` written beside it (file name -> PNG bytes) and its
    headline numbers ``summary`` (None: none), made from ``metrics_files`` metrics files of
    the folder ``metrics_dir`` (with the heat maps and curves of ``plots_dir``) and
    ``ablation_runs`` ablation runs; written as the report folder ``out``."""

    title: str
    blocks: tuple[Block, ...]
    images: Mapping[str, bytes]
    figures: Mapping[str, bytes]
    summary: Mapping[str, float] | None
    metrics_files: int
    ablation_runs: int
    metrics_dir: Path
    plots_dir: Path
    out: Path


def write_report(job: ReportJob, folder: Path) -> None:
    """The job's report.md, report.html, figures and summary.json, into ``folder``."""
    (folder / "report.md").write_text(render_markdown(job.blocks))
    (folder / "report.html").write_text(render_html(job.blocks, job.images, job.title))
    for name, data in job.figures.items():
        (folder / name).write_bytes(data)
    if job.summary is not None:
        write_metrics(folder / SUMMARY, job.summary)
