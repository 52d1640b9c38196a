"""Numbers as table cells: one spelling of a metric, a setting, a change, a spread and a
rate's 95% confidence interval."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from mimicgen_pipe.core.taskspec import TaskSpec

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


# suffixes of a headline number's 95% interval bounds in a report's summary.json
CI_BOUNDS = ("_lo", "_hi")
Z95 = 1.959963984540054  # the standard normal's 97.5th percentile: a two-sided 95% interval
# what a report's intro says the brackets after a rate are
CI_NOTE = (
    "Brackets after a DGR or success rate give its 95% confidence interval (Wilson score "
    "interval of the successes counted: of the attempts for a DGR, of the episodes pooled "
    "over training seeds for a success rate)."
)


def wilson_interval(successes: int, trials: int, z: float = Z95) -> tuple[float, float] | None:
    """The Wilson score interval [%] of a binomial rate, ``successes`` of ``trials`` (95% for
    the default ``z``); None without trials. Unlike p ± z·se it stays within 0–100 and is
    not empty at 0 or ``trials`` successes, which small runs (20 attempts) often have."""
    if trials <= 0:
        return None
    p, z2 = successes / trials, z * z
    denom = 1 + z2 / trials
    centre = (p + z2 / (2 * trials)) / denom
    half = z / denom * math.sqrt(p * (1 - p) / trials + z2 / (4 * trials * trials))
    return 100.0 * max(0.0, centre - half), 100.0 * min(1.0, centre + half)


def dgr_counts(values: Mapping[str, Any] | None) -> tuple[int, int] | None:
    """(successes, attempts) of a generate run's metrics values; None when absent."""
    if not values or not isinstance(values.get("attempts"), int):
        return None
    if not isinstance(values.get("successes"), int):
        return None
    return values["successes"], values["attempts"]


def sr_counts(
    values: Mapping[str, Any] | None, kind: str = "max", seed: int | None = None
) -> tuple[int, int] | None:
    """(successes, episodes) behind an evaluation's success rate ``kind`` (max: each seed's
    best checkpoint; last: its last), pooled over training seeds, or of one ``seed``.

    Evaluate metrics hold rates, not counts: each seed's rate is its successes over
    ``episodes``, so the mean over ``seeds`` times episodes × seeds is the pooled count.
    None when a count is absent or the product is not a whole number (then no count is
    exact)."""
    if not values:
        return None
    key = f"success_rate_{kind}" if seed is None else f"seed{seed}_success_rate_{kind}"
    rate, episodes = values.get(key), values.get("episodes")
    seeds = 1 if seed is not None else values.get("seeds")
    if not all(isinstance(x, (int, float)) for x in (rate, episodes, seeds)):
        return None
    trials = episodes * seeds
    successes = rate * trials / 100.0
    if trials <= 0 or abs(successes - round(successes)) > 1e-6:
        return None
    return int(round(successes)), int(trials)


def fmt_ci(counts: tuple[int, int] | None) -> str:
    """`` [lo–hi]``, the 95% Wilson interval [%] of ``counts`` (successes, trials), to
    follow a rate in its cell; empty when there are no counts."""
    ci = wilson_interval(*counts) if counts else None
    return "" if ci is None else f" [{ci[0]:.1f}–{ci[1]:.1f}]"


def fmt_dgr(values: Mapping[str, Any] | None) -> str:
    """A generate run's DGR [%] with its 95% interval: ``90.9 [72.2–97.5]``."""
    if not values:
        return MISSING
    return fmt(values.get("dgr")) + fmt_ci(dgr_counts(values))


def fmt_sr(
    values: Mapping[str, Any] | None, kind: str = "max", std: bool = True, seed: int | None = None
) -> str:
    """An evaluation's success rate ``kind`` [%], mean ± std over seeds (``std``), or one
    ``seed``'s, with the 95% interval of its episodes (pooled over seeds):
    ``96.0 ± 0.0 [86.5–98.9]``."""
    if not values:
        return MISSING
    if seed is not None:
        rate = values.get(f"seed{seed}_success_rate_{kind}")
        shown = fmt(rate)
    else:
        rate = values.get(f"success_rate_{kind}")
        shown = fmt_pm(rate, values.get(f"success_rate_{kind}_std")) if std else fmt(rate)
    return shown + ("" if rate is None else fmt_ci(sr_counts(values, kind, seed)))


def fmt_failures(spec: TaskSpec, values: Mapping[str, Any]) -> str:
    """A generate run's task failures per subtask of ``spec`` (the first subtask an attempt
    did not achieve), each after its arm where the task has several:
    ``grasp_cubeA 0, place_on_cubeB 2``."""
    return ", ".join(
        f"{s.arm + ': ' if spec.several_arms else ''}{s.name} {values.get(f'failures_{s.name}', 0)}"
        for s in spec.subtasks
    )
