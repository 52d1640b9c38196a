"""Robot transfer (paper E): the data generation rate per arm from the same source demos."""

from __future__ import annotations

from collections.abc import Sequence

from mimicgen_pipe.metrics import Metrics
from mimicgen_pipe.report.blocks import Block, Heading, Table, Text
from mimicgen_pipe.report.fmt import MISSING, fmt
from mimicgen_pipe.report.inputs import MetricsSet
from mimicgen_pipe.report.paper import PaperResults


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
                    else f"{fmt(m.values['dgr'])} ({m.values.get('ik_failures', 0)}/"
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
