"""Robot transfer (paper E): the data generation rate per arm from the same source demos;
and the D0 policies of the transfer back end's tasks built to the paper's geometry
(transfer.policy_tasks), beside Table P.1."""

from __future__ import annotations

from collections.abc import Sequence

from mimicgen_pipe.core.taskspec import TaskSpec
from mimicgen_pipe.data.metrics import Metrics
from mimicgen_pipe.data.params import Params
from mimicgen_pipe.report.blocks import Block, Heading, Table, Text
from mimicgen_pipe.report.fmt import CI_NOTE, MISSING, fmt, fmt_dgr
from mimicgen_pipe.report.inputs import MetricsSet, evaluation
from mimicgen_pipe.report.paper import PaperResults
from mimicgen_pipe.report.suite import (
    PAPER_GEOMETRY_COLUMNS,
    TARGET_MARGIN,
    paper_geometry_rows,
)


def transfer_cell(
    ms: MetricsSet, task: str, backend: str, variant: str, robot: str
) -> Metrics | None:
    """The generate run of ``task`` on ``variant`` with ``robot``: its fixed attempts (a
    DGR measure)."""
    return ms.one(
        stage="generate", task=task, backend=backend, variant=variant, robot=robot, purpose="dgr"
    )


def transfer_table(
    ms: MetricsSet,
    backend: str,
    tasks: Sequence[str],
    variants: Sequence[str],
    robots: Sequence[str],
) -> Table:
    """DGR per task variant x arm (:func:`transfer_cell`), with the attempts stopped at IK
    beside each."""
    rows = []
    for task in tasks:
        for v in variants:
            cells = [f"{task} ({v})"]
            for r in robots:
                m = transfer_cell(ms, task, backend, v, r)
                cells.append(
                    MISSING
                    if m is None
                    else f"{fmt_dgr(m.values)} ({m.values.get('ik_failures', 0)}/"
                    f"{m.values['attempts']} IK)"
                )
            rows.append(tuple(cells))
    return Table(("task (variant)", *robots), tuple(rows))


def transfer_blocks(tables: Sequence[Table], paper: PaperResults) -> list[Block]:
    """Robot transfer (paper E.1): the tables of :func:`transfer_table` under one heading."""
    by_task: dict[str, dict[str, list[str]]] = {}  # task -> variant -> "arm value"
    for e in paper.find(table="E.1", metric="dgr"):
        by_task.setdefault(e.task, {}).setdefault(e.variant, []).append(
            f"{e.condition} {e.value:g}"
        )
    cited = "; ".join(
        f"{task}: " + "; ".join(f"{v}: {', '.join(arms)}" for v, arms in variants.items())
        for task, variants in by_task.items()
    )
    return [
        Heading(1, "Robot transfer"),
        Text(CI_NOTE),
        Heading(2, "Robot transfer: data generation rate per arm"),
        Text(
            "Source demos recorded with the Panda; each cell generated with the arm of its "
            "column from those demos: DGR % (attempts stopped because a target was outside "
            f"the arm's workspace / attempts). Paper Table E.1, {cited}. First table: "
            "PyBullet. Second: the default pipeline's task on ManiSkill, from its source "
            "demos, whose controller solves its own IK (no IK check ahead, so 0 IK failures "
            "by construction)."
        ),
        *tables,
    ]


def transfer_policy_blocks(
    params: Params, specs: Sequence[TaskSpec], ms: MetricsSet, paper: PaperResults
) -> list[Block]:
    """The tasks of transfer.policy_tasks (``specs``: theirs) on the transfer back end, one
    table as the suite's paper geometry (mimicgen_pipe.report.suite.paper_geometry_rows):
    the generating arm's fixed attempts on D0 and D1 beside Table O.1, and the D0 policies
    (transfer.policy_seeds seeds) beside Table P.1."""
    t = params.transfer
    tasks = [s for s in specs if s.name in t.policy_tasks]
    if not tasks:
        return []
    rows = []
    for spec in tasks:
        dgr = [transfer_cell(ms, spec.name, t.backend, v, params.generate.robot)
               for v in ("D0", "D1")]  # fmt: skip
        ev = evaluation(ms, params, spec.name, t.backend, "D0", "D0")
        rows += paper_geometry_rows(spec, dgr, [(f"`{params.train.profile}`", ev)], paper)
    return [
        Heading(2, f"Policies on {t.backend}: the paper's own geometry"),
        Text(
            f"The {t.backend} tasks of `transfer.policy_tasks`: the {params.generate.robot}'s "
            f"{t.attempts} fixed attempts on D0 and D1 (the table above), and BC-RNN "
            f"(`{params.train.profile}` profile) trained on {params.train.num_demos} "
            f"generated D0 demos with {t.policy_seeds} seeds, rolled out on D0 (mean ± std "
            "of the max over training), beside Tables O.1 and P.1. The target is P.1 − "
            f"{fmt(TARGET_MARGIN)} points."
        ),
        Table(PAPER_GEOMETRY_COLUMNS, tuple(rows)),
    ]
