"""One generation ablation run (the ablation stage, params ``ablations``): its params file
and the stages it runs on it, pose_noise, generate and coverage, in order. The stage
resolves the job, the run's params checked and its command lines built, before anything is
written (mimicgen_pipe.stages.ablation)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from mimicgen_pipe.data.outputs import temporary_name


@dataclass(frozen=True)
class AblationJob:
    """Ablation run ``run`` (``what`` it measures): ``params_text``, its whole params file,
    on which ``steps`` run in order (each resolves and runs one stage: pose_noise, generate,
    coverage), written to ``work``/params.yaml first and to ``out``/params.yaml, beside the
    run's metrics, once they are done."""

    run: str
    what: str
    params_text: str
    work: Path
    out: Path
    steps: tuple[Callable[[], None], ...]


def run_ablation(job: AblationJob) -> float:
    """Write the run's params, run its steps, and write its params beside its metrics last,
    so that a run folder with its params is a finished run (report.inputs.read_runs); the
    seconds it took."""
    t0 = time.perf_counter()
    job.work.mkdir(parents=True, exist_ok=True)
    _write(job.work / "params.yaml", job.params_text)
    for step in job.steps:
        step()
    _write(job.out / "params.yaml", job.params_text)
    return time.perf_counter() - t0


def _write(path: Path, text: str) -> None:
    """``text`` at ``path``, whole or not at all."""
    tmp = temporary_name(path)
    tmp.write_text(text)
    os.replace(tmp, path)
