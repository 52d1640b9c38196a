"""The transit pipeline's report (transit/dvc.yaml): each cell generated with linear and
with planned transit (generate.transit), side by side."""

from __future__ import annotations

from mimicgen_pipe.data.metrics import Metrics
from mimicgen_pipe.data.params import Params
from mimicgen_pipe.report.blocks import Block, Heading, Table, Text
from mimicgen_pipe.report.fmt import CI_NOTE, MISSING, fmt, fmt_delta, fmt_dgr, fmt_sr
from mimicgen_pipe.report.inputs import MetricsSet

WALL_TASK, WALL_VARIANT = "stack_cube_wall", "wall"  # the cell where a wall blocks the line


def transit_cells(params: Params) -> list[tuple[str, str]]:
    """(task, variant) of every cell: each task's D0, and stack_cube_wall's wall."""
    cells = [(task, "D0") for task in params.planned_transit.tasks]
    return (
        cells + [(WALL_TASK, WALL_VARIANT)] if WALL_TASK in params.planned_transit.tasks else cells
    )


def transit_run(
    ms: MetricsSet, task: str, variant: str, planned: bool, purpose: str = "dgr"
) -> Metrics | None:
    """The generate run of ``task`` on ``variant`` with planned (or linear) transit made for
    ``purpose`` (fixed attempts: "dgr"; a dataset: "policy_data"), None unless exactly one:
    the planned run's metrics count planner failures, the linear run's do not."""
    runs = [
        m
        for m in ms.find(stage="generate", task=task, variant=variant, purpose=purpose)
        if ("planner_failures" in m.values) == planned
    ]
    return runs[0] if len(runs) == 1 else None


def wall_evaluation(ms: MetricsSet, transit: str) -> Metrics | None:
    """The evaluation of the wall variant's policy trained on ``transit``'s demos ("linear"
    or "planned"), None unless exactly one."""
    ev = ms.find(stage="evaluate", task=WALL_TASK, variant=WALL_VARIANT, data=f"wall_{transit}")
    return ev[0] if len(ev) == 1 else None


def _cell(m: Metrics | None, key: str, digits: int = 1) -> str:
    return MISSING if m is None else fmt(m.values.get(key), digits)


def transit_blocks(params: Params, ms: MetricsSet) -> list[Block]:
    rows = []
    for task, variant in transit_cells(params):
        lin = transit_run(ms, task, variant, planned=False)
        plan = transit_run(ms, task, variant, planned=True)
        kept = [
            MISSING
            if m is None
            else f"{fmt_dgr(m.values)} ({m.values['successes']}/{m.values['attempts']})"
            for m in (lin, plan)
        ]
        steps = [
            MISSING if m is None else fmt(m.values["steps"] / max(1, m.values["attempts"]), 0)
            for m in (lin, plan)
        ]
        rows.append(
            (
                f"{task} ({variant})",
                *kept,
                fmt_delta(*(None if m is None else m.values["dgr"] for m in (lin, plan))),
                _cell(plan, "planner_failures"),
                *steps,
            )
        )
    table = Table(
        (
            "task (variant)",
            "linear DGR % (kept/attempts)",
            "planned DGR % (kept/attempts)",
            "planned − linear",
            "planner failures",
            "steps/attempt linear",
            "steps/attempt planned",
        ),
        tuple(rows),
    )
    g = params.generate.planner
    return [
        Heading(1, "Linear vs planned transit"),
        Text(
            "Each cell generated twice from the same source demos and attempt seeds, "
            f"{params.planned_transit.attempts} fixed attempts at σ "
            f"{params.planned_transit.action_noise}: with MimicGen's straight interpolation "
            "(linear, paper M.2) and with a motion planner's collision-free path to each segment's "
            f"approach (planned: approach within {g.approach_distance} m of the reference "
            f"object, clearance {g.clearance} m, at most {g.max_joint_step} rad per joint "
            "and step). stack_cube_wall's source demos are recorded with its wall out of the "
            "way (D0); in its variant wall, the wall stands between the cubes. Planner "
            "failures: attempts stopped because no path was found, apart from task "
            "failures. Steps per attempt over all attempts (times per attempt: "
            f"`transit/timings/`). `{MISSING}` marks a "
            f"run the pipeline did not produce. {CI_NOTE}"
        ),
        table,
        *policy_blocks(params, ms),
    ]


def policy_blocks(params: Params, ms: MetricsSet) -> list[Block]:
    """The wall variant's policies, one per transit: the demos they trained on, the attempts
    that took, and their success on the wall variant."""
    rows = []
    for transit in ("linear", "planned"):
        run = transit_run(ms, WALL_TASK, WALL_VARIANT, transit == "planned", "policy_data")
        ev = wall_evaluation(ms, transit)
        g = None if run is None else run.values
        e = None if ev is None else ev.values
        rows.append(
            (
                transit,
                MISSING if g is None else f"{g['successes']} of {g['attempts']} attempts",
                fmt_sr(e, "max", std=False),
                fmt_sr(e, "last", std=False),
            )
        )
    n = params.planned_transit.policy_demos
    return [
        Heading(2, "Policies on the wall variant"),
        Text(
            f"BC-RNN policies (train profile {params.train.profile}) on {n} kept demos of "
            "each transit on the wall variant, generated until that many succeeded, each "
            f"rolled out {params.evaluate.episodes} times per checkpoint on the wall variant: "
            "success % of the best checkpoint and of the last."
        ),
        Table(
            ("transit", "demos (kept of attempts)", "success % max", "success % last"),
            tuple(rows),
        ),
    ]
