"""The main task's policies over training: their loss per epoch and the success rate of each
checkpoint rolled out, drawn as PNG figures from the CSV files train and evaluate write
(layout.plot_file), so that the report and ``dvc plots show`` need no network to show them.

Each policy's CSV is chosen by the metrics that say it was trained or evaluated
(:func:`~mimicgen_pipe.report.inputs.trained`, :func:`~mimicgen_pipe.report.inputs.evaluated`);
a CSV that is absent is left out of its figure, and a figure with nothing to draw is not made.
The same CSVs give the same PNG bytes: fixed size, resolution and style, no version or date.
"""

from __future__ import annotations

import contextlib
import csv
import io
import itertools
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.figures import quiet_matplotlib_import
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.params import Params
from mimicgen_pipe.report.blocks import Block, Heading, Image, Text
from mimicgen_pipe.report.inputs import MetricsSet, evaluated, trained

if TYPE_CHECKING:
    from matplotlib.axes import Axes

TRAINING_CURVES = "training_curves.png"
SUCCESS_RATES = "success_rates.png"
# figure file -> its caption, in the report's order
FIGURES = {
    TRAINING_CURVES: "training and validation loss per epoch, one panel per policy",
    SUCCESS_RATES: "success rate per checkpoint rolled out",
}
PANEL_INCHES, PANELS_PER_ROW, DPI = (5.0, 3.6), 3, 100  # the same size, the same bytes


@dataclass(frozen=True)
class Curve:
    """One CSV's columns per epoch, each the mean over the training seeds in it."""

    label: str
    seeds: int
    epochs: np.ndarray  # (n,) epochs, ascending
    columns: Mapping[str, np.ndarray]  # column name -> (n,) values


def read_curve(path: Path, label: str, columns: Sequence[str]) -> Curve | None:
    """``columns`` of a curve CSV (one row per training seed and epoch: seed, epoch, ...)
    averaged over seeds per epoch; None when the file is absent or has no rows."""
    if not path.is_file():
        return None
    expected = f"a curve CSV with columns {', '.join(('seed', 'epoch', *columns))}"
    by_epoch: dict[int, list[list[float]]] = {}
    seeds: set[str] = set()
    try:
        with path.open(newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            missing = [c for c in ("seed", "epoch", *columns) if c not in (reader.fieldnames or ())]
            if missing:
                raise InputError(
                    f"{path}: columns {', '.join(missing)} missing; expected {expected}"
                )
            for row in reader:
                try:
                    by_epoch.setdefault(int(row["epoch"]), []).append(
                        [float(row[c]) for c in columns]
                    )
                except (TypeError, ValueError):
                    raise InputError(
                        f"{path}: line {reader.line_num}: expected numbers in {expected}"
                    ) from None
                seeds.add(row["seed"])
    except UnicodeDecodeError:
        raise InputError(f"{path}: not UTF-8 text; expected {expected}") from None
    if not by_epoch:
        return None
    epochs = np.array(sorted(by_epoch))
    means = np.array([np.mean(by_epoch[e], axis=0) for e in epochs])
    return Curve(label, len(seeds), epochs, {c: means[:, i] for i, c in enumerate(columns)})


def _policy(data: str) -> str:
    return "source demos" if data == "source" else f"generated {data}"


def read_curves(
    ms: MetricsSet, params: Params, plots: str | Path
) -> tuple[list[Curve], list[Curve]]:
    """The main task's training curves (loss, val_loss) and success rates per checkpoint
    (success_rate [%]) in ``plots``, for the policies ``ms`` says were trained / evaluated."""
    task = params.task

    def csv_of(stage: str, name: str) -> Path:
        return Path(plots) / layout.plot_file(stage, task, name).name

    training = [
        read_curve(csv_of("train", d), _policy(d), ("loss", "val_loss"))
        for d in trained(ms, params)
    ]
    success = [
        read_curve(csv_of("evaluate", f"{d}_on_{v}"), f"{_policy(d)} on {v}", ("success_rate",))
        for d, v in evaluated(ms, params)
    ]
    return [c for c in training if c], [c for c in success if c]


@contextlib.contextmanager
def figure(out: io.BytesIO, title: str, panels: int) -> Iterator[list[Axes]]:
    """``panels`` axes to draw on, PANELS_PER_ROW to a row; when the block ends, the figure
    is written to ``out`` as PNG."""
    with quiet_matplotlib_import():
        import matplotlib.style
        from matplotlib.figure import Figure

    cols, rows = min(panels, PANELS_PER_ROW), -(-panels // PANELS_PER_ROW)
    # matplotlib's own style, not a matplotlibrc's: the same curves give the same bytes
    with matplotlib.style.context("default"):
        fig = Figure(figsize=(PANEL_INCHES[0] * cols, PANEL_INCHES[1] * rows), dpi=DPI,
                     layout="constrained")  # fmt: skip
        axes = list(fig.subplots(rows, cols, squeeze=False).ravel())
        for ax in axes[panels:]:
            fig.delaxes(ax)
        yield axes[:panels]
        for ax in axes[:panels]:
            ax.grid(alpha=0.3)
            ax.legend(fontsize="small")
        fig.suptitle(title)
        fig.savefig(out, format="png", dpi=DPI, metadata={"Software": None})


def _seeds(c: Curve) -> str:
    return f" ({c.seeds} seeds)" if c.seeds > 1 else ""


def draw_curves(task: str, training: Sequence[Curve], success: Sequence[Curve]) -> dict[str, bytes]:
    """Figure file -> PNG bytes (FIGURES), for the figures with a curve to draw: the training
    curves one panel per policy (each its own loss scale), the success rates in one panel."""
    figures = {}
    if training:
        out = io.BytesIO()
        with figure(out, f"{task}: training curves", len(training)) as axes:
            for ax, c in zip(axes, training, strict=True):
                ax.plot(c.epochs, c.columns["loss"], label="loss")
                ax.plot(c.epochs, c.columns["val_loss"], linestyle="--", label="val_loss")
                ax.set_title(f"trained on {c.label}{_seeds(c)}")
                ax.set_xlabel("epoch")
                ax.set_ylabel("loss (NLL)")
        figures[TRAINING_CURVES] = out.getvalue()
    if success:
        out = io.BytesIO()
        with figure(out, f"{task}: success rate per checkpoint", 1) as (ax,):
            for c, marker in zip(success, itertools.cycle("os^Dv"), strict=False):
                ax.plot(c.epochs, c.columns["success_rate"], marker=marker,
                        label=f"{c.label}{_seeds(c)}")  # fmt: skip
            ax.set_ylim(-2.0, 102.0)
            ax.set_xlabel("checkpoint epoch")
            ax.set_ylabel("success rate [%]")
        figures[SUCCESS_RATES] = out.getvalue()
    return figures


def curve_blocks(task: str, figures: Sequence[str]) -> list[Block]:
    """The section showing the figure files ``figures`` (those made), none when there are
    none."""
    if not figures:
        return []
    return [
        Heading(2, "Policies over training"),
        Text(
            f"The policies of `{task}` over training, drawn from the train and evaluate "
            "stages' CSV files: each curve the mean over the policy's training seeds where it "
            "has several."
        ),
        *(Image(name, alt) for name, alt in FIGURES.items() if name in figures),
    ]
