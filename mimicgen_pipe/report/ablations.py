"""Ablation runs (the ablation stages, params.yaml's ``ablations``): each run's DGR and
coverage against its base run, beside the same change in the paper's tables, and the spread
over seeds."""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence
from typing import Any

from mimicgen_pipe.data.metrics import Metrics
from mimicgen_pipe.report.blocks import Block, Heading, Table, Text
from mimicgen_pipe.report.fmt import (
    MISSING,
    dgr_counts,
    fmt,
    fmt_ci,
    fmt_delta,
    fmt_dgr,
    fmt_pm,
    fmt_setting,
)
from mimicgen_pipe.report.inputs import OTHER_RUN, Run, of_other_run, other_run_note
from mimicgen_pipe.report.paper import METRIC_LABELS, PaperResults, paper_deltas
from mimicgen_pipe.report.settings import changed_settings, method_settings

# what the sections say first: which stages made the runs
MADE_BY = (
    "The ablation stages made these runs (`{dvc_file}`: `{stage}`, one per run of "
    "`ablations.runs` in `{params_file}`; each run's params and metrics under "
    "`{folder}<run>/`): `dvc repro` remakes them."
)


def ablation_blocks(
    task: str,
    paper_task: str,
    settings: Mapping[str, Any],
    ablations: Sequence[Run],
    paper: PaperResults,
    heading: str = "Ablations",
    base_settings_are: str = "this run's",
    made_by: str = MADE_BY.format(
        dvc_file="dvc.yaml",
        stage="ablation@<run>",
        params_file="params.yaml",
        folder="metrics/ablations/",
    ),
) -> list[Block]:
    """Every ablation run of ``task`` (its params' task) against the one with ``settings``;
    no section when there is none (a pipeline that makes none, such as the quickstart)."""
    ablations = [r for r in ablations if r.params.task == task]
    if not ablations:
        return []
    blocks: list[Block] = [Heading(2, heading), Text(made_by)]
    runs = [(r, method_settings(r.params)) for r in ablations]
    base = [(r, s) for r, s in runs if not changed_settings(settings, s)]
    if not base:
        return blocks + [
            Text(
                "No ablation run has this run's generation settings, so no deltas: "
                f"{MISSING}. Runs saved: " + ", ".join(r.name for r in ablations) + "."
            )
        ]
    base_run, base_settings = base[0]
    blocks.append(
        Text(
            f"Each run against `{base_run.name}` ({base_settings_are} settings, same attempts). "
            "Δ is in points of DGR; brackets give each DGR's 95% confidence interval (Wilson "
            "score interval of its successes of attempts): two runs whose intervals do not "
            "overlap differ by more than seed noise. The paper column gives the same change in "
            "the paper's table for the same reset variant (its base → changed value), on the "
            "task the table holds. Coverage is the joint support coverage (paper Q) of the "
            "kept scenes, beside what as many uniformly spread scenes would cover: with a "
            "fixed number of attempts a lower DGR keeps fewer scenes, which alone covers "
            "fewer bins."
        )
    )
    rows, marked = [], False
    for r, s in sorted(runs, key=lambda rs: rs[0] is not base_run):  # the base first
        for g in _generated(r, task):
            row, other = _ablation_row(task, paper_task, paper, r, s, g, base_run, base_settings)
            rows.append(row)
            marked |= other
    columns = ("run", "changed", "variant", "attempts", "DGR ours", "Δ DGR",
               "joint coverage (uniform)", "Δ coverage", "paper")  # fmt: skip
    blocks.append(Table(columns, tuple(rows)))
    if marked:
        blocks.append(Text(other_run_note("coverage")))
    blocks.extend(_seed_spread(task, base_settings, runs, paper))
    return blocks


def _generated(run: Run, task: str) -> list[Metrics]:
    """A run's generate metrics of ``task``, by variant."""
    return sorted(run.metrics.find(stage="generate", task=task), key=lambda m: str(m.variant))


def _ablation_row(
    task: str,
    paper_task: str,
    paper: PaperResults,
    run: Run,
    settings: Mapping[str, Any],
    g: Metrics,
    base_run: Run,
    base_settings: Mapping[str, Any],
) -> tuple[tuple[str, ...], bool]:
    """One run's row for one variant, and whether its coverage is of another generate run."""
    v, gm = g.variant, g.values
    base_g = base_run.metrics.one(stage="generate", task=task, variant=v)
    bm = base_g.values if base_g else None
    cov = run.metrics.one(stage="coverage", task=task, variant=v)
    other = of_other_run(cov, "run_id", g)
    cm = cov.values if cov else {}
    base_cov = base_run.metrics.one(stage="coverage", task=task, variant=v)
    bcm = base_cov.values if base_cov else {}
    pairs = paper_deltas(paper, str(v), base_settings, settings)
    pairs.sort(key=lambda p: (p[0].task != paper_task, p[0].table, p[0].task))
    paper_cell = "; ".join(
        f"{a.task} {METRIC_LABELS[a.metric]} {a.value:.1f} → {b.value:.1f} "
        f"({b.value - a.value:+.1f}, Table {a.table})"
        for a, b in pairs
    )
    changed = changed_settings(base_settings, settings)
    if set(changed) == {"generate.seed"}:
        paper_cell = "spread over seeds: Table S.1, below"
    coverage = (
        f"{fmt(cm.get('support_coverage_joint'))} ({fmt(cm.get('uniform_support_coverage_joint'))})"
    )
    row = (
        run.name,
        ", ".join(fmt_setting(k, x) for k, x in changed.items()) or "(base)",
        str(v),
        fmt(gm.get("attempts")),
        fmt_dgr(gm),
        "" if not changed else fmt_delta(bm and bm.get("dgr"), gm.get("dgr")),
        coverage + (f" {OTHER_RUN}" if other else ""),
        ""
        if not changed
        else fmt_delta(bcm.get("support_coverage_joint"), cm.get("support_coverage_joint")),
        paper_cell or ("" if not changed else "not in paper"),
    )
    return row, other


def _seed_spread(
    task: str,
    base_settings: Mapping[str, Any],
    runs: Sequence[tuple[Run, Mapping[str, Any]]],
    paper: PaperResults,
) -> list[Block]:
    """DGR spread over runs that differ from the base in the generation seed only (S.1)."""
    seeds = [
        (r, s) for r, s in runs if set(changed_settings(base_settings, s)) <= {"generate.seed"}
    ]
    if len(seeds) < 2:
        return []
    rows = []
    variants = sorted({str(g.variant) for r, _ in seeds for g in _generated(r, task)})
    for v in variants:
        found = [r.metrics.one(stage="generate", task=task, variant=v) for r, _ in seeds]
        values = [g.values for g in found if g is not None]
        dgr = [g["dgr"] for g in values]
        ref = paper.find(table="S.1", variant=v)
        rows.append(
            (
                v,
                ", ".join(str(s["generate.seed"]) for _, s in seeds),
                ", ".join(fmt_dgr(g) for g in values),
                fmt_pm(statistics.mean(dgr), statistics.stdev(dgr)) + fmt_ci(_pooled(values))
                if len(dgr) >= 2
                else MISSING,
                f"{max(dgr) - min(dgr):.1f}" if dgr else MISSING,
                "; ".join(e.cite() for e in ref) or "not in paper",
            )
        )
    return [
        Heading(3, "Generation seed (Table S.1)"),
        Table(
            ("variant", "seeds", "DGR per seed", "mean ± std", "max − min", "paper (3 seeds)"),
            tuple(rows),
        ),
    ]


def _pooled(values: Sequence[Mapping[str, Any]]) -> tuple[int, int] | None:
    """(successes, attempts) summed over generate runs of equal attempts, whose pooled DGR is
    then their mean DGR; None otherwise (a mean of unequal runs has no one count)."""
    counts = [dgr_counts(g) for g in values]
    if None in counts or len({n for _, n in counts}) != 1:
        return None
    return sum(k for k, _ in counts), sum(n for _, n in counts)


def suite_ablation_blocks(
    task: str, paper_task: str, runs: Sequence[Run], paper: PaperResults
) -> list[Block]:
    """A suite task's ablation runs (suite/dvc.yaml: ablation_suite), each against the one of
    them named ``default``, whose settings are the base (the suite's, e.g. its lower action
    noise, not params.yaml's)."""
    base = next((r for r in runs if r.name == "default"), None)
    heading = f"Ablations on {task} ({paper_task})"
    made_by = MADE_BY.format(
        dvc_file="suite/ablations/dvc.yaml",
        stage=f"ablation_suite@{task}-<run>",
        params_file="suite/params.yaml",
        folder=f"suite/metrics/ablations/{task}/",
    )
    if base is None:
        names = ", ".join(r.name for r in runs) or "none"
        return [
            Heading(2, heading),
            Text(made_by),
            Text(f"No run named `default` to compare with: {MISSING} (runs: {names})."),
        ]
    return ablation_blocks(
        task, paper_task, method_settings(base.params), runs, paper, heading, "its own", made_by
    )
