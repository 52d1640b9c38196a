"""The suite's outside learner: robomimic 0.3.0's own BC-RNN trained on the same D0 demos as
our learner (suite.robomimic_tasks; suite/robomimic/dvc.yaml), with its
observations as stored and normalized, beside our own D0 policy and Table P.1. Its metrics
live in their own folder, ROBOMIMIC under the suite's metrics: train and evaluate metrics
named ``<stage>_<task>_D0[_on_D0]_<obs>.json``, obs one of OBS."""

from __future__ import annotations

from collections.abc import Sequence

from mimicgen_pipe.core.taskspec import TaskSpec
from mimicgen_pipe.data.metrics import Metrics
from mimicgen_pipe.data.params import Params
from mimicgen_pipe.report.blocks import Block, Heading, Table, Text
from mimicgen_pipe.report.fmt import MISSING, fmt, fmt_sr
from mimicgen_pipe.report.inputs import MetricsSet, evaluation
from mimicgen_pipe.report.paper import PaperResults

ROBOMIMIC = "robomimic"  # the runs' metrics folder, in the suite's metrics folder
OBS = ("raw", "normalized")  # observations as stored, and normalized by robomimic


def _robomimic(ms: MetricsSet, task: str, obs: str) -> Metrics | None:
    """The evaluation of robomimic's D0 run of ``task`` with observations ``obs``."""
    found = [
        m
        for m in ms.find(stage="evaluate", task=task, data="D0", variant="D0")
        if m.path.stem.endswith(f"_{obs}")
    ]
    return found[0] if found else None


def _max_at(m: Metrics | None) -> str:
    """Success max over checkpoints [%], with the epoch of the best, and the last, each with
    its 95% interval."""
    if m is None:
        return MISSING
    v = m.values
    return (
        f"{fmt_sr(v, 'max', std=False)} (epoch {fmt(v.get('seed0_best_epoch'))}) / "
        f"{fmt_sr(v, 'last', std=False)}"
    )


def outside_learner_blocks(
    params: Params,
    specs: Sequence[TaskSpec],
    ms: MetricsSet,
    robomimic: MetricsSet,
    paper: PaperResults,
) -> list[Block]:
    """One row per task of suite.robomimic_tasks: our D0 policy's success (seed 0's max and
    last over training, and the mean ± std of the max where it has several seeds), robomimic's
    with raw and normalized observations (max, its epoch, and last), and Table P.1's D0."""
    tasks = [s for s in specs if s.name in params.suite.robomimic_tasks]
    if not tasks:
        return []
    rows = []
    for spec in tasks:
        ours = evaluation(ms, params, spec.name, params.suite.backend, "D0", "D0")
        v = ours.values if ours else {}
        seeds = v.get("seeds") or 1
        mean = f"; {fmt_sr(v, 'max')} over {seeds} seeds" if seeds > 1 else ""
        own = f"{fmt_sr(v, 'max', seed=0)} / {fmt_sr(v, 'last', seed=0)}{mean}" if ours else MISSING
        ref = paper.find(table="P.1", task=spec.paper_task, data="D0", variant="D0")
        rows.append(
            (
                f"`{spec.name}`",
                own,
                *(_max_at(_robomimic(robomimic, spec.name, obs)) for obs in OBS),
                ref[0].cite() if ref else MISSING,
            )
        )
    prof = params.train.active
    columns = ("task", "ours, seed 0: max / last", "robomimic, raw: max (epoch) / last",
               "robomimic, normalized: max (epoch) / last", "paper (P.1, D0)")  # fmt: skip
    return [
        Heading(2, "An outside learner on the same demos"),
        Text(
            "robomimic 0.3.0's own BC-RNN (`configs/robomimic/bc_rnn_low_dim.json`: GMM of 5 "
            f"modes) trained on the robomimic export of the {params.train.num_demos} D0 demos "
            f"our D0 policy trains on, at our `{params.train.profile}` profile's size and "
            f"schedule (2×{prof.hidden} LSTM, {prof.epochs} epochs × {prof.steps_per_epoch} "
            f"steps, seed {prof.seeds[0]}), with its observations as stored (robomimic's "
            "default) and normalized by robomimic (ours normalizes them), rolled out from "
            f"the scenes of our evaluation ({params.evaluate.episodes} episodes per "
            f"checkpoint, every {params.evaluate.every_epochs}th epoch). Success rate %."
        ),
        Table(columns, tuple(rows)),
    ]
