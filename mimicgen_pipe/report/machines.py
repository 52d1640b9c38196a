"""Where the results were made: the CPU each stage ran on, as its timings file records it
(mimicgen_pipe.data.metrics.write_timings), so that a reader sees which rows came from
which machine type when a pipeline's stages ran on several."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.jsonfile import read_json
from mimicgen_pipe.data.metrics import timings_file
from mimicgen_pipe.report.blocks import Block, Heading, Table, Text

# metrics sub-folders that hold no pipeline result (benchmark scripts' figures)
NOT_RESULTS = ("benchmarks",)
NOT_RECORDED = "not recorded (a run from before the stages recorded their CPU)"


def describe_cpu(cpu: Mapping[str, Any]) -> str:
    """A CPU type as a timings file records it (data.metrics.cpu_type), in one line."""
    flags = ", ".join(cpu.get("flags") or []) or "none of the kernel flags"
    return (
        f"{cpu.get('model_name')} ({cpu.get('vendor')} family {cpu.get('family')} "
        f"model {cpu.get('model')}; {flags})"
    )


def read_machines(metrics_dir: Path) -> dict[str, str]:
    """Each metrics file under ``metrics_dir`` whose stage writes a timings file (the path
    below ``metrics_dir`` without ``.json``) -> the CPU it records, described, or
    :data:`NOT_RECORDED`; files without a timings file (stages that time nothing) are left
    out."""
    found = {}
    for path in sorted(metrics_dir.rglob("*.json")):
        rel = path.relative_to(metrics_dir)
        if rel.parts[0] in NOT_RESULTS:
            continue
        timings = timings_file(path)
        if not timings.is_file():
            continue
        try:
            cpu = read_json(timings, "timings file").get("cpu")
        except (InputError, AttributeError):
            cpu = None  # informational: a damaged timings file names no machine
        name = rel.with_suffix("").as_posix()
        found[name] = describe_cpu(cpu) if isinstance(cpu, dict) else NOT_RECORDED
    return found


def machine_blocks(machines: Mapping[str, str]) -> list[Block]:
    """One line when every result was made on one CPU type; else a table of the types, the
    most frequent first with its count, the others with the results they made."""
    if not machines:
        return []
    by_cpu: dict[str, list[str]] = {}
    for name, cpu in machines.items():
        by_cpu.setdefault(cpu, []).append(name)
    heading = Heading(2, "Where the results were made")
    note = (
        "The CPU each stage ran on, from its timings file (`timings/` beside `metrics/`). "
        "The pipelines give the same bytes on every AMD CPU measured; an Intel CPU moves "
        "the last bits of the simulation (`docs/workflow.md`)."
    )
    if len(by_cpu) == 1:
        (cpu,) = by_cpu
        return [heading, Text(f"Every result here ({len(machines)} files) was made on {cpu}.")]
    ranked = sorted(by_cpu.items(), key=lambda kv: (-len(kv[1]), kv[0]))
    rows = [(ranked[0][0], f"the other {len(ranked[0][1])} files")]
    rows += [(cpu, ", ".join(_folded(names, machines))) for cpu, names in ranked[1:]]
    return [heading, Text(note), Table(("CPU", "results (metrics files)"), tuple(rows))]


def _folded(names: list[str], machines: Mapping[str, str]) -> list[str]:
    """``names`` as the report lists them: a sub-folder whose files all ran on one CPU type
    as one entry with its count (``ablations/`` (11 files)), other files by name."""
    out, done = [], set()
    for name in names:
        folder = name.split("/", 1)[0] if "/" in name else None
        if folder is None:
            out.append(f"`{name}`")
            continue
        inside = [n for n in machines if n.startswith(folder + "/")]
        if all(n in names for n in inside):
            if folder not in done:
                out.append(f"`{folder}/` ({len(inside)} files)")
                done.add(folder)
        else:
            out.append(f"`{name}`")
    return out
