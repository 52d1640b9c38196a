"""Runs of one pipeline side by side, from ``dvc exp show --json``: one column per commit or
experiment, one row per params key that differs between them and per headline number of the
pipeline (its report's summary.json), with each number's change from the first column and,
where the summary holds them, its 95% interval's bounds (``90.9 [72.2–97.5]``). A
transposed view, so that many numbers and a few runs fit a terminal."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.report.fmt import CI_BOUNDS


@dataclass(frozen=True)
class Pipeline:
    """Where a pipeline keeps what a comparison reads (paths from the repository root)."""

    params: str
    summary: str


PIPELINES = {
    "default": Pipeline("params.yaml", "report/summary.json"),
    "quickstart": Pipeline("quickstart/params.yaml", "quickstart/report/summary.json"),
    "suite": Pipeline("suite/params.yaml", "suite/report/summary.json"),
    "transit": Pipeline("transit/params.yaml", "transit/report/summary.json"),
    "transfer": Pipeline("transfer/params.yaml", "transfer/report/summary.json"),
}


@dataclass(frozen=True)
class Column:
    """One column of the comparison: a commit, the workspace or an experiment, with its
    params (flattened to dotted keys) and headline numbers."""

    name: str
    params: Mapping[str, Any]
    numbers: Mapping[str, float]


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1}}`` -> ``{"a.b": 1}``; lists stay values."""
    out: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out |= flatten(value, f"{name}.")
        else:
            out[name] = value
    return out


def _typed(value: Any, kind: type, where: str) -> Any:
    """``value`` (empty when null or absent) when it is a ``kind``; else the one-line
    InputError naming where in dvc exp show's JSON it is."""
    if value is None:
        return kind()
    if not isinstance(value, kind):
        what = "a mapping" if kind is dict else f"a {kind.__name__}"
        raise InputError(
            f"dvc exp show --json: {where}: expected {what}, got a {type(value).__name__}"
        )
    return value


def _entries(rows: Any, where: str = "") -> Iterator[dict[str, Any]]:
    """Every commit, workspace and experiment entry of dvc exp show's JSON, in its order
    (baselines with their experiments after each)."""
    for i, row in enumerate(_typed(rows, list, where or "the top level")):
        at = f"{where}[{i}]"
        row = _typed(row, dict, at)
        if "rev" in row:
            yield row
        for j, exp in enumerate(_typed(row.get("experiments"), list, f"{at}.experiments")):
            exp = _typed(exp, dict, f"{at}.experiments[{j}]")
            yield from _entries(exp.get("revs"), f"{at}.experiments[{j}].revs")


def _file_data(data: Mapping[str, Any], kind: str, path: str, where: str) -> dict[str, Any]:
    files = _typed(data.get(kind), dict, f"{where}.{kind}")
    entry = _typed(files.get(path), dict, f"{where}.{kind}.{path}")
    return _typed(entry.get("data"), dict, f"{where}.{kind}.{path}.data")


def runs_of(exp_show: Any, pipeline: Pipeline) -> list[Column]:
    """The runs of ``dvc exp show --json`` output, as one pipeline sees them: its params file
    and its summary. Entries DVC could not read (``error``) and those without the pipeline's
    params are left out; the workspace is named "workspace" and comes last, a commit is
    named by its name or short rev, an experiment by its name."""
    if not isinstance(exp_show, list):
        raise InputError("dvc exp show --json: expected a list of commits")
    runs = []
    for e in _entries(exp_show):
        where = f"rev {_printable(str(e.get('rev')))}"
        if e.get("error"):
            continue
        data = _typed(e.get("data"), dict, f"{where}.data")
        params = flatten(_file_data(data, "params", pipeline.params, f"{where}.data"))
        if not params:
            continue
        numbers = {
            k: float(v)
            for k, v in flatten(
                _file_data(data, "metrics", pipeline.summary, f"{where}.data")
            ).items()
            if isinstance(v, (int, float)) and not isinstance(v, bool)
        }
        rev = str(e.get("rev", ""))
        name = e.get("name") or (rev if rev == "workspace" else rev[:7])
        runs.append(Column(str(name), params, numbers))
    # the commits (each followed by its experiments) first, so that changes are from a commit
    return sorted(runs, key=lambda r: r.name == "workspace")


def select(runs: Sequence[Column], names: Sequence[str]) -> list[Column]:
    """The runs named (in the order given), or all when none are; InputError for a name no
    run has, listing those there are."""
    if not names:
        return list(runs)
    by_name = {r.name: r for r in runs}
    unknown = [n for n in names if n not in by_name]
    if unknown:
        raise InputError(
            _printable(
                f"no run named {', '.join(unknown)} in dvc exp show (there are: "
                f"{', '.join(by_name) or 'none'})"
            )
        )
    return [by_name[n] for n in names]


_ABSENT = object()  # a key a run's params do not have


def _cell(value: Any) -> str:
    if value is _ABSENT:
        return "-"
    if isinstance(value, float):
        return f"{value:g}"
    return value if isinstance(value, str) else json.dumps(value)  # true, null, [D0, D1]


def _number(numbers: Mapping[str, float], key: str, first: float | None) -> str:
    """``key``'s number in a run, its 95% interval where the run has both bounds, and its
    change from ``first``."""
    value = numbers.get(key)
    if value is None:
        return "-"
    lo, hi = (numbers.get(key + s) for s in CI_BOUNDS)
    shown = f"{value:g}" if lo is None or hi is None else f"{value:g} [{lo:g}–{hi:g}]"
    if first is None or value == first:
        return shown
    return f"{shown} ({value - first:+.1f})"


def _bound_of(key: str, keys: set[str]) -> bool:
    """Whether ``key`` is an interval bound of another key in ``keys`` (shown in its row)."""
    return any(key.endswith(s) and key[: -len(s)] in keys for s in CI_BOUNDS)


def table(runs: Sequence[Column], all_params: bool = False) -> list[list[str]]:
    """Rows of the comparison, a header first: the params that differ between ``runs`` (or
    every one, ``all_params``), then every headline number any run has, each run's value
    with its interval followed by its change from the first run's."""
    header = ["", *(r.name for r in runs)]
    keys = sorted({k for r in runs for k in r.params})
    rows = [header]
    for k in keys:
        values = [r.params.get(k, _ABSENT) for r in runs]
        if all_params or any(v != values[0] for v in values):
            rows.append([k, *(_cell(v) for v in values)])
    names = {k for r in runs for k in r.numbers}
    for k in sorted(k for k in names if not _bound_of(k, names)):
        first = runs[0].numbers.get(k)
        rows.append([k, *(_number(r.numbers, k, first) for r in runs)])
    return rows


# C0 controls, DEL and C1 controls: a name from dvc's JSON (an experiment's, a params key)
# could otherwise move the cursor, recolour or retitle the terminal it is printed on
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def _printable(text: str) -> str:
    """``text`` with every control character written as its escape (``\\x1b``)."""
    return _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", text)


def render(rows: Sequence[Sequence[str]], width: int = 120) -> str:
    """``rows`` as aligned text no wider than ``width`` where the names allow: the runs'
    columns are split into blocks, each repeating the first (row name) column."""
    if not rows:
        return ""
    rows = [[_printable(cell) for cell in r] for r in rows]
    name_w = max(len(r[0]) for r in rows)
    col_w = [max(len(r[i]) for r in rows) for i in range(1, len(rows[0]))]
    blocks, current, used = [], [], name_w
    for i, w in enumerate(col_w):
        if current and used + 2 + w > width:
            blocks.append(current)
            current, used = [], name_w
        current.append(i + 1)
        used += 2 + w
    blocks.append(current)
    out = []
    for block in blocks:
        for r in rows:
            cells = [r[0].ljust(name_w)] + [r[i].rjust(col_w[i - 1]) for i in block]
            out.append("  ".join(cells).rstrip())
        out.append("")
    return "\n".join(out).rstrip() + "\n"


@dataclass(frozen=True)
class CompareJob:
    """A comparison, its runs read and chosen (the compare stage): ``runs`` side by side,
    with every params key (``all_params``) or the changed ones, fitted to ``width``
    characters."""

    runs: tuple[Column, ...]
    all_params: bool
    width: int


def comparison(job: CompareJob) -> str:
    """The job's comparison as aligned text (:func:`table`, :func:`render`)."""
    return render(table(job.runs, job.all_params), job.width)
