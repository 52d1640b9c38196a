"""Flat JSON metrics files, written atomically, each saying what it measured.

Every metrics file a stage writes holds its identity as top-level fields beside the values
(:func:`metrics_identity`), so that readers such as the report select metrics by what they
are, never by their file names:

- ``stage``: the stage that wrote it (:data:`STAGES`);
- ``task``, ``backend``: the task file and the simulator back end;
- ``variant``: the reset variant (or object-transfer variant) measured, null where none
  (train: a policy is trained on data, not in a variant);
- ``robot``: the arm the stage ran (source: recorded with; generate: generated with;
  evaluate: rolled out with; train, coverage, export, render: the arm of the data read);
- ``data``: for train and evaluate what the policy was trained on, ``source`` (the source
  demos) or a reset variant (that variant's generated demos); null elsewhere;
- ``purpose``: for generate why the run was made (:data:`GENERATE_PURPOSE`): ``policy_data``
  (generated until ``generate.num_demos`` demos were kept: a dataset policies train on) or
  ``dgr`` (a fixed number of attempts: a measure of the data generation rate); null
  elsewhere.

Wall-clock times are not results: they differ on every run, even one that reproduces every
store bit for bit. A stage writes them (:func:`is_timing`) apart, with the same identity
fields, to a timings file (:func:`timings_file`: ``timings/`` mirroring ``metrics/``) after
its outputs are committed. The timings file is no output of the stage (DVC does not track
it), so that a rerun that reproduces the data leaves its metrics file and dvc.lock as they
were.
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.jsonfile import read_json
from mimicgen_pipe.data.outputs import METRICS, temporary_name

STAGES = ("source", "generate", "coverage", "train", "evaluate", "export", "render", "observe")
IDENTITY_FIELDS = ("stage", "task", "backend", "variant", "robot", "data", "purpose")
# generate.mode -> the purpose of a generate run
GENERATE_PURPOSE = {"guarantee": "policy_data", "fixed_attempts": "dgr"}


def metrics_identity(
    stage: str,
    task: str,
    backend: str,
    robot: str | None,
    *,
    variant: str | None = None,
    data: str | None = None,
    purpose: str | None = None,
) -> dict[str, Any]:
    """The identity fields of a metrics file (see the module's docstring); a stage writes
    ``write_metrics(path, metrics_identity(...) | values)``. ``data`` is given by train and
    evaluate only, ``purpose`` by generate only."""
    if stage not in STAGES:
        raise ValueError(f"stage {stage!r}: not one of {STAGES}")
    if (data is not None) != (stage in ("train", "evaluate")):
        raise ValueError(f"{stage}: data {data!r} (given by train and evaluate only)")
    if (purpose is not None) != (stage == "generate"):
        raise ValueError(f"{stage}: purpose {purpose!r} (given by generate only)")
    if purpose not in (None, *GENERATE_PURPOSE.values()):
        raise ValueError(f"{stage}: purpose {purpose!r} (generate only: policy_data | dgr)")
    return {
        "stage": stage,
        "task": task,
        "backend": backend,
        "variant": variant,
        "robot": robot,
        "data": data,
        "purpose": purpose,
    }


@dataclass(frozen=True)
class Metrics:
    """One metrics file as read back: its path, identity fields and every other value."""

    path: Path
    stage: str
    task: str
    backend: str
    variant: str | None
    robot: str | None
    data: str | None
    purpose: str | None
    values: Mapping[str, Any]


def read_metrics(path: str | os.PathLike) -> Metrics:
    """A metrics file a stage wrote; one InputError naming the file when it is not a JSON
    object or lacks identity fields (a file written before they existed: re-run its stage)."""
    path = Path(path)
    raw = read_json(path, "metrics file")
    if not isinstance(raw, dict):
        raise InputError(f"{path}: expected a flat JSON object")
    missing = [k for k in IDENTITY_FIELDS if k not in raw]
    if missing:
        raise InputError(
            f"{path}: identity fields missing: {', '.join(missing)} (every stage writes "
            f"{', '.join(IDENTITY_FIELDS)}; re-run the stage that wrote it)"
        )
    if raw["stage"] not in STAGES or not all(isinstance(raw[k], str) for k in ("task", "backend")):
        raise InputError(
            f"{path}: stage {raw['stage']!r}, task {raw['task']!r}, backend "
            f"{raw['backend']!r}: expected a stage of {', '.join(STAGES)} and names"
        )
    values = {k: v for k, v in raw.items() if k not in IDENTITY_FIELDS}
    return Metrics(path, *(raw[k] for k in IDENTITY_FIELDS), values=values)


# wall-clock fields: exact names, prefixes and suffixes (is_timing)
TIMING_NAMES = frozenset({"seconds", "wall_seconds"})
TIMING_PREFIXES = ("seconds_per_", "ms_per_")
TIMING_SUFFIXES = ("_seconds",)


def is_timing(key: str) -> bool:
    """Whether a metrics field is a wall-clock time (``seconds``, ``wall_seconds``,
    ``seconds_per_*``, ``ms_per_*``, ``*_seconds``): it goes to the timings file."""
    return key in TIMING_NAMES or key.startswith(TIMING_PREFIXES) or key.endswith(TIMING_SUFFIXES)


def split_timings(values: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """``values`` as (result fields, wall-clock fields) by :func:`is_timing`."""
    results = {k: v for k, v in values.items() if not is_timing(k)}
    return results, {k: v for k, v in values.items() if is_timing(k)}


def timings_file(metrics_path: str | os.PathLike) -> Path:
    """Where the times of the stage that writes ``metrics_path`` go: the same path with its
    last folder named ``metrics`` named ``timings`` (``suite/metrics/x.json`` ->
    ``suite/timings/x.json``); beside it as ``<stem>.timings.json`` when no folder of the
    path is named ``metrics``."""
    path = Path(metrics_path)
    folders = path.parent.parts
    if "metrics" not in folders:
        return path.with_name(f"{path.stem}.timings.json")
    i = len(folders) - 1 - folders[::-1].index("metrics")
    return Path(*folders[:i], "timings", *folders[i + 1 :], path.name)


def _write_json(path: Path, values: Mapping[str, Any]) -> Path:
    """Write flat ``values`` as JSON through a temporary file of a name no other writer uses
    (pid and random suffix), so that concurrent writers never clobber each other's
    half-written file and the reader sees a whole file, old or new."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_name(path)
    # NaN/inf are not JSON; a value that could not be measured is written as null
    clean = {
        k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in values.items()
    }
    try:
        tmp.write_text(json.dumps(clean, indent=2, sort_keys=True) + "\n")
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def write_metrics(path: str | os.PathLike, metrics: Mapping[str, Any]) -> Path:
    """Write flat metrics as JSON, atomically (:func:`_write_json`). Result fields only:
    a wall-clock field (:func:`is_timing`) is a ValueError (a stage writes those with
    :func:`write_timings`), so that a metrics file is the same on every reproducing run."""
    timings = sorted(k for k in metrics if is_timing(k))
    if timings:
        raise ValueError(f"{path}: wall-clock fields {timings} belong in its timings file")
    return _write_json(Path(path), metrics)


# the CPU flags whose presence changes which kernels numpy, torch and OpenBLAS run, and so
# the last bits of a float: the pins hold them equal on one CPU type, not across types
KERNEL_FLAGS = ("avx2", "fma", "avx512f", "avx512_vnni", "amx_tile")


def cpu_type(cpuinfo: str | None = None) -> dict[str, Any]:
    """The CPU a stage ran on, for its timings file: vendor, model name, family and model
    numbers, and which of KERNEL_FLAGS it has (``cpuinfo``: /proc/cpuinfo's text, read when
    None; fields it lacks are None)."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            cpuinfo = ""
    first: dict[str, str] = {}
    for line in cpuinfo.split("\n\n", 1)[0].splitlines():  # the first processor's block
        key, _, value = line.partition(":")
        first.setdefault(key.strip(), value.strip())
    flags = set(first.get("flags", "").split())

    def number(key: str) -> int | None:
        return int(first[key]) if first.get(key, "").isdigit() else None

    return {
        "vendor": first.get("vendor_id"),
        "model_name": first.get("model name"),
        "family": number("cpu family"),
        "model": number("model"),
        "flags": [f for f in KERNEL_FLAGS if f in flags],
    }


def write_timings(
    metrics_path: str | os.PathLike, identity: Mapping[str, Any], timings: Mapping[str, Any]
) -> Path | None:
    """Write ``identity`` (the metrics file's identity fields, and its run id where it has
    one), the wall-clock fields ``timings`` and the CPU they were taken on (``cpu``,
    :func:`cpu_type`) atomically to :func:`timings_file` of the final ``metrics_path``.
    Called after the stage's outputs are committed: the file is informational, no output of
    the stage, so what keeps it from being written (a path that holds anything but a JSON
    object, which is left alone; a full disk) is one warning line and the stage still
    succeeds; returns None then. ValueError for a field of ``timings`` that is not a time or
    one of ``identity`` that is."""
    if wrong := sorted(k for k in timings if not is_timing(k)):
        raise ValueError(f"{metrics_path}: {wrong} are not wall-clock fields")
    if wrong := sorted(k for k in identity if is_timing(k)):
        raise ValueError(f"{metrics_path}: identity fields {wrong} are wall-clock fields")
    path = timings_file(metrics_path)
    why = METRICS.why_not(path) if path.exists() else None  # a link is replaced, as outputs are
    try:
        if why is None:
            return _write_json(path, {**identity, **timings, "cpu": cpu_type()})
    except OSError as exc:
        why = f"cannot be written ({exc.strerror or exc})"
    print(f"warning: {path} {why}; the times of this run are not kept", file=sys.stderr)
    return None


def generation_metrics(
    success: np.ndarray,
    failed_subtask: np.ndarray,
    seconds: np.ndarray,
    subtasks: list[str],
    ik_failed: np.ndarray | None = None,
    planner_failed: np.ndarray | None = None,
) -> dict[str, Any]:
    """attempts, successes, dgr (data generation rate, %), seconds per attempt (mean, median),
    task failures per subtask (the first subtask an attempt did not achieve) and, apart from
    them, IK failures (attempts stopped because the arm cannot reach a subtask's targets),
    in total and per subtask; with ``planner_failed`` (planned transit), planner failures
    (attempts stopped because no transit to a subtask's segment was found) apart too."""
    ik = np.zeros(len(success), bool) if ik_failed is None else np.asarray(ik_failed, bool)
    plan = np.zeros(len(success), bool) if planner_failed is None else np.asarray(planner_failed)
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
        out[f"failures_{name}"] = int(np.sum((failed_subtask == i) & ~ik & ~plan))
        out[f"ik_failures_{name}"] = int(np.sum((failed_subtask == i) & ik))
    if planner_failed is not None:
        out["planner_failures"] = int(plan.sum())
        for i, name in enumerate(subtasks):
            out[f"planner_failures_{name}"] = int(np.sum((failed_subtask == i) & plan))
    return out


def evaluation_metrics(
    per_run: Mapping[int, list[tuple[int | None, float]]],
) -> dict[str, Any]:
    """Success rates [%] of the paper's protocol and the honest one, from
    training seed -> [(epoch, success rate of that checkpoint)] in epoch order:
    success_rate_max (max over a run's checkpoints) and success_rate_last (its last
    checkpoint), each as mean and std (population) over training seeds, plus per seed, with
    the epoch of each run's best checkpoint (the first of equals): the checkpoint's own
    epoch, as its training counted it; null where that is unknown."""
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
        epoch = max(rows, key=lambda r: r[1])[0]
        out[f"seed{seed}_best_epoch"] = None if epoch is None else int(epoch)
    return out
