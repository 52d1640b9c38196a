"""Flat JSON metrics files, written atomically."""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np


def write_metrics(path: str | os.PathLike, metrics: Mapping[str, Any]) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(dict(metrics), indent=2, sort_keys=True) + "\n")
    tmp.replace(path)
    return path


def generation_metrics(
    success: np.ndarray, failed_subtask: np.ndarray, seconds: np.ndarray, subtasks: list[str]
) -> dict[str, Any]:
    """attempts, successes, dgr (data generation rate, %), seconds per attempt (mean, median),
    and failures per subtask (the first subtask an attempt did not achieve)."""
    n = len(success)
    out: dict[str, Any] = {
        "attempts": int(n),
        "successes": int(np.sum(success)),
        "dgr": float(100.0 * np.mean(success)) if n else 0.0,
        "seconds_per_attempt_mean": float(np.mean(seconds)) if n else 0.0,
        "seconds_per_attempt_median": float(np.median(seconds)) if n else 0.0,
    }
    for i, name in enumerate(subtasks):
        out[f"failures_{name}"] = int(np.sum(failed_subtask == i))
    return out
