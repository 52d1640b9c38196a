"""Where each stage's declared outputs live (relative to the repository root); dvc.yaml
names the same paths."""

from __future__ import annotations

from pathlib import Path


def source_store(task: str) -> Path:
    return Path("data/source") / f"{task}.zarr"


def parsed_store(task: str) -> Path:
    return Path("data/parsed") / f"{task}.zarr"


def generated_store(task: str, variant: str, failed: bool = False) -> Path:
    return Path("data/generated") / f"{task}_{variant}{'_failed' if failed else ''}.zarr"


def metrics_file(stage: str, task: str, variant: str | None = None) -> Path:
    name = f"{stage}_{task}" + (f"_{variant}" if variant else "")
    return Path("metrics") / f"{name}.json"
