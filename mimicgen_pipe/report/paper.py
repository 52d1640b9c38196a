"""The paper's numbers (reference/paper_results.yaml): read, checked, and looked up."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data.params import read_yaml
from mimicgen_pipe.report.settings import METHOD_KEYS, changed_settings, matches

METRIC_LABELS = {
    "dgr": "DGR",
    "sr_low_dim": "SR low-dim",
    "sr_image": "SR image",
    "support_coverage": "support coverage",
}


@dataclass(frozen=True)
class PaperEntry:
    """One number of the paper (see reference/paper_results.yaml for the fields)."""

    table: str
    task: str
    variant: str
    metric: str
    value: float
    std: float | None = None
    data: str | None = None
    condition: str = ""
    settings: Mapping[str, Any] = field(default_factory=dict)

    def cite(self) -> str:
        spread = f" ± {self.std:.1f}" if self.std is not None else ""
        return f"{self.value:.1f}{spread} (Table {self.table}, {self.task} {self.variant})"


@dataclass(frozen=True)
class PaperResults:
    entries: tuple[PaperEntry, ...]

    def find(self, **where: Any) -> list[PaperEntry]:
        return [e for e in self.entries if all(getattr(e, k) == v for k, v in where.items())]


def load_paper_results(path: str | Path) -> PaperResults:
    """Read the paper's numbers; InputError naming the file and entry when malformed."""
    path = Path(path)
    raw = read_yaml(path, "paper results file")
    if not isinstance(raw, dict) or not isinstance(raw.get("entries"), list):
        raise InputError(f"{path}: expected a mapping with a list under 'entries'")
    entries = []
    for i, e in enumerate(raw["entries"]):
        where = f"{path}: entries[{i}]"
        if not isinstance(e, dict):
            raise InputError(f"{where}: expected a mapping, got {e!r}")
        for key in ("table", "task", "variant", "metric", "value"):
            if key not in e:
                raise InputError(f"{where}: '{key}' missing")
        if e["metric"] not in METRIC_LABELS:
            raise InputError(f"{where}: metric {e['metric']!r} not one of {list(METRIC_LABELS)}")
        unknown = sorted(set(e.get("settings") or {}) - set(METHOD_KEYS))
        if unknown:
            raise InputError(f"{where}: unknown settings key {unknown[0]!r}")
        try:
            entries.append(
                PaperEntry(
                    table=str(e["table"]),
                    task=str(e["task"]),
                    variant=str(e["variant"]),
                    metric=str(e["metric"]),
                    value=float(e["value"]),
                    std=None if e.get("std") is None else float(e["std"]),
                    data=None if e.get("data") is None else str(e["data"]),
                    condition=str(e.get("condition", "")),
                    settings=dict(e.get("settings") or {}),
                )
            )
        except (TypeError, ValueError) as exc:
            raise InputError(f"{where}: {exc}") from exc
    return PaperResults(tuple(entries))


def paper_deltas(
    paper: PaperResults, variant: str, base: Mapping[str, Any], run: Mapping[str, Any]
) -> list[tuple[PaperEntry, PaperEntry]]:
    """Pairs (paper's run like ``base``, paper's run like ``run``) of one table, task and
    metric on ``variant``, where the table varies every setting in which the runs differ."""
    changed = changed_settings(base, run)
    if not changed:
        return []
    pairs = []
    groups: dict[tuple[str, str, str, str | None], list[PaperEntry]] = {}
    for e in paper.entries:
        if e.variant == variant and e.settings and set(changed) <= set(e.settings):
            groups.setdefault((e.table, e.task, e.metric, e.data), []).append(e)
    for entries in groups.values():
        like_base = [e for e in entries if matches(base, e.settings)]
        like_run = [e for e in entries if matches(run, e.settings)]
        if len(like_base) == 1 and len(like_run) == 1 and like_base[0] is not like_run[0]:
            pairs.append((like_base[0], like_run[0]))
    return pairs
