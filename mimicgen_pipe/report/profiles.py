"""The suite's policies by training profile: policies on generated D0 or D1 data trained
with several seeds under other budgets than the suite's own one-seed `cpu` runs (the `cpu`
profile with 3 seeds, the paper's profile trained on a GPU by scripts/paper_profile.py, data
generated for another arm), beside Tables P.1 and E.3. Each run's metrics live in their own
folder, PROFILES/<run> under the suite's metrics, as train and evaluate metrics of data D0
or D1 (evaluated in the same variant); a train metric of a GPU run also says its device,
matmul precision, epochs reached and the precision its weights came back in. None of these
runs is a pipeline stage's: MADE_BY, beside the runs' folders, says for each the commit that
added it, where it trained and the commands that made it, and the report shows them in a
section of their own."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from itertools import product
from pathlib import Path

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.taskspec import TaskSpec
from mimicgen_pipe.core.yamlfile import load_yaml
from mimicgen_pipe.data.params import Params
from mimicgen_pipe.report.blocks import Block, Heading, Table, Text
from mimicgen_pipe.report.fmt import MISSING, fmt, fmt_sr
from mimicgen_pipe.report.inputs import MetricsSet, read_metrics_folder
from mimicgen_pipe.report.paper import PaperResults

PROFILES = "profiles"  # the runs' metrics folders, in the suite's metrics folder
VARIANTS = ("D0", "D1")  # the variants with policies (paper P.1)
MADE_BY = "made_by.yaml"  # in PROFILES: run -> {commit, trained_on, command}
MADE_BY_KEYS = ("commit", "trained_on", "command")
MADE_BY_HAND = (
    "No stage of this pipeline makes these rows: each run was made by hand, on the machine "
    f"and with the commands the second table names (`suite/metrics/{PROFILES}/{MADE_BY}`), "
    "and `dvc repro` neither remakes nor checks them. The GPU runs are not bit-reproducible."
)


def read_profile_runs(metrics_dir: Path) -> dict[str, MetricsSet]:
    """Run name -> its metrics folder (PROFILES/<run>), in name order; none: empty."""
    root = metrics_dir / PROFILES
    if not root.is_dir():
        return {}
    return {p.name: read_metrics_folder(p) for p in sorted(root.iterdir()) if p.is_dir()}


def read_made_by(metrics_dir: Path) -> dict[str, dict[str, str]]:
    """How each run was made (MADE_BY in PROFILES): run -> its MADE_BY_KEYS as text; empty
    where there is no such file. InputError naming the file for another shape."""
    path = metrics_dir / PROFILES / MADE_BY
    if not path.is_file():
        return {}
    found = load_yaml(path, "the profile runs' provenance")
    ok = isinstance(found, dict) and all(
        isinstance(v, dict) and set(v) == set(MADE_BY_KEYS) for v in found.values()
    )
    if not ok:
        raise InputError(f"{path}: expected run: {{{', '.join(MADE_BY_KEYS)}}} for each run")
    return {str(run): {k: str(v[k]) for k in MADE_BY_KEYS} for run, v in found.items()}


PROFILE_COLUMNS = ("task", "variant", "run", "demos", "arm", "profile (trained on)", "hidden",
                   "epochs", "seeds", "checkpoints per seed", "horizon", "generated SR max",
                   "SR last", "paper (P.1, generated data)")  # fmt: skip


def profile_blocks(
    params: Params,
    specs: Sequence[TaskSpec],
    runs: Mapping[str, MetricsSet],
    paper: PaperResults,
    made_by: Mapping[str, Mapping[str, str]] | None = None,
) -> list[Block]:
    """One row per (task, variant, run) with an evaluation, in that variant, of a policy on
    generated data of that variant: the demos it trained and validated on, the arm its data
    was generated with and it acts with, the profile and where it trained, the network width,
    epochs, seeds, checkpoints rolled out per seed and their rollout horizon [steps], and
    success rate max / last over training as mean ± std over seeds, beside the paper's agents
    on generated data of the variant (Panda's, Table P.1)."""
    backend = params.suite.backend
    rows = []
    for spec, variant, (name, ms) in product(specs, VARIANTS, runs.items()):
        where = {"task": spec.name, "backend": backend, "data": variant}
        ev = ms.one(stage="evaluate", variant=variant, **where)
        if ev is None:
            continue
        train = ms.one(stage="train", **where)
        t = train.values if train is not None else {}
        profile = t.get("profile")
        prof = getattr(params.train, profile) if profile in ("cpu", "paper") else None
        seeds = t.get("seeds") or ev.values.get("seeds")
        epochs = t.get("epochs")
        if epochs is None and prof is not None and seeds:
            epochs = t["gradient_steps"] // (seeds * prof.steps_per_epoch)
        device = ", ".join(
            [t.get("device", "cpu")]
            + ([t["matmul"]] if "matmul" in t else [])
            # weights rounded on their way back move a policy's success (results.md)
            + (["float16 weights"] if t.get("weights_returned_as") == "float16" else [])
        )
        ref = paper.find(table="P.1", task=spec.paper_task, data=variant, variant=variant)
        v = ev.values
        demos = t.get("train_episodes", 0) + t.get("val_episodes", 0) or None
        rows.append(
            (
                spec.name,
                variant,
                name,
                fmt(demos, 0),
                ev.robot or MISSING,
                f"{profile or MISSING} ({device})",
                str(prof.hidden) if prof is not None else MISSING,
                fmt(epochs, 0),
                fmt(seeds, 0),
                fmt(v.get("checkpoints"), 0),
                fmt(v.get("horizon"), 0),
                fmt_sr(v, "max"),
                fmt_sr(v, "last"),
                "; ".join(e.cite() for e in ref) or "–",
            )
        )
    if not rows:
        return []
    return [
        Heading(2, "Made outside the pipeline: policies by training profile (%)"),
        Text(MADE_BY_HAND),
        Text(
            "BC-RNN on generated demos of a variant (1000: the suite's policy data; the "
            "default pipeline's store for its task; for another arm, demos generated for it "
            "from the same source demos, the policy acting with it; more: a longer run of the "
            "same generation, whose first 1000 demos are those), training and validation "
            "demos together, evaluated in that "
            "variant with 50 episodes per checkpoint; success rate mean ± std over training "
            "seeds, max over the checkpoints evaluated and the last. The paper's column is "
            f"its Panda agents{_other_arms(paper)}. Every policy here observes object poses "
            "(low-dim), as Table P.1's and E.3's do. "
            f"Runs in `suite/metrics/{PROFILES}/<run>`; a GPU run (scripts/paper_profile.py) "
            "names its device and matmul precision, and its weights where they came back as "
            "float16."
        ),
        Table(PROFILE_COLUMNS, tuple(rows)),
        made_by_table(runs, made_by or {}),
    ]


def made_by_table(runs: Iterable[str], made_by: Mapping[str, Mapping[str, str]]) -> Table:
    """Each run's commit, device and commands (MADE_BY), "not recorded" where it has none."""
    rows = tuple(
        (f"`{run}`", *(made_by.get(run, {}).get(k, "not recorded") for k in MADE_BY_KEYS))
        for run in runs
    )
    return Table(("run", "commit", "trained on", "made with"), rows)


def _other_arms(paper: PaperResults) -> str:
    """The paper's agents on data generated for other arms, low-dim (Table E.3) and image
    (Table E.2), as a clause of the table's text."""
    tables = []
    for table, kind in (("E.3", "low-dim"), ("E.2", "image agents")):
        cells = []
        for variant in VARIANTS:
            for task in sorted({e.task for e in paper.find(table=table, variant=variant)}):
                found = paper.find(table=table, task=task, variant=variant)
                panda = [e.value for e in found if e.condition == "Panda"]
                other = [e.value for e in found if e.condition != "Panda"]
                if panda and other:
                    cells.append(
                        f"{task} {variant} Panda {panda[0]:.1f}, "
                        f"other arms {min(other):.1f}–{max(other):.1f}"
                    )
        if cells:
            tables.append(f"Table {table}, {kind}: " + "; ".join(cells))
    return f" (on data generated for other arms, {'; '.join(tables)})" if tables else ""
