"""Where each stage's declared outputs live (relative to the repository root); dvc.yaml
names the same paths. A stage run with another pipeline's params file finds each top folder
(data/, metrics/, ...) where that pipeline's dvc.yaml keeps it (:func:`pipelines.use_pipeline`),
e.g. quickstart/data/. A stage run by hand, outside DVC, writes a default output that a
pipeline tracks under :data:`SCRATCH` instead (``mimicgen_pipe.stages.output_path``)."""

from __future__ import annotations

from pathlib import Path

from mimicgen_pipe.data import pipelines

SCRATCH = Path("scratch")  # ignored by git; the same layout below it


def _at(path: Path) -> Path:
    """``path`` below the folder where the running stage's pipeline keeps its first folder
    (unchanged for the default pipeline and outside any pipeline)."""
    return pipelines.layout_roots().get(path.parts[0], Path()) / path


def source_store(task: str) -> Path:
    return _at(Path("data/source") / f"{task}.zarr")


def parsed_store(task: str) -> Path:
    return _at(Path("data/parsed") / f"{task}.zarr")


def pose_noise_store(task: str) -> Path:
    """The parsed source demos as the generator observes them (pose_noise stage; an
    unperturbed copy at level none)."""
    return _at(Path("data/pose_noise") / f"{task}.zarr")


def generate_input(task: str) -> Path:
    """The store generate reads by default: the pose_noise stage's, or the parsed store in
    a pipeline without that stage (the quickstart's generate reads its parsed store)."""
    noisy = pose_noise_store(task)
    return noisy if pipelines.declares(noisy) else parsed_store(task)


def heatmap_file(task: str, variant: str) -> Path:
    """The coverage stage's heat maps of initial object positions."""
    return plots_dir() / f"coverage_{task}_{variant}.png"


def report_dir() -> Path:
    return _at(Path("report"))


def metrics_dir() -> Path:
    """The metrics folder the report reads."""
    return _at(Path("metrics"))


def plots_dir() -> Path:
    """The folder of the coverage heat maps and the train and evaluate CSVs."""
    return _at(Path("plots"))


def ablations_dir() -> Path:
    """Ablation runs (the ablation stages): one folder per run with its params.yaml and
    metrics JSON files."""
    return metrics_dir() / "ablations"


def ablation_stores(run: str) -> Path:
    """An ablation run's stores (the ablation stage): pose-noised, kept and failed, coverage
    table and heat maps."""
    return _at(Path("data/ablations") / run)


def generated_store(task: str, variant: str, failed: bool = False) -> Path:
    return _at(Path("data/generated") / f"{task}_{variant}{'_failed' if failed else ''}.zarr")


def observed_store(task: str, variant: str) -> Path:
    """The observe stage's store: a generated (or other) store's first episodes with camera
    images (data/obs/<camera>_image)."""
    return _at(Path("data/observed") / f"{task}_{variant}.zarr")


def failed_store(kept: Path) -> Path:
    """Where a generate run's failed attempts lie: <name>_failed.zarr beside its kept store
    <name>.zarr (<name>_failed beside a kept store named without .zarr): never the kept
    store's own path."""
    stem = kept.name.removesuffix(".zarr")
    return kept.with_name(f"{stem}_failed{kept.name[len(stem) :]}")


def metrics_file(stage: str, task: str, variant: str | None = None) -> Path:
    name = f"{stage}_{task}" + (f"_{variant}" if variant else "")
    return metrics_dir() / f"{name}.json"


def training_store(task: str, data: str) -> Path:
    """The store a policy trains on: ``data`` is "source" (the source demos) or a reset
    variant (that variant's generated store)."""
    return source_store(task) if data == "source" else generated_store(task, data)


def policy_dir(task: str, data: str) -> Path:
    """Checkpoints of every training seed: <dir>/seed<k>/epoch<NNNNN>.pt."""
    return _at(Path("data/policies") / f"{task}_{data}")


def plot_file(stage: str, task: str, name: str) -> Path:
    return plots_dir() / f"{stage}_{task}_{name}.csv"


def external_evaluation_files(task: str, name: str) -> tuple[Path, Path]:
    """The metrics JSON and per-episode CSV of an evaluation of a policy trained elsewhere
    (``evaluate --policy``), apart from the pipeline's own: the report reads neither."""
    stem = f"evaluate_{task}_{name}"
    return metrics_dir() / "external" / f"{stem}.json", plots_dir() / "external" / f"{stem}.csv"


def export_dir(store_name: str) -> Path:
    """The export stage's directory for a store (its name without .zarr): one file or
    folder per format (each exporter's FILE_NAME, mimicgen_pipe.formats.exporters)."""
    return _at(Path("data/export") / store_name)


MEDIA = Path("media")  # the render stage's videos (kept in git: the report shows its GIFs)


def media_dir(task: str, variant: str) -> Path:
    """The render stage's videos of one variant."""
    return _at(MEDIA / f"{task}_{variant}")
