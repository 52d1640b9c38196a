"""What every benchmark shares: where its figures go (``figures_path``) and what it ran on,
written beside them (these machines differ, so a figure is read against the machine that
gave it)."""

from __future__ import annotations

import os
import platform
from pathlib import Path

from mimicgen_pipe.data.metrics import cpu_type

FIGURES = Path(__file__).resolve().parent.parent / "metrics" / "benchmarks"


def figures_path(script: str) -> Path:
    """metrics/benchmarks/<name>.json, the committed figures of benchmarks/<name>.py
    (``script``: that file's ``__file__``)."""
    return FIGURES / Path(script).with_suffix(".json").name


def machine() -> dict:
    """device, the CPU's model name, its logical CPUs, and the 1-minute load average when
    the figures were taken."""
    model = cpu_type()["model_name"]  # the stages' own reading of /proc/cpuinfo
    return {
        "device": "cpu",
        "cpu": model or platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
