"""The suite's dataset-size comparison (params suite.scaling; paper Fig. P.1, right): the
success rate of policies trained on the first N of one store's generated demos, for each N,
as a table and a figure. Its metrics live in their own folder (SCALING under the suite's
metrics): their generate run has the identity of the suite's own policy data."""

from __future__ import annotations

import io

from mimicgen_pipe.data.metrics import Metrics
from mimicgen_pipe.data.params import Params
from mimicgen_pipe.report.blocks import Block, Heading, Image, Table, Text
from mimicgen_pipe.report.curves import figure
from mimicgen_pipe.report.fmt import MISSING, fmt, fmt_dgr, fmt_sr
from mimicgen_pipe.report.inputs import (
    OTHER_RUN,
    MetricsSet,
    evaluation,
    of_other_run,
    other_run_note,
    policy_data,
)

SCALING = "scaling"  # the comparison's metrics folder, in the suite's metrics folder
DATASET_SIZE = "dataset_size.png"  # its figure, beside the suite's report


def data_name(variant: str, n: int) -> str:
    """The training data name of the policy on the first ``n`` demos (train --data)."""
    return f"{variant}_n{n}"


def scaling_runs(
    params: Params, ms: MetricsSet
) -> list[tuple[int, Metrics | None, Metrics | None]]:
    """(N, train metrics, evaluate metrics) for each N of suite.scaling.num_demos, from the
    comparison's metrics folder ``ms``; None where absent."""
    s, backend = params.suite.scaling, params.suite.backend
    if s.task is None:
        return []
    out = []
    for n in s.num_demos:
        data = data_name(s.variant, n)
        train = ms.one(stage="train", task=s.task, backend=backend, data=data)
        out.append((n, train, evaluation(ms, params, s.task, backend, data, s.variant)))
    return out


def draw_dataset_size(params: Params, ms: MetricsSet) -> dict[str, bytes]:
    """{DATASET_SIZE: PNG bytes}: success rate (max over training and last checkpoint, mean
    over training seeds) against N, on a log axis; empty when nothing was evaluated."""
    s = params.suite.scaling
    points = [(n, e.values) for n, _, e in scaling_runs(params, ms) if e is not None]
    if not points:
        return {}
    ns = [n for n, _ in points]
    out = io.BytesIO()
    with figure(out, f"{s.task} ({s.variant}): success rate by dataset size", 1) as (ax,):
        for key, marker, style, label in (
            ("success_rate_max", "o", "-", "max over training"),
            ("success_rate_last", "s", "--", "last checkpoint"),
        ):
            ax.plot(ns, [v.get(key) for _, v in points], marker=marker, linestyle=style,
                    label=label)  # fmt: skip
        ax.set_xscale("log")
        ax.set_xticks(ns, [str(n) for n in ns])
        ax.minorticks_off()
        ax.set_ylim(-2.0, 102.0)
        ax.set_xlabel("generated demos trained on")
        ax.set_ylabel("success rate [%]")
    return {DATASET_SIZE: out.getvalue()}


def scaling_blocks(params: Params, ms: MetricsSet, figures: dict[str, bytes]) -> list[Block]:
    """The comparison's section: the store the policies drew from, one row per N, and the
    figure where it was drawn (``figures``)."""
    s, backend = params.suite.scaling, params.suite.backend
    if s.task is None:
        return []
    runs = scaling_runs(params, ms)
    store = policy_data(ms, params, s.task, backend, s.variant)
    if store is None and all(t is None and e is None for _, t, e in runs):
        return []
    marked = False
    rows = []
    for n, train, ev in runs:
        other = of_other_run(ev, "data_run_id", store) or of_other_run(train, "data_run_id", store)
        marked |= other
        episodes = (
            f"{train.values['train_episodes']} / {train.values['val_episodes']}"
            if train is not None
            else MISSING
        )
        v = ev.values if ev is not None else {}
        rows.append(
            (
                str(n),
                episodes,
                fmt_sr(v, "max") + (f" {OTHER_RUN}" if other else ""),
                fmt_sr(v, "last"),
                fmt(v.get("seeds")) if ev is not None else MISSING,
            )
        )
    made = (
        f"the first N of {store.values['successes']} demos kept of "
        f"{store.values['attempts']} attempts (DGR {fmt_dgr(store.values)} %)"
        if store is not None
        else f"the first N demos of one store ({MISSING})"
    )
    blocks: list[Block] = [
        Heading(2, f"Policies on more or fewer generated demos: {s.task} ({s.variant})"),
        Text(
            f"As the paper's Fig. P.1 (right), which compares 200, 1000 and 5000 generated "
            f"demos (its numbers are in a figure only, not here): BC-RNN policies trained on "
            f"{made} of {s.task} on {s.variant}, each evaluated on {s.variant} with the "
            "evaluate stage's protocol; success rate max over training and at the last "
            "checkpoint, mean ± std over training seeds. Every policy trains for the same "
            "gradient steps, so a larger dataset is seen fewer times."
        ),
        Table(
            (
                "demos N",
                "episodes trained / validated",
                "success rate max %",
                "success rate last %",
                "seeds",
            ),
            tuple(rows),
        ),
    ]
    if marked:
        blocks.append(Text(other_run_note("train or evaluate")))
    if DATASET_SIZE in figures:
        blocks.append(Image(DATASET_SIZE, "success rate by dataset size"))
    return blocks
