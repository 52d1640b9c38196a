"""Flat JSON metrics files, written atomically."""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from mimicgen_pipe.outputs import temporary_name


def write_metrics(path: str | os.PathLike, metrics: Mapping[str, Any]) -> Path:
    """Write flat metrics as JSON through a temporary file of a name no other writer uses
    (pid and random suffix), so that concurrent writers never clobber each other's
    half-written file and the reader sees a whole file, old or new."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_name(path)
    # NaN/inf are not JSON; a value that could not be measured is written as null
    clean = {
        k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in metrics.items()
    }
    try:
        tmp.write_text(json.dumps(clean, indent=2, sort_keys=True) + "\n")
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def generation_metrics(
    success: np.ndarray,
    failed_subtask: np.ndarray,
    seconds: np.ndarray,
    subtasks: list[str],
    ik_failed: np.ndarray | None = None,
) -> dict[str, Any]:
    """attempts, successes, dgr (data generation rate, %), seconds per attempt (mean, median),
    task failures per subtask (the first subtask an attempt did not achieve) and, apart from
    them, IK failures (attempts stopped because the arm cannot reach a subtask's targets),
    in total and per subtask."""
    ik = np.zeros(len(success), bool) if ik_failed is None else np.asarray(ik_failed, bool)
    n = len(success)
    out: dict[str, Any] = {
        "attempts": int(n),
        "successes": int(np.sum(success)),
        "dgr": float(100.0 * np.mean(success)) if n else 0.0,
        "seconds_per_attempt_mean": float(np.mean(seconds)) if n else 0.0,
        "seconds_per_attempt_median": float(np.median(seconds)) if n else 0.0,
    }
    out["ik_failures"] = int(ik.sum())
    for i, name in enumerate(subtasks):
        out[f"failures_{name}"] = int(np.sum((failed_subtask == i) & ~ik))
        out[f"ik_failures_{name}"] = int(np.sum((failed_subtask == i) & ik))
    return out


def evaluation_metrics(per_run: Mapping[int, list[tuple[int, float]]]) -> dict[str, Any]:
    """Success rates [%] of the paper's protocol and the honest one, from
    training seed -> [(epoch, success rate of that checkpoint)] in epoch order:
    success_rate_max (max over a run's checkpoints) and success_rate_last (its last
    checkpoint), each as mean and std (population) over training seeds, plus per seed."""
    best = np.array([max(rate for _, rate in rows) for rows in per_run.values()])
    last = np.array([rows[-1][1] for rows in per_run.values()])
    out: dict[str, Any] = {
        "seeds": len(per_run),
        "checkpoints": int(np.mean([len(rows) for rows in per_run.values()])),
        "success_rate_max": float(best.mean()),
        "success_rate_max_std": float(best.std()),
        "success_rate_last": float(last.mean()),
        "success_rate_last_std": float(last.std()),
    }
    for (seed, rows), b, la in zip(per_run.items(), best, last, strict=True):
        out[f"seed{seed}_success_rate_max"] = float(b)
        out[f"seed{seed}_success_rate_last"] = float(la)
        out[f"seed{seed}_best_epoch"] = int(max(rows, key=lambda r: r[1])[0])
    return out
