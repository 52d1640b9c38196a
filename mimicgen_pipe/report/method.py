"""The main task's sections: its data generation rates, policy success rates and support
coverage, each beside the paper's numbers for the task it stands for."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from mimicgen_pipe.core.taskspec import TaskSpec
from mimicgen_pipe.data.params import Params
from mimicgen_pipe.report.blocks import Block, Heading, Image, Table, Text
from mimicgen_pipe.report.fmt import (
    CI_NOTE,
    MISSING,
    fmt,
    fmt_dgr,
    fmt_failures,
    fmt_setting,
    fmt_sr,
)
from mimicgen_pipe.report.inputs import (
    OTHER_RUN,
    MetricsSet,
    coverage,
    evaluated,
    evaluation,
    of_other_run,
    other_run_note,
    policy_data,
    trained,
)
from mimicgen_pipe.report.paper import PaperResults
from mimicgen_pipe.report.settings import matches


def intro_blocks(task: str, paper_task: str, settings: Mapping[str, Any]) -> list[Block]:
    return [
        Heading(1, f"MimicGen on {task}: our numbers and the paper's"),
        Text(
            f"Our task `{task}` is set beside the paper's {paper_task} task. Paper numbers "
            "come from `reference/paper_results.yaml`, each with the table it was read from; "
            f"ours from the metrics files of this run. `{MISSING}` marks a metric this run "
            "did not produce. Generation settings: "
            + ", ".join(f"`{fmt_setting(k, v)}`" for k, v in settings.items())
            + ". "
            + CI_NOTE
        ),
    ]


def source_file_blocks(params: Params, ms: MetricsSet) -> list[Block]:
    """A sentence naming the file the main task's source demos were brought in from, with
    its sha256, as the source stage's metrics record them (source.from_file); none for the
    demonstrator's demos."""
    found = ms.find(stage="source", task=params.task, backend=params.backend)
    return [
        Text(
            f"Source demos brought in from `{m.values['source_file']}` (sha256 "
            f"`{m.values.get('source_file_sha256', MISSING)}`)."
        )
        for m in found
        if "source_file" in m.values
    ]


def dgr_blocks(
    params: Params,
    spec: TaskSpec,
    settings: Mapping[str, Any],
    ms: MetricsSet,
    paper: PaperResults,
) -> list[Block]:
    """Per variant the DGR of the generate run policies train on, with its task failures per
    subtask of ``spec`` (the main task's), beside the paper's (Table O.1, its settings) and
    the paper's run with ``settings`` (this run's) where one of its tables has it."""
    paper_task = spec.paper_task
    rows = []
    for v in params.generate.variants:
        g = policy_data(ms, params, params.task, params.backend, v)
        gv = g.values if g else {}
        headline = paper.find(table="O.1", task=paper_task, variant=v, metric="dgr")
        same = [
            e
            for e in paper.find(task=paper_task, variant=v, metric="dgr")
            if e.settings and matches(settings, e.settings)
        ]
        rows.append(
            (
                v,
                fmt(gv.get("attempts")),
                fmt(gv.get("successes")),
                fmt_dgr(gv),
                fmt_failures(spec, gv) if g else MISSING,
                "; ".join(e.cite() for e in headline) or "not in paper",
                "; ".join(f"{e.cite()} [{e.condition}]" for e in same) or "not in paper",
            )
        )
    columns = ("variant", "attempts", "successes", "DGR ours", "task failures per subtask",
               "paper (its settings)", "paper with our settings")  # fmt: skip
    blocks: list[Block] = [
        Heading(2, "Data generation rate (DGR, %)"),
        Table(columns, tuple(rows)),
    ]
    o1 = [e for e in paper.find(table="O.1", task=paper_task) if e.settings]
    if o1 and not matches(settings, o1[0].settings):
        blocks.append(
            Text(
                f"The paper generated {paper_task} with "
                + ", ".join(f"`{fmt_setting(k, v)}`" for k, v in o1[0].settings.items())
                + "; the last column is the paper's run with the settings used here, where "
                "one of its tables has it."
            )
        )
    return blocks


def policy_blocks(
    params: Params, paper_task: str, ms: MetricsSet, paper: PaperResults
) -> list[Block]:
    """Success rates of the policies evaluated: the paper's P.1 rows of the variants
    generated first (missing where ours are), then every other evaluation present. None
    where the pipeline trained and evaluated no policy of the task (a pipeline without
    those stages, such as one that only generates)."""
    task, backend, variants = params.task, params.backend, params.generate.variants
    if not trained(ms, params) and not evaluated(ms, params):
        return []
    expected = [
        (e.data, e.variant)
        for e in paper.find(table="P.1", task=paper_task)
        if e.data in ("source", *variants) and e.variant in variants
    ]
    rows, marked = [], False
    for data, v in dict.fromkeys(expected + evaluated(ms, params)):
        ev = evaluation(ms, params, task, backend, data, v)
        evv = ev.values if ev else {}
        other = data != "source" and of_other_run(
            ev, "data_run_id", policy_data(ms, params, task, backend, data)
        )
        marked |= other
        ref = paper.find(table="P.1", task=paper_task, data=data, variant=v)
        rows.append(
            (
                ("source demos" if data == "source" else f"generated {data}")
                + (f" {OTHER_RUN}" if other else ""),
                v,
                fmt_sr(evv, "max"),
                fmt_sr(evv, "last"),
                f"{fmt(evv.get('episodes'))} × {fmt(evv.get('seeds'))}" if ev else MISSING,
                "; ".join(e.cite() for e in ref) or "not in paper",
            )
        )
    columns = ("trained on", "evaluated on", "SR max ours", "SR last ours", "episodes × seeds",
               "paper (low-dim)")  # fmt: skip
    return [
        Heading(2, "Policy success rate (%, max over training, mean ± std over seeds)"),
        Table(columns, tuple(rows)),
        *([Text(other_run_note("train/evaluate"))] if marked else []),
    ]


def coverage_blocks(
    params: Params,
    paper_task: str,
    ms: MetricsSet,
    paper: PaperResults,
    heatmaps: Mapping[str, str],
) -> list[Block]:
    """Support coverage (paper Q) per variant, with its heat maps (``heatmaps``: variant ->
    image name, those present)."""
    task, backend, variants = params.task, params.backend, params.generate.variants
    rows, marked = [], False
    for v in variants:
        c = coverage(ms, params, v)
        other = of_other_run(c, "run_id", policy_data(ms, params, task, backend, v))
        marked |= other
        rows.append((v + (f" {OTHER_RUN}" if other else ""), *_coverage_cells(c and c.values)))
    columns = ("variant", "bins per dim", "generated / attempted", "joint", "joint attempted",
               "joint uniform", "per object (attempted)")  # fmt: skip
    return [
        Heading(2, "Support coverage of initial scenes (%, paper Q)"),
        Text(
            "Each object's initial (x, y, yaw) binned over the variant's reset bounds; coverage "
            "is the share of non-empty bins, per object and jointly over all objects, for the "
            "generated (kept) scenes and for all attempted ones. `uniform` is what the same "
            "number of scenes spread uniformly over the joint bins would cover on average; a "
            "generated coverage well below it (and below the attempted one) means the kept "
            "scenes are biased."
        ),
        Table(columns, tuple(rows)),
        *([Text(other_run_note("coverage"))] if marked else []),
        Text(_paper_coverage(paper, paper_task)),
        *(
            Image(heatmaps[v], f"initial object positions, {task} {v}")
            if v in heatmaps
            else Text(f"Heat maps for {v}: {MISSING}.")
            for v in variants
        ),
    ]


def _coverage_cells(c: Mapping[str, Any] | None) -> tuple[str, ...]:
    if not c:
        return (MISSING,) * 6
    objects = sorted(
        k[len("support_coverage_") :]
        for k in c
        if k.startswith("support_coverage_") and k != "support_coverage_joint"
    )
    per_object = ", ".join(
        f"{o} {fmt(c.get(f'support_coverage_{o}'))} "
        f"({fmt(c.get(f'attempted_support_coverage_{o}'))})"
        for o in objects
    )
    return (
        fmt(c.get("bins")),
        f"{fmt(c.get('episodes'))} / {fmt(c.get('attempts'))}",
        fmt(c.get("support_coverage_joint")),
        fmt(c.get("attempted_support_coverage_joint")),
        fmt(c.get("uniform_support_coverage_joint")),
        per_object,
    )


def _paper_coverage(paper: PaperResults, paper_task: str) -> str:
    """The paper's coverage numbers (Appendix Q, in its text): the task's own, else others'."""
    entries = paper.find(metric="support_coverage")
    own = [e for e in entries if e.task == paper_task]
    if own:
        cited = ", ".join(f"{e.variant} {e.value:g}%" for e in own)
        return f"The paper's support coverage of {paper_task}: {cited} (Appendix Q)."
    cited = ", ".join(f"{e.task} {e.variant} {e.value:g}%" for e in entries)
    return (
        f"The paper reports coverage for other tasks only (e.g. {cited}, Appendix Q); it has "
        f"no number for {paper_task}."
    )
