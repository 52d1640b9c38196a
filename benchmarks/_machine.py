"""What a benchmark ran on, written beside its figures: these machines differ, so a figure
is read against the machine that gave it."""

from __future__ import annotations

import os
import platform
from pathlib import Path


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
