"""The task suite's sections: per task its data generation rates, object transfer and
policies, beside the paper's numbers for the task it stands for."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from mimicgen_pipe.core.taskspec import TaskSpec
from mimicgen_pipe.data.metrics import Metrics
from mimicgen_pipe.data.params import Params
from mimicgen_pipe.report.blocks import Block, Heading, Table, Text
from mimicgen_pipe.report.fmt import (
    CI_NOTE,
    MISSING,
    fmt,
    fmt_delta,
    fmt_dgr,
    fmt_failures,
    fmt_sr,
)
from mimicgen_pipe.report.inputs import (
    OTHER_RUN,
    MetricsSet,
    evaluation,
    of_other_run,
    other_run_note,
    policy_data,
)
from mimicgen_pipe.report.paper import PaperResults


def intro_blocks(specs: Sequence[TaskSpec]) -> list[Block]:
    tasks = ", ".join(f"`{s.name}` ({s.paper_task})" for s in specs)
    return [
        Heading(1, "MimicGen task suite: our numbers and the paper's"),
        Text(
            f"Tasks, each beside the paper's task it stands for: {tasks}. Paper numbers come "
            "from `reference/paper_results.yaml`, each with the table it was read from; ours "
            f"from the suite's metrics files (`suite/dvc.yaml`). `{MISSING}` marks a metric "
            f"the suite did not produce. {CI_NOTE}"
        ),
    ]


def dgr_run(ms: MetricsSet, params: Params, task: str, variant: str) -> Metrics | None:
    """The suite's fixed attempts of ``task`` on ``variant`` (a DGR measure)."""
    return ms.one(
        stage="generate",
        task=task,
        backend=params.suite.backend,
        variant=variant,
        robot=params.generate.robot,
        purpose="dgr",
    )


def _kept(m: Mapping[str, Any]) -> str:
    """A DGR with its 95% interval and the counts it is of."""
    return f"{fmt_dgr(m)} ({m['successes']}/{m['attempts']})"


def suite_dgr_blocks(
    params: Params, specs: Sequence[TaskSpec], ms: MetricsSet, paper: PaperResults
) -> list[Block]:
    """Per task x variant the DGR of the suite's fixed attempts, the action-noise sigma they
    ran with (the suite's ``action_noise``, or less where the task caps it), the task
    failures per subtask (the first subtask an attempt did not achieve) and steps per attempt,
    beside the paper's Table O.1 DGR of the task it stands for."""
    rows = []
    for spec in specs:
        for v in params.suite.variants:
            g = dgr_run(ms, params, spec.name, v)
            ref = paper.find(table="O.1", task=spec.paper_task, variant=v, metric="dgr")
            if g is None:
                ours, failures, per_attempt = MISSING, MISSING, MISSING
            else:
                m = g.values
                ours = _kept(m)
                failures = fmt_failures(spec, m)
                per_attempt = fmt(m["steps"] / max(1, m["attempts"]), 0)
            rows.append(
                (
                    f"{spec.name} ({v})",
                    spec.paper_task,
                    ours,
                    f"{spec.action_noise(params.suite.action_noise):g}",
                    failures,
                    per_attempt,
                    ref[0].cite() if ref else "– (none in the paper)",
                )
            )
    columns = ("task (variant)", "paper task", "DGR % (kept/attempts)", "σ",
               "task failures per subtask", "steps per attempt", "paper DGR")  # fmt: skip
    return [
        Heading(2, "Task suite: data generation rate per task"),
        Text(
            "Each task generated from its own 10 source demos (ManiSkill's motion planner; "
            "a task with two arms: its task file's scripted demonstrator), a fixed number "
            "of attempts per reset variant (`suite/dvc.yaml`), with action "
            "noise σ (paper M.4; a task file may cap it where its tolerances cannot take the "
            "suite's). Paper numbers are Table O.1's for the task ours stands for; the "
            "paper's settings per task (M.6) differ from ours (random selection, one source "
            "demo per episode, σ 0.05 in robosuite's units). Times per attempt: "
            "`suite/timings/`."
        ),
        Table(columns, tuple(rows)),
    ]


def object_transfer_blocks(
    params: Params, specs: Sequence[TaskSpec], ms: MetricsSet, paper: PaperResults
) -> list[Block]:
    """The tasks generated on their object-transfer variant O1 (suite.object_transfer): its
    DGR beside D0's, with the same source demos and attempts."""
    rows = []
    for spec in specs:
        if spec.name not in params.suite.object_transfer:
            continue
        d0, o1 = (dgr_run(ms, params, spec.name, v) for v in ("D0", "O1"))
        rows.append(
            (
                spec.name,
                spec.paper_task,
                _kept(d0.values) if d0 else MISSING,
                _kept(o1.values) if o1 else MISSING,
                fmt_delta(d0 and d0.values["dgr"], o1 and o1.values["dgr"]),
            )
        )
    if not rows:
        return []
    cited = ", ".join(f"{e.variant} {e.value:.1f}" for e in paper.find(table="F.1", metric="dgr"))
    tasks = ", ".join(dict.fromkeys(e.task for e in paper.find(table="F.1")))
    columns = ("task", "paper task", "D0 DGR % (kept/attempts)", "O1 DGR % (kept/attempts)",
               "Δ DGR (O1 − D0)")  # fmt: skip
    return [
        Heading(2, "Object transfer: data generation rate with another object"),
        Text(
            "O1 is D0's reset distribution with another object in the scene, generated from "
            "the same source demos (recorded with D0's object) and the same attempts and σ "
            f"as the table above (paper F). The paper's object transfer is {tasks} (Table "
            f"F.1, DGR %): {cited}."
        ),
        Table(columns, tuple(rows)),
    ]


def suite_policy_blocks(
    params: Params, specs: Sequence[TaskSpec], ms: MetricsSet, paper: PaperResults
) -> list[Block]:
    """Per task x variant the success rate of the BC-RNN trained on the source demos and of
    the one trained on that variant's generated demos, max and last over training, beside the
    paper's Table P.1 for the task ours stands for. Rows: D0 always, other variants where a
    metric is present."""
    backend = params.suite.backend
    rows, marked = [], False
    protocols = set()  # (episodes, every_epochs, checkpoints) of the evaluations shown
    for spec in specs:
        for v in spec.variants:
            src, gen = (evaluation(ms, params, spec.name, backend, d, v) for d in ("source", v))
            if v != "D0" and src is None and gen is None:
                continue
            protocols |= {
                (
                    m.values.get("episodes"),
                    m.values.get("every_epochs"),
                    m.values.get("checkpoints"),
                )
                for m in (src, gen)
                if m is not None
            }
            other = of_other_run(gen, "data_run_id", policy_data(ms, params, spec.name, backend, v))
            marked |= other
            ref = [
                e
                for d in ("source", v)
                for e in paper.find(table="P.1", task=spec.paper_task, data=d, variant=v)
            ]
            rows.append(
                (
                    f"{spec.name} ({v})",
                    spec.paper_task,
                    _sr(src),
                    _sr(gen) + (f" {OTHER_RUN}" if other else ""),
                    fmt_delta(
                        src.values.get("success_rate_max"), gen.values.get("success_rate_max")
                    )
                    if src and gen
                    else MISSING,
                    "; ".join(f"{e.data}: {e.cite()}" for e in ref) or "– (none in the paper)",
                )
            )
    columns = ("task (evaluated on)", "paper task", "source-only SR max / last",
               "generated SR max / last", "gain (max)", "paper (low-dim, P.1)")  # fmt: skip
    if len(protocols) == 1:
        ((episodes, every, checkpoints),) = protocols
        protocol = (
            f"{episodes} episodes on each of {checkpoints} checkpoints per policy (every "
            f"{every}th epoch and the last)"
        )
    else:
        protocol = "episodes and checkpoints per policy as in each evaluate metric"
    return [
        Heading(2, "Task suite: policy success rate (%)"),
        Text(
            "BC-RNN (cpu profile) trained on each task's 10 source demos and on the demos "
            f"generated for a variant (`suite/dvc.yaml`), evaluated on that variant: {protocol}."
            " One training seed each, but for `suite.seeded_policy_tasks`: a D0 policy only, "
            f"mean ± std over its {params.suite.policy_seeds} seeds as the paper's over 3. The "
            "paper's source agents are evaluated on D0 only."
        ),
        Table(columns, tuple(rows)),
        *([Text(other_run_note("train/evaluate"))] if marked else []),
    ]


def _rate(m: Metrics, kind: str) -> str:
    """Success rate ``kind`` (max or last over training); mean ± std over seeds where there
    are several; with its 95% interval."""
    return fmt_sr(m.values, kind, std=(m.values.get("seeds") or 1) > 1)


def _count(n: Any, what: str) -> str:
    return f"{fmt(n)} {what}" + ("" if n == 1 else "s")


def _sr(m: Metrics | None) -> str:
    """Success rate max / last over training."""
    return MISSING if m is None else f"{_rate(m, 'max')} / {_rate(m, 'last')}"


TARGET_MARGIN = 5.0  # [points] a paper-geometry task meets the paper when SR >= P.1 - this


PAPER_GEOMETRY_COLUMNS = ("task", "paper task", "DGR D0 % ours / O.1", "DGR D1 % ours / O.1",
                          "policies (profile or run)", "generated D0 SR max %",
                          "paper (P.1, D0)", "SR ≥ P.1 − 5")  # fmt: skip


def paper_geometry_rows(
    spec: TaskSpec,
    dgr: Sequence[Metrics | None],
    runs: Sequence[tuple[str, Metrics | None]],
    paper: PaperResults,
) -> list[tuple[str, ...]]:
    """The rows of one task built to the paper's geometry (PAPER_GEOMETRY_COLUMNS): its
    fixed attempts on D0 and D1 (``dgr``) beside Table O.1, then per run of ``runs`` (label,
    the evaluation of its D0 policies on D0) the success rate (max over training, mean ± std
    over seeds) beside Table P.1's, with whether it reaches P.1 − TARGET_MARGIN."""
    cells = []
    for v, ours in zip(("D0", "D1"), dgr, strict=True):
        ref = paper.find(table="O.1", task=spec.paper_task, variant=v, metric="dgr")
        cells.append(
            f"{fmt_dgr(ours.values) if ours else MISSING} / {fmt(ref[0].value) if ref else MISSING}"
        )
    ref = paper.find(table="P.1", task=spec.paper_task, data="D0", variant="D0")
    target = ref[0].value - TARGET_MARGIN if ref else None
    rows = []
    for i, (label, ev) in enumerate(runs):
        sr = ev.values.get("success_rate_max") if ev else None
        met = MISSING if sr is None or target is None else ("yes" if sr >= target else "no")
        rows.append(
            (
                f"`{spec.name}`" if i == 0 else "",
                spec.paper_task if i == 0 else "",
                *(cells if i == 0 else ("", "")),
                label,
                f"{_rate(ev, 'max')} ({_count(ev.values.get('seeds'), 'seed')})" if ev else MISSING,
                ref[0].cite() if ref else MISSING,
                f"{met} (≥ {fmt(target)})" if target is not None else MISSING,
            )
        )
    return rows


def paper_geometry_blocks(
    params: Params, specs: Sequence[TaskSpec], ms: MetricsSet, paper: PaperResults
) -> list[Block]:
    """The tasks of suite.seeded_policy_tasks (the paper's own geometry) in one table
    (:func:`paper_geometry_rows`) of the suite's own policies (runs made outside the
    pipeline have a section of their own, mimicgen_pipe.report.profiles)."""
    seeded = [s for s in specs if s.name in params.suite.seeded_policy_tasks]
    if not seeded:
        return []
    rows = []
    for spec in seeded:
        dgr = [dgr_run(ms, params, spec.name, v) for v in ("D0", "D1")]
        ev = evaluation(ms, params, spec.name, params.suite.backend, "D0", "D0")
        rows += paper_geometry_rows(
            spec, dgr, [(f"`{params.train.profile}` (the suite's)", ev)], paper
        )
    return [
        Heading(2, "The paper's own geometry"),
        Text(
            "The tasks built to the paper's geometry (`suite.seeded_policy_tasks`), where "
            "our numbers should meet the paper's: the suite's fixed attempts on D0 and D1, "
            f"and the D0 policies trained on {params.train.num_demos} generated demos with "
            f"{params.suite.policy_seeds} seeds (mean ± std of the max over training), "
            f"beside Tables O.1 and P.1. The target is P.1 − {fmt(TARGET_MARGIN)} points. "
            "Policies of other training profiles on the same demos, made outside the "
            "pipeline, are in the report's last section."
        ),
        Table(PAPER_GEOMETRY_COLUMNS, tuple(rows)),
    ]


LONG = 5  # subtasks from which a task is long (the paper's long tasks have 5 to 8)
# the paper's long tasks and their subtasks (Appendix J's task list)
PAPER_LONG_TASKS = {"Kitchen": 7, "Coffee Preparation": 5}


def long_task_blocks(
    params: Params, specs: Sequence[TaskSpec], ms: MetricsSet, paper: PaperResults
) -> list[Block]:
    """The suite's long one-arm tasks (LONG or more subtasks) in one table with the paper's long
    tasks: subtasks, DGR per variant (Table O.1) and the success rate of policies trained on
    the source demos and on D0's generated demos, evaluated on D0 (max over training; P.1)."""
    longs = [s for s in specs if len(s.subtasks) >= LONG and not s.several_arms]
    if not longs:
        return []
    variants = ("D0", "D1", "D2")
    rows = []
    for spec in longs:
        dgr = [dgr_run(ms, params, spec.name, v) for v in variants]
        sr = [
            evaluation(ms, params, spec.name, params.suite.backend, d, "D0")
            for d in ("source", "D0")
        ]
        rows.append(
            (
                f"`{spec.name}` (ours)",
                str(len(spec.subtasks)),
                *(_kept(m.values) if m else MISSING for m in dgr),
                *(fmt_sr(m.values, std=False) if m else MISSING for m in sr),
            )
        )
    for task, subtasks in PAPER_LONG_TASKS.items():
        dgr = [paper.find(table="O.1", task=task, variant=v, metric="dgr") for v in variants]
        sr = [paper.find(table="P.1", task=task, data=d, variant="D0") for d in ("source", "D0")]
        rows.append(
            (
                f"{task} (paper)",
                str(subtasks),
                *(f"{e[0].value:.1f}" if e else MISSING for e in dgr),
                *(f"{e[0].value:.1f} ± {e[0].std:.1f}" if e else MISSING for e in sr),
            )
        )
    columns = ("task", "subtasks", *(f"DGR {v} %" for v in variants),
               "source-only SR % (D0)", "generated D0 SR % (D0)")  # fmt: skip
    return [
        Heading(2, "Long tasks beside the paper's"),
        Text(
            f"The suite's tasks of {LONG} subtasks or more, with the paper's long tasks "
            "(Tables O.1 and P.1; policies: max success rate over training, the paper's over 3 "
            "seeds). Ours: the suite's fixed attempts per variant and its D0 policies, as in "
            "the tables above."
        ),
        Table(columns, tuple(rows)),
    ]


def two_arm_blocks(params: Params, specs: Sequence[TaskSpec], ms: MetricsSet) -> list[Block]:
    """The suite's tasks with two arms (beyond the paper, its limitation 9): each arm's
    subtasks, the constraints between them, the DGR per variant with the failures charged to
    each arm, and the source-only and generated D0 policies on D0 (max / last over
    training)."""
    twos = [s for s in specs if s.several_arms]
    if not twos:
        return []
    rows = []
    for spec in twos:
        arms = "; ".join(
            f"{a}: " + ", ".join(s.name for s in spec.arm_subtasks(a)) for a in spec.arms
        )
        constraints = "; ".join(
            f"{c.kind}: {c.first[0]} {c.first[1]} → {c.second[0]} {c.second[1]}"
            if c.kind == "sequential"
            else f"{c.kind}: {c.first[0]} {c.first[1]} with {c.second[0]} {c.second[1]}"
            for c in spec.constraints
        )
        dgr = []
        for v in params.suite.variants:
            g = dgr_run(ms, params, spec.name, v)
            if g is None:
                dgr.append(MISSING)
                continue
            per_arm = {
                a: sum(g.values.get(f"failures_{s.name}", 0) for s in spec.arm_subtasks(a))
                for a in spec.arms
            }
            charged = ", ".join(f"{a} {n}" for a, n in per_arm.items())
            dgr.append(f"{_kept(g.values)}; failed: {charged}")
        backend = params.suite.backend
        sr = [evaluation(ms, params, spec.name, backend, d, "D0") for d in ("source", "D0")]
        rows.append((f"`{spec.name}`", arms, constraints or "–", *dgr, *(_sr(m) for m in sr)))
    columns = ("task", "subtasks per arm", "constraints",
               *(f"DGR {v} % (failures per arm)" for v in params.suite.variants),
               "source-only SR % (D0) max / last", "generated D0 SR % (D0) max / last")  # fmt: skip
    return [
        Heading(2, "Two arms"),
        Text(
            "Tasks with two arms, beyond the paper (its limitation 9): each arm has its own "
            "subtasks; a sequential constraint makes one arm's subtask wait for the other's "
            "end, a coordinated one runs two subtasks together from one source demo and one "
            "observed pose of their shared object. A failed attempt is charged to the arm and "
            "subtask it first failed in (per subtask in the DGR table above). Actions are 7 per "
            "arm (14); policies observe both arms' end effectors and grippers. DGR and "
            "policies as in the tables above."
        ),
        Table(columns, tuple(rows)),
    ]
