"""The suite's policies by training profile: D0 policies trained with several seeds under
other budgets than the suite's own one-seed `cpu` runs (the `cpu` profile with 3 seeds, the
paper's profile trained on a GPU by scripts/paper_profile.py), beside Table P.1. Each run's
metrics live in their own folder, PROFILES/<run> under the suite's metrics, as train and
evaluate metrics of data D0; a train metric of a GPU run also says its device, matmul
precision and epochs reached."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from mimicgen_pipe.params import Params
from mimicgen_pipe.report.blocks import Block, Heading, Table, Text
from mimicgen_pipe.report.fmt import MISSING, fmt, fmt_pm
from mimicgen_pipe.report.inputs import MetricsSet, read_metrics_folder
from mimicgen_pipe.report.paper import PaperResults
from mimicgen_pipe.taskspec import TaskSpec

PROFILES = "profiles"  # the runs' metrics folders, in the suite's metrics folder


def read_profile_runs(metrics_dir: Path) -> dict[str, MetricsSet]:
    """Run name -> its metrics folder (PROFILES/<run>), in name order; none: empty."""
    root = metrics_dir / PROFILES
    if not root.is_dir():
        return {}
    return {p.name: read_metrics_folder(p) for p in sorted(root.iterdir()) if p.is_dir()}


def profile_blocks(
    params: Params,
    specs: Sequence[TaskSpec],
    runs: Mapping[str, MetricsSet],
    paper: PaperResults,
) -> list[Block]:
    """One row per (task, run) with a D0 evaluation: the arm its data was generated with and
    it acts with, the profile and where it trained, the network width, epochs, seeds,
    checkpoints rolled out per seed, and success rate max / last over training as mean ± std
    over seeds, beside the paper's generated-D0 agents (Panda's, Table P.1)."""
    backend = params.suite.backend
    rows = []
    for spec in specs:
        for name, ms in runs.items():
            ev = ms.one(stage="evaluate", task=spec.name, backend=backend, data="D0")
            if ev is None:
                continue
            train = ms.one(stage="train", task=spec.name, backend=backend, data="D0")
            t = train.values if train is not None else {}
            profile = t.get("profile")
            prof = getattr(params.train, profile) if profile in ("cpu", "paper") else None
            seeds = t.get("seeds") or ev.values.get("seeds")
            epochs = t.get("epochs")
            if epochs is None and prof is not None and seeds:
                epochs = t["gradient_steps"] // (seeds * prof.steps_per_epoch)
            where = t.get("device", "cpu")
            if "matmul" in t:
                where += f", {t['matmul']}"
            ref = paper.find(table="P.1", task=spec.paper_task, data="D0", variant="D0")
            v = ev.values
            rows.append(
                (
                    spec.name,
                    name,
                    ev.robot or MISSING,
                    f"{profile or MISSING} ({where})",
                    str(prof.hidden) if prof is not None else MISSING,
                    fmt(epochs, 0),
                    fmt(seeds, 0),
                    fmt(v.get("checkpoints"), 0),
                    fmt_pm(v.get("success_rate_max"), v.get("success_rate_max_std")),
                    fmt_pm(v.get("success_rate_last"), v.get("success_rate_last_std")),
                    "; ".join(e.cite() for e in ref) or "–",
                )
            )
    if not rows:
        return []
    columns = ("task", "run", "arm", "profile (trained on)", "hidden", "epochs", "seeds",
               "checkpoints per seed", "generated D0 SR max", "SR last",
               "paper (P.1, generated D0)")  # fmt: skip
    return [
        Heading(2, "Task suite: D0 policies by training profile (%)"),
        Text(
            "BC-RNN on 1000 generated D0 demos (the suite's policy data; the default "
            "pipeline's D0 store for its task; for another arm, demos generated for it from "
            "the same source demos, the policy acting with it), evaluated on D0 with 50 "
            "episodes per checkpoint; success rate mean ± std over training seeds, max over "
            "the checkpoints evaluated and the last. The paper's column is its Panda agents. "
            f"Runs in `suite/metrics/{PROFILES}/<run>`; a GPU run's weights come back as "
            "float16 (scripts/paper_profile.py)."
        ),
        Table(columns, tuple(rows)),
    ]
