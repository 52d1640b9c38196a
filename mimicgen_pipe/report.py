"""The report: our metrics beside the paper's numbers, as Markdown and HTML.

Built only from what is present: every number in it comes from a metrics file of this run,
of a saved ablation run, or from the paper's numbers file (each with the table it was read
from). A metric that was not produced is written ``missing``; no row is made up.

The report is a list of blocks (headings, text, tables, images) rendered twice, so the
Markdown and the HTML say the same thing.
"""

from __future__ import annotations

import base64
import html
import math
import re
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mimicgen_pipe.errors import InputError
from mimicgen_pipe.outputs import check_same_run
from mimicgen_pipe.params import Params, read_yaml
from mimicgen_pipe.pose_noise import NAMED_LEVELS
from mimicgen_pipe.taskspec import TaskSpec

MISSING = "missing"

# The generation settings an ablation may change (params keys); the paper's entries name
# theirs with the same keys.
METHOD_KEYS = (
    "generate.action_noise",
    "generate.selection",
    "generate.nn_k",
    "generate.per_subtask",
    "generate.n_interp",
    "generate.n_fixed",
    "pose_noise.level",
    "pose_noise.seed",
    "generate.seed",
)
METRIC_LABELS = {"dgr": "DGR", "sr_low_dim": "SR low-dim", "sr_image": "SR image"}


# --- blocks -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Heading:
    level: int
    text: str


@dataclass(frozen=True)
class Text:
    """A paragraph; `code` spans are kept in both renderings."""

    text: str


@dataclass(frozen=True)
class Table:
    columns: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]


@dataclass(frozen=True)
class Image:
    """An image file, referred to by its name in the report's folder."""

    name: str
    alt: str


Block = Heading | Text | Table | Image


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def render_markdown(blocks: Sequence[Block]) -> str:
    out: list[str] = []
    for b in blocks:
        if isinstance(b, Heading):
            out.append(f"{'#' * b.level} {b.text}")
        elif isinstance(b, Text):
            out.append(b.text)
        elif isinstance(b, Table):
            out.append("| " + " | ".join(_md_cell(c) for c in b.columns) + " |")
            out.append("|" + "---|" * len(b.columns))
            out.extend("| " + " | ".join(_md_cell(c) for c in row) + " |" for row in b.rows)
        elif isinstance(b, Image):
            out.append(f"![{b.alt}]({b.name})")
        out.append("")
    return "\n".join(out)


def _inline_html(text: str) -> str:
    parts = html.escape(text).split("`")
    return "".join(f"<code>{p}</code>" if i % 2 else p for i, p in enumerate(parts))


def render_html(blocks: Sequence[Block], images: Mapping[str, bytes], title: str) -> str:
    """One self-contained HTML page; ``images`` maps Image names to PNG bytes (embedded)."""
    body: list[str] = []
    for b in blocks:
        if isinstance(b, Heading):
            body.append(f"<h{b.level}>{_inline_html(b.text)}</h{b.level}>")
        elif isinstance(b, Text):
            body.append(f"<p>{_inline_html(b.text)}</p>")
        elif isinstance(b, Table):
            head = "".join(f"<th>{_inline_html(c)}</th>" for c in b.columns)
            rows = "".join(
                "<tr>" + "".join(f"<td>{_inline_html(c)}</td>" for c in row) + "</tr>"
                for row in b.rows
            )
            body.append(f"<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>")
        elif isinstance(b, Image):
            if b.name in images:
                data = base64.b64encode(images[b.name]).decode("ascii")
                src = f"data:image/png;base64,{data}"
            else:
                src = html.escape(b.name)
            body.append(f'<p><img src="{src}" alt="{html.escape(b.alt)}"></p>')
    style = (
        "body{font-family:sans-serif;max-width:70em;margin:2em auto;padding:0 1em}"
        "table{border-collapse:collapse;margin:1em 0}"
        "th,td{border:1px solid #bbb;padding:.25em .6em;text-align:left}"
        "th{background:#eee}img{max-width:100%}code{background:#f4f4f4}"
    )
    return (
        "<!DOCTYPE html>\n<html><head><meta charset='utf-8'>"
        f"<title>{html.escape(title)}</title><style>{style}</style></head>\n<body>\n"
        + "\n".join(body)
        + "\n</body></html>\n"
    )


# --- inputs -----------------------------------------------------------------------------


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


@dataclass(frozen=True)
class Run:
    """A finished run: its params and its metrics files (file stem -> flat metrics)."""

    name: str
    params: Params
    metrics: Mapping[str, Mapping[str, Any]]


def check_run_ids(metrics: Mapping[str, Mapping[str, Any]], folder: str | Path) -> None:
    """InputError when metrics that the report puts side by side describe different generate
    runs: generate_<x> (run_id) against coverage_<x> (run_id of the stores it measured),
    train_<x> and evaluate_<x>_on_<v> (data_run_id of the store the policy learnt from).
    Metrics written before run ids existed carry none and are not compared. Where a
    generate_<x>_train exists (the suite's policy data, apart from its DGR store), train_<x>
    and evaluate_<x>_on_<v> are compared with it instead."""
    for stem, m in metrics.items():
        if not stem.startswith("generate_") or m.get("run_id") is None:
            continue
        name = stem.removeprefix("generate_")
        policy = name.removesuffix("_train")  # the name its policy's metrics carry
        ids = {f"{Path(folder) / stem}.json run_id": m["run_id"]}
        trained_here = name.endswith("_train") or f"generate_{name}_train" not in metrics
        for other, om in metrics.items():
            key = {f"coverage_{name}": "run_id"}.get(other)
            if trained_here and (
                other == f"train_{policy}" or other.startswith(f"evaluate_{policy}_on_")
            ):
                key = "data_run_id"
            if key is not None and om.get(key) is not None:
                ids[f"{Path(folder) / other}.json {key}"] = om[key]
        check_same_run(ids)


def method_settings(params: Params) -> dict[str, Any]:
    """The generation settings of a run (METHOD_KEYS -> value); a pose-noise pair that equals
    a named level is written as the name."""
    out: dict[str, Any] = {}
    for key in METHOD_KEYS:
        section, name = key.split(".")
        out[key] = getattr(getattr(params, section), name)
    level = out["pose_noise.level"]
    if not isinstance(level, str):
        named = [n for n, v in NAMED_LEVELS.items() if tuple(map(float, level)) == v]
        out["pose_noise.level"] = named[0] if named else list(level)
    return out


def _equal(a: Any, b: Any) -> bool:
    if isinstance(a, bool) or isinstance(b, bool):
        return a is b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(a, b, abs_tol=1e-12)
    return a == b


def matches(settings: Mapping[str, Any], entry: PaperEntry) -> bool:
    """Whether a run with ``settings`` is the paper's run of ``entry`` on its named keys."""
    return all(_equal(settings.get(k), v) for k, v in entry.settings.items())


def changed_settings(base: Mapping[str, Any], run: Mapping[str, Any]) -> dict[str, Any]:
    return {k: run[k] for k in METHOD_KEYS if not _equal(base.get(k), run.get(k))}


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
        like_base = [e for e in entries if matches(base, e)]
        like_run = [e for e in entries if matches(run, e)]
        if len(like_base) == 1 and len(like_run) == 1 and like_base[0] is not like_run[0]:
            pairs.append((like_base[0], like_run[0]))
    return pairs


# --- formatting -------------------------------------------------------------------------


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


def _delta(a: Any, b: Any) -> str:
    if a is None or b is None:
        return MISSING
    return f"{b - a:+.1f}"


def _dgr_stderr(m: Mapping[str, Any] | None) -> float | None:
    """Binomial standard error [points] of a run's DGR."""
    if not m or not m.get("attempts"):
        return None
    p = m["dgr"] / 100.0
    return 100.0 * math.sqrt(p * (1 - p) / m["attempts"])


# --- the report -------------------------------------------------------------------------


def build_report(
    task: str,
    paper_task: str,
    variants: Sequence[str],
    run: Run,
    ablations: Sequence[Run],
    paper: PaperResults,
    heatmaps: Mapping[str, str],
) -> list[Block]:
    """The report's blocks. ``run``: this workspace's run; ``ablations``: saved ablation runs;
    ``heatmaps``: variant -> image name of its coverage heat maps (only those present);
    ``paper_task``: the paper's task ours stands for (its task file's spec.paper_task)."""
    settings = method_settings(run.params)
    m = run.metrics
    blocks: list[Block] = [
        Heading(1, f"MimicGen on {task}: our numbers and the paper's"),
        Text(
            f"Our task `{task}` is set beside the paper's {paper_task} task. Paper numbers "
            "come from `reference/paper_results.yaml`, each with the table it was read from; "
            f"ours from the metrics files of this run. `{MISSING}` marks a metric this run "
            "did not produce. Generation settings: "
            + ", ".join(f"`{fmt_setting(k, v)}`" for k, v in settings.items())
            + "."
        ),
    ]

    # Data generation rates
    blocks.append(Heading(2, "Data generation rate (DGR, %)"))
    rows = []
    for v in variants:
        g = m.get(f"generate_{task}_{v}")
        headline = paper.find(table="O.1", task=paper_task, variant=v, metric="dgr")
        same = [
            e
            for e in paper.find(task=paper_task, variant=v, metric="dgr")
            if e.settings and matches(settings, e)
        ]
        rows.append(
            (
                v,
                fmt(g.get("attempts")) if g else MISSING,
                fmt(g.get("successes")) if g else MISSING,
                fmt(g.get("dgr")) if g else MISSING,
                "; ".join(e.cite() for e in headline) or "not in paper",
                "; ".join(f"{e.cite()} [{e.condition}]" for e in same) or "not in paper",
            )
        )
    blocks.append(
        Table(
            (
                "variant",
                "attempts",
                "successes",
                "DGR ours",
                "paper (its settings)",
                "paper with our settings",
            ),
            tuple(rows),
        )
    )
    o1 = [e for e in paper.find(table="O.1", task=paper_task) if e.settings]
    if o1 and not matches(settings, o1[0]):
        blocks.append(
            Text(
                f"The paper generated {paper_task} with "
                + ", ".join(f"`{fmt_setting(k, v)}`" for k, v in o1[0].settings.items())
                + "; the last column is the paper's run with the settings used here, where "
                "one of its tables has it."
            )
        )

    # Policy success rates
    blocks.append(Heading(2, "Policy success rate (%, max over training, mean ± std over seeds)"))
    expected = [
        (e.data, e.variant) for e in paper.find(table="P.1", task=paper_task) if e.data is not None
    ]
    present = []
    for stem in m:
        hit = re.fullmatch(rf"evaluate_{re.escape(task)}_(.+)_on_(.+)", stem)
        if hit:
            present.append((hit.group(1), hit.group(2)))
    rows = []
    for data, v in list(dict.fromkeys(expected + sorted(present))):
        ev = m.get(f"evaluate_{task}_{data}_on_{v}")
        ref = paper.find(table="P.1", task=paper_task, data=data, variant=v)
        rows.append(
            (
                "source demos" if data == "source" else f"generated {data}",
                v,
                fmt_pm(ev.get("success_rate_max"), ev.get("success_rate_max_std"))
                if ev
                else MISSING,
                fmt_pm(ev.get("success_rate_last"), ev.get("success_rate_last_std"))
                if ev
                else MISSING,
                f"{fmt(ev.get('episodes'))} × {fmt(ev.get('seeds'))}" if ev else MISSING,
                "; ".join(e.cite() for e in ref) or "not in paper",
            )
        )
    blocks.append(
        Table(
            (
                "trained on",
                "evaluated on",
                "SR max ours",
                "SR last ours",
                "episodes × seeds",
                "paper (low-dim)",
            ),
            tuple(rows),
        )
    )

    # Coverage
    blocks.append(Heading(2, "Support coverage of initial scenes (%, paper Q)"))
    blocks.append(
        Text(
            "Each object's initial (x, y, yaw) binned over the variant's reset bounds; coverage "
            "is the share of non-empty bins, per object and jointly over all objects, for the "
            "generated (kept) scenes and for all attempted ones. `uniform` is what the same "
            "number of scenes spread uniformly over the joint bins would cover on average; a "
            "generated coverage well below it (and below the attempted one) means the kept "
            "scenes are biased."
        )
    )
    rows = []
    for v in variants:
        c = m.get(f"coverage_{task}_{v}")
        objects = sorted(
            k[len("support_coverage_") :]
            for k in (c or {})
            if k.startswith("support_coverage_") and k != "support_coverage_joint"
        )
        per_object = (
            ", ".join(
                f"{o} {fmt(c.get(f'support_coverage_{o}'))} "
                f"({fmt(c.get(f'attempted_support_coverage_{o}'))})"
                for o in objects
            )
            if c
            else MISSING
        )
        rows.append(
            (
                v,
                fmt(c.get("bins")) if c else MISSING,
                f"{fmt(c.get('episodes'))} / {fmt(c.get('attempts'))}" if c else MISSING,
                fmt(c.get("support_coverage_joint")) if c else MISSING,
                fmt(c.get("attempted_support_coverage_joint")) if c else MISSING,
                fmt(c.get("uniform_support_coverage_joint")) if c else MISSING,
                per_object,
            )
        )
    blocks.append(
        Table(
            (
                "variant",
                "bins per dim",
                "generated / attempted",
                "joint",
                "joint attempted",
                "joint uniform",
                "per object (attempted)",
            ),
            tuple(rows),
        )
    )
    blocks.append(
        Text(
            "The paper reports coverage for other tasks only (e.g. Coffee D1 98.8%, "
            f"Threading D1 71%, Appendix Q); it has no number for {paper_task}."
        )
    )
    for v in variants:
        if v in heatmaps:
            blocks.append(Image(heatmaps[v], f"initial object positions, {task} {v}"))
        else:
            blocks.append(Text(f"Heat maps for {v}: {MISSING}."))

    blocks.extend(_ablation_blocks(task, paper_task, settings, ablations, paper))
    return blocks


def suite_ablation_blocks(spec: TaskSpec, runs: Sequence[Run], paper: PaperResults) -> list[Block]:
    """A suite task's saved ablation runs (benchmarks/ablations.py --task), each against the
    one of them named ``default``, whose settings are the base (they may differ from
    params.yaml's, e.g. a lower action noise)."""
    base = next((r for r in runs if r.name == "default"), None)
    heading = f"Ablations on {spec.name} ({spec.paper_task})"
    if base is None:
        names = ", ".join(r.name for r in runs) or "none"
        return [
            Heading(2, heading),
            Text(f"No saved run named `default` to compare with: {MISSING} (runs: {names})."),
        ]
    return _ablation_blocks(
        spec.name, spec.paper_task, method_settings(base.params), runs, paper, heading, "its own"
    )


def _ablation_blocks(
    task: str,
    paper_task: str,
    settings: Mapping[str, Any],
    ablations: Sequence[Run],
    paper: PaperResults,
    heading: str = "Ablations",
    base_settings_are: str = "this run's",
) -> list[Block]:
    blocks: list[Block] = [Heading(2, heading)]
    if not ablations:
        return blocks + [Text(f"No saved ablation runs ({MISSING}).")]
    runs = [(r, method_settings(r.params)) for r in ablations]
    base = [(r, s) for r, s in runs if not changed_settings(settings, s)]
    if not base:
        return blocks + [
            Text(
                "No saved ablation run has this run's generation settings, so no deltas: "
                f"{MISSING}. Runs saved: " + ", ".join(r.name for r in ablations) + "."
            )
        ]
    base_run, base_settings = base[0]
    blocks.append(
        Text(
            f"Each run against `{base_run.name}` ({base_settings_are} settings, same attempts). "
            "Δ is in points of DGR; ± is the binomial standard error of one run's DGR, so a Δ "
            "within about twice it is noise. The paper column gives the same change in the paper's "
            "table for the same reset variant (its base → changed value), on the task the "
            "table holds. Coverage is the joint support coverage (paper Q) of the kept scenes, "
            "beside what as many uniformly spread scenes would cover: with a fixed number of "
            "attempts a lower DGR keeps fewer scenes, which alone covers fewer bins."
        )
    )
    rows = []
    for r, s in sorted(runs, key=lambda rs: rs[0] is not base_run):  # the base first
        for stem, gm in sorted(r.metrics.items()):
            hit = re.fullmatch(rf"generate_{re.escape(task)}_(.+)", stem)
            if not hit:
                continue
            v = hit.group(1)
            bm = base_run.metrics.get(stem)
            cm = r.metrics.get(f"coverage_{task}_{v}") or {}
            bcm = base_run.metrics.get(f"coverage_{task}_{v}") or {}
            pairs = paper_deltas(paper, v, base_settings, s)
            pairs.sort(key=lambda p: (p[0].task != paper_task, p[0].table, p[0].task))
            paper_cell = "; ".join(
                f"{a.task} {METRIC_LABELS[a.metric]} {a.value:.1f} → {b.value:.1f} "
                f"({b.value - a.value:+.1f}, Table {a.table})"
                for a, b in pairs
            )
            changed = changed_settings(base_settings, s)
            if set(changed) == {"generate.seed"}:
                paper_cell = "spread over seeds: Table S.1, below"
            se = _dgr_stderr(gm)
            rows.append(
                (
                    r.name,
                    ", ".join(fmt_setting(k, x) for k, x in changed.items()) or "(base)",
                    v,
                    fmt(gm.get("attempts")),
                    f"{fmt(gm.get('dgr'))} ± {fmt(se)}" if se is not None else fmt(gm.get("dgr")),
                    "" if not changed else _delta(bm and bm.get("dgr"), gm.get("dgr")),
                    f"{fmt(cm.get('support_coverage_joint'))} "
                    f"({fmt(cm.get('uniform_support_coverage_joint'))})",
                    ""
                    if not changed
                    else _delta(
                        bcm.get("support_coverage_joint"), cm.get("support_coverage_joint")
                    ),
                    paper_cell or ("" if not changed else "not in paper"),
                )
            )
    blocks.append(
        Table(
            (
                "run",
                "changed",
                "variant",
                "attempts",
                "DGR ours",
                "Δ DGR",
                "joint coverage (uniform)",
                "Δ coverage",
                "paper",
            ),
            tuple(rows),
        )
    )
    blocks.extend(_seed_spread(task, base_run, base_settings, runs, paper))
    return blocks


def _seed_spread(
    task: str,
    base_run: Run,
    base_settings: Mapping[str, Any],
    runs: Sequence[tuple[Run, Mapping[str, Any]]],
    paper: PaperResults,
) -> list[Block]:
    """DGR spread over runs that differ from the base in the generation seed only (S.1)."""
    seeds = [
        (r, s) for r, s in runs if set(changed_settings(base_settings, s)) <= {"generate.seed"}
    ]
    if len(seeds) < 2:
        return []
    rows = []
    variants = sorted(
        {
            stem.rsplit("_", 1)[1]
            for r, _ in seeds
            for stem in r.metrics
            if stem.startswith(f"generate_{task}_")
        }
    )
    for v in variants:
        dgr = [
            r.metrics[f"generate_{task}_{v}"]["dgr"]
            for r, _ in seeds
            if f"generate_{task}_{v}" in r.metrics
        ]
        ref = paper.find(table="S.1", variant=v)
        rows.append(
            (
                v,
                ", ".join(str(s["generate.seed"]) for _, s in seeds),
                ", ".join(fmt(d) for d in dgr),
                fmt_pm(statistics.mean(dgr), statistics.stdev(dgr)) if len(dgr) >= 2 else MISSING,
                f"{max(dgr) - min(dgr):.1f}" if dgr else MISSING,
                "; ".join(e.cite() for e in ref) or "not in paper",
            )
        )
    return [
        Heading(3, "Generation seed (Table S.1)"),
        Table(
            ("variant", "seeds", "DGR per seed", "mean ± std", "max − min", "paper (3 seeds)"),
            tuple(rows),
        ),
    ]


# Paper Table E.1 (Square, DGR %): the source arm and the arms it transferred to
PAPER_TRANSFER = {
    "D0": {"Panda": 73.7, "IIWA": 37.7, "UR5e": 64.7},
    "D1": {"Panda": 48.9, "IIWA": 26.5, "UR5e": 34.1},
}


def transfer_table(
    tasks: Sequence[str],
    variants: Sequence[str],
    robots: Sequence[str],
    metrics: Mapping[str, Mapping[str, Any]],
) -> Table:
    """DGR per task variant x arm from the metrics files generate_<task>_<variant>_<robot>
    (or generate_<task>_<variant>, the main run, for the source arm), with the attempts
    stopped at IK beside each."""
    rows = []
    for task in tasks:
        for v in variants:
            cells = [f"{task} ({v})"]
            for r in robots:
                m = metrics.get(f"generate_{task}_{v}_{r}")
                if m is None and r == "panda":
                    m = metrics.get(f"generate_{task}_{v}")
                cells.append(
                    MISSING
                    if m is None
                    else f"{fmt(m['dgr'])} ({m.get('ik_failures', 0)}/{m['attempts']} IK)"
                )
            rows.append(tuple(cells))
    return Table(("task (variant)", *robots), tuple(rows))


def transfer_blocks(tables: Sequence[Table]) -> list[Block]:
    """Robot transfer (paper E.1): the tables of :func:`transfer_table` under one heading."""
    paper = "; ".join(
        f"{v}: " + ", ".join(f"{arm} {val}" for arm, val in arms.items())
        for v, arms in PAPER_TRANSFER.items()
    )
    return [
        Heading(2, "Robot transfer: data generation rate per arm"),
        Text(
            "Source demos recorded with the Panda; each cell generated with the arm of its "
            "column from those demos: DGR % (attempts stopped because a target was outside "
            f"the arm's workspace / attempts). Paper Table E.1, Square: {paper}. First table: "
            "PyBullet. Second: ManiSkill, whose controller solves its own IK (no IK check "
            "ahead, so 0 IK failures by construction); its Panda cells are the main run "
            "(generated until 1000 successes)."
        ),
        *tables,
    ]


def suite_blocks(
    specs: Sequence[TaskSpec],
    variants: Sequence[str],
    metrics: Mapping[str, Mapping[str, Any]],
    paper: PaperResults,
    action_noise: float,
) -> list[Block]:
    """The task suite: per task x variant the DGR of the fixed attempts in metrics
    generate_<task>_<variant>, the action-noise sigma they ran with (the suite's
    ``action_noise``, or less where the task caps it), the task failures per subtask (the
    first subtask an attempt did not achieve), time and steps per attempt, beside the
    paper's Table O.1 DGR of the task it stands for."""
    rows = []
    for spec in specs:
        for v in variants:
            if v not in spec.variants:
                continue
            m = metrics.get(f"generate_{spec.name}_{v}")
            ref = paper.find(table="O.1", task=spec.paper_task, variant=v, metric="dgr")
            if m is None:
                ours, failures, per_attempt = MISSING, MISSING, MISSING
            else:
                ours = f"{fmt(m['dgr'])} ({m['successes']}/{m['attempts']})"
                failures = ", ".join(
                    f"{s.name} {m.get(f'failures_{s.name}', 0)}" for s in spec.subtasks
                )
                per_attempt = (
                    f"{fmt(m['seconds_per_attempt_mean'], 2)} s, "
                    f"{fmt(m['steps'] / max(1, m['attempts']), 0)} steps"
                )
            rows.append(
                (
                    f"{spec.name} ({v})",
                    spec.paper_task,
                    ours,
                    f"{spec.action_noise(action_noise):g}",
                    failures,
                    per_attempt,
                    ref[0].cite() if ref else "– (none in the paper)",
                )
            )
    columns = ("task (variant)", "paper task", "DGR % (kept/attempts)", "σ",
               "task failures per subtask", "per attempt", "paper DGR")  # fmt: skip
    return [
        Heading(2, "Task suite: data generation rate per task"),
        Text(
            "Each task generated from its own 10 source demos (ManiSkill's motion planner), "
            "a fixed number of attempts per reset variant (`suite/dvc.yaml`), with action "
            "noise σ (paper M.4; a task file may cap it where its tolerances cannot take the "
            "suite's). Paper numbers are Table O.1's for the task ours stands for; the "
            "paper's settings per task (M.6) differ from ours (random selection, one source "
            "demo per episode, σ 0.05 in robosuite's units)."
        ),
        Table(columns, tuple(rows)),
    ]


def suite_policy_blocks(
    specs: Sequence[TaskSpec], metrics: Mapping[str, Mapping[str, Any]], paper: PaperResults
) -> list[Block]:
    """The task suite's policies: per task x variant the success rate of the BC-RNN trained
    on the 10 source demos (metrics evaluate_<task>_source_on_<variant>) and of the one
    trained on that variant's generated demos (evaluate_<task>_<variant>_on_<variant>), max
    and last over training, beside the paper's Table P.1 for the task ours stands for. Rows:
    D0 always, other variants where a metric is present."""
    rows = []
    protocols = set()  # (episodes, every_epochs, checkpoints) of the evaluations shown
    for spec in specs:
        for v in spec.variants:
            src, gen = (metrics.get(f"evaluate_{spec.name}_{d}_on_{v}") for d in ("source", v))
            if v != "D0" and src is None and gen is None:
                continue
            protocols |= {
                (m.get("episodes"), m.get("every_epochs"), m.get("checkpoints"))
                for m in (src, gen)
                if m is not None
            }

            def sr(m: Mapping[str, Any] | None) -> str:
                if m is None:
                    return MISSING
                return f"{fmt(m.get('success_rate_max'))} / {fmt(m.get('success_rate_last'))}"

            gain = (
                _delta(src.get("success_rate_max"), gen.get("success_rate_max"))
                if src and gen
                else MISSING
            )
            ref = [
                e
                for d in ("source", v)
                for e in paper.find(table="P.1", task=spec.paper_task, data=d, variant=v)
            ]
            rows.append(
                (
                    f"{spec.name} ({v})",
                    spec.paper_task,
                    sr(src),
                    sr(gen),
                    gain,
                    "; ".join(f"{e.data}: {e.cite()}" for e in ref) or "– (none in the paper)",
                )
            )
    columns = ("task (evaluated on)", "paper task", "source-only SR max / last",
               "generated SR max / last", "gain (max)", "paper (low-dim, P.1)")  # fmt: skip
    if len(protocols) == 1:
        ((episodes, every, checkpoints),) = protocols
        protocol = (
            f"{episodes} episodes on each of {checkpoints} checkpoints per policy (every "
            f"{every}th epoch and the last)"
        )
    else:
        protocol = "episodes and checkpoints per policy as in each evaluate metric"
    return [
        Heading(2, "Task suite: policy success rate (%)"),
        Text(
            "BC-RNN (cpu profile) trained on each task's 10 source demos and on the demos "
            f"generated for a variant (`suite/dvc.yaml`), evaluated on that variant: {protocol}."
            " The paper's source agents are evaluated on D0 only."
        ),
        Table(columns, tuple(rows)),
    ]


def video_blocks(
    task: str, variants: Sequence[str], media: Mapping[str, Mapping[str, Any]], folder: str
) -> list[Block]:
    """The render stage's GIFs per variant (first kept and first failed episode), referred to
    from the report's folder as ``folder``/<task>_<variant>/<kept|failed>_0.gif, with their
    MP4s and the measured time per frame. ``media``: variant -> {"files": names present,
    "ms_per_frame": ...}; variants without videos are left out."""
    blocks: list[Block] = []
    for v in variants:
        m = media.get(v)
        if not m:
            continue
        blocks.append(Heading(3, f"{task} {v}"))
        for kind in ("kept", "failed"):
            if f"{kind}_0.gif" in m["files"]:
                blocks.append(Image(f"{folder}/{task}_{v}/{kind}_0.gif", f"{kind} episode, {v}"))
        mp4s = ", ".join(
            f"`{folder}/{task}_{v}/{f}`" for f in sorted(m["files"]) if f.endswith(".mp4")
        )
        blocks.append(
            Text(
                f"Videos: {mp4s or 'none'} (rendered at {fmt(m.get('ms_per_frame'))} ms per frame)."
            )
        )
    if blocks:
        blocks.insert(0, Heading(2, "What generated demos look like"))
        blocks.insert(
            1,
            Text(
                "The first kept and the first failed generated episode of each variant, replayed "
                "from their stored states (render stage); the caption names the subtask and the "
                "source demo its segment was taken from."
            ),
        )
    return blocks
