"""What the report reads: the metrics files of a folder, selected by their identity fields
(mimicgen_pipe.data.metrics), ablation runs, heat maps and the render stage's videos."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data import layout
from mimicgen_pipe.data.metrics import GENERATE_PURPOSE, Metrics, read_metrics
from mimicgen_pipe.data.outputs import check_committed_in
from mimicgen_pipe.data.params import Params, load_params


@dataclass(frozen=True)
class MetricsSet:
    """The metrics files of one folder."""

    files: tuple[Metrics, ...]

    def find(self, **identity: Any) -> list[Metrics]:
        """The files whose identity fields have the given values (the others: any)."""
        return [m for m in self.files if all(getattr(m, k) == v for k, v in identity.items())]

    def one(self, **identity: Any) -> Metrics | None:
        """The file with the given identity, None if absent; InputError naming the files when
        several have it (two runs the report cannot tell apart)."""
        found = self.find(**identity)
        if len(found) > 1:
            what = ", ".join(f"{k}={v}" for k, v in identity.items())
            raise InputError(
                f"{' and '.join(str(m.path) for m in found)}: metrics of the same {what}; "
                "keep one of them"
            )
        return found[0] if found else None


def read_metrics_folder(folder: str | Path) -> MetricsSet:
    """Every metrics JSON directly in ``folder`` (InputError for one without its identity)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: metrics folder not found")
    check_committed_in(folder)  # never read a set that a killed run left half committed
    return MetricsSet(tuple(read_metrics(p) for p in sorted(folder.glob("*.json"))))


@dataclass(frozen=True)
class Run:
    """A saved run (an ablation): its name, params and metrics."""

    name: str
    params: Params
    metrics: MetricsSet


def read_runs(folder: str | Path) -> list[Run]:
    """The saved runs in ``folder``: one sub-folder each, with its params.yaml and metrics."""
    runs = []
    for sub in sorted(p for p in Path(folder).glob("*") if p.is_dir()):
        if not (sub / "params.yaml").exists():
            raise InputError(f"{sub}: params.yaml missing (an ablation run saves its params)")
        runs.append(Run(sub.name, load_params(sub / "params.yaml"), read_metrics_folder(sub)))
    return runs


def policy_data(
    ms: MetricsSet, params: Params, task: str, backend: str, variant: str
) -> Metrics | None:
    """The generate run whose store policies of ``variant`` train on (generate.mode decides
    its purpose), None if absent."""
    g = params.generate
    return ms.one(
        stage="generate",
        task=task,
        backend=backend,
        variant=variant,
        robot=g.robot,
        purpose=GENERATE_PURPOSE[g.mode],
    )


def policy_robot(params: Params, data: str) -> str:
    """The arm a policy trained on ``data`` acts with: the one its data was recorded with."""
    return params.source.robot if data == "source" else params.generate.robot


def evaluation(
    ms: MetricsSet, params: Params, task: str, backend: str, data: str, variant: str
) -> Metrics | None:
    """The evaluation of the policy trained on ``data`` in ``variant`` (rolled out with
    :func:`policy_robot`), None if absent."""
    robot = policy_robot(params, data)
    return ms.one(
        stage="evaluate", task=task, backend=backend, variant=variant, data=data, robot=robot
    )


def evaluated(ms: MetricsSet, params: Params) -> list[tuple[str, str]]:
    """(data, variant) of every evaluation of the main task in ``ms`` whose policy acted with
    the arm its data was recorded with (:func:`policy_robot`), sorted."""
    return sorted(
        (str(m.data), str(m.variant))
        for m in ms.find(stage="evaluate", task=params.task, backend=params.backend)
        if m.robot == policy_robot(params, str(m.data))
    )


def trained(ms: MetricsSet, params: Params) -> list[str]:
    """The data of every policy of the main task trained in ``ms`` (on data recorded with
    :func:`policy_robot`), the source demos first."""
    return sorted(
        (
            str(m.data)
            for m in ms.find(stage="train", task=params.task, backend=params.backend)
            if m.robot == policy_robot(params, str(m.data))
        ),
        key=lambda d: (d != "source", d),
    )


def coverage(ms: MetricsSet, params: Params, variant: str) -> Metrics | None:
    """The support coverage of the main task's scenes of ``variant`` generated with
    generate.robot, None if absent."""
    return ms.one(
        stage="coverage",
        task=params.task,
        backend=params.backend,
        variant=variant,
        robot=params.generate.robot,
    )


# marks a row measured on the data of another generate run than the one shown beside it
OTHER_RUN = "†"


def of_other_run(m: Metrics | None, key: str, generate: Metrics | None) -> bool:
    """Whether ``m`` measured the data of another generate run than ``generate``: its
    ``key`` (coverage: run_id, train and evaluate: data_run_id) against the generate run's
    run_id; False where either is unknown."""
    if m is None or generate is None:
        return False
    ours, theirs = m.values.get(key), generate.values.get("run_id")
    return ours is not None and theirs is not None and ours != theirs


def other_run_note(stage: str) -> str:
    return (
        f"{OTHER_RUN} measured on the data of another generate run than the one whose "
        f"metrics are shown here (the run ids differ): {stage} has not been re-run since "
        "generate was; `dvc repro` brings it up to date."
    )


@dataclass(frozen=True)
class Media:
    """The render stage's videos of one variant: their file names."""

    files: frozenset[str]


def read_heatmaps(plots: str | Path, task: str, variants: Sequence[str]) -> dict[str, Path]:
    """Variant -> its coverage heat maps in ``plots``, for the variants that have them."""
    found = {v: Path(plots) / layout.heatmap_file(task, v).name for v in variants}
    return {v: p for v, p in found.items() if p.exists()}


def link(path: str | Path, folder: str | Path) -> str:
    """``path`` as a report in ``folder`` refers to it: relative to ``folder``,
    '/'-separated."""
    return Path(os.path.relpath(path, folder)).as_posix()


def read_media(
    ms: MetricsSet, task: str, backend: str, variants: Sequence[str]
) -> Mapping[str, Media]:
    """Variant -> its videos where the render stage keeps them (layout.media_dir); variants
    without videos, or whose render metrics are not in ``ms`` (another pipeline's videos),
    are left out."""
    media = {}
    for v in variants:
        folder = layout.media_dir(task, v)
        m = ms.one(stage="render", task=task, backend=backend, variant=v)
        if folder.is_dir() and m is not None:
            media[v] = Media(frozenset(p.name for p in folder.iterdir()))
    return media
