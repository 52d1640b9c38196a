"""Numbers as table cells: one spelling of a metric, a setting, a change and a spread."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

MISSING = "missing"  # a metric that was not produced


def fmt(value: Any, digits: int = 1) -> str:
    """A metric for a table cell: ``missing`` when absent."""
    if value is None:
        return MISSING
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return str(value)
    if isinstance(value, int):
        return str(value)
    return f"{value:.{digits}f}"


def fmt_pm(mean: Any, std: Any) -> str:
    if mean is None:
        return MISSING
    return fmt(mean) if std is None else f"{fmt(mean)} ± {fmt(std)}"


def fmt_setting(key: str, value: Any) -> str:
    """``key=value`` as params.yaml would spell it (generate's keys without the section)."""
    name = key.split(".", 1)[1] if key.startswith("generate.") else key
    text = str(value).lower() if isinstance(value, bool) else str(value)
    return f"{name}={text}"


def fmt_delta(a: Any, b: Any) -> str:
    """b - a in points, signed; ``missing`` when either is absent."""
    if a is None or b is None:
        return MISSING
    return f"{b - a:+.1f}"


def dgr_stderr(values: Mapping[str, Any] | None) -> float | None:
    """Binomial standard error [points] of a generate run's DGR (its metrics values)."""
    if not values or not values.get("attempts"):
        return None
    p = values["dgr"] / 100.0
    return 100.0 * math.sqrt(p * (1 - p) / values["attempts"])
