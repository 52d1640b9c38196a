"""What every benchmark shares: where its figures go (``figures_path``) and what it ran on,
written beside them (these machines differ, so a figure is read against the machine that
gave it)."""

from __future__ import annotations

import os
import platform
from pathlib import Path

FIGURES = Path(__file__).resolve().parent.parent / "metrics" / "benchmarks"


def figures_path(script: str) -> Path:
    """metrics/benchmarks/<name>.json, the committed figures of benchmarks/<name>.py
    (``script``: that file's ``__file__``)."""
    return FIGURES / Path(script).with_suffix(".json").name


def machine() -> dict:
    """device, the CPU's model name, its logical CPUs, and the 1-minute load average when
    the figures were taken."""
    cpuinfo = Path("/proc/cpuinfo")
    names = [
        line.split(":", 1)[1].strip()
        for line in (cpuinfo.read_text().splitlines() if cpuinfo.exists() else [])
        if line.startswith("model name")
    ]
    return {
        "device": "cpu",
        "cpu": names[0] if names else platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
