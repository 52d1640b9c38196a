"""Every result number in README.md and docs/ is in a committed file the text cites, so a
number in the manual cannot drift from the run it describes. The rules, applied outside
fenced code blocks and inline `code` spans:

1. The text splits into blocks: a paragraph, a list item, a table row, a heading. A table
   row also cites what its table's header row cites.
2. A result number is a decimal (``90.9``, ``0.143``), a percentage (``38 %``; each number
   of ``0–4 %`` and of ``2, 16, 34 %``), a duration (``82 s``, ``21 min``, ``2 h``,
   ``5 h 30 min``, ``1.2 ms``; each number of ``22–75 s``) or a success fraction
   (``187/200``). Not results: a version (``v3.0``, ``0.3.0``, a number
   after a name in VERSIONED), and a task's or a setting's geometry, which task files and
   params set: a length (``px`` too), angle, mass or frequency (``0.76 m``, ``1.2–1.7 cm/s``,
   ``±0.1 rad``, ``0.11 kg``, ``240 Hz``) and the bounds of an interval
   (``x ∈ [−0.1, 0.05]``).
3. A block holding a result number cites a source: a Markdown link, or a backticked path
   from the repository root, to a committed file that is data (``.json``, ``.csv``, a
   params or reference ``.yaml``), a generated report (``report.md`` in a ``report/``
   folder) or a pipeline's ``dvc.lock``.
4. Each result number of the block equals a number written in one of its sources, rounded
   as the text shows it (within half a unit of its last digit). A percentage may also equal
   100 times the file's number; a duration may be in seconds in the file and a decimal size
   (``22.6 MB``) in bytes, or either in the unit the text uses; a fraction N/M needs both N
   and M in the source.
5. A duration in a block that cites a pipeline's ``dvc.lock`` is that pipeline's whole
   time: within 10 % of the sum of ``wall_seconds`` over the timings files of the metrics
   files its lock records as outputs (``timings/`` beside ``metrics/``), and those of the
   studies in its folder (the suite's ``suite/<study>/dvc.lock``), which its report reads.
   A training's ``wall_seconds`` is divided by the trainings that ran side by side with it
   (``trainings_side_by_side`` of its metrics), so that their shared hours count once.
   It may also be the pipeline's longest chain (``chain_seconds``).
"""

from __future__ import annotations

import bisect
import dataclasses
import functools
import json
import re
from pathlib import Path

import pytest

from mimicgen_pipe.data.metrics import timings_file
from tests.test_lock_consistency import PIPELINES, LockGraph, Stage, lock_graph, locks

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]

# Numbers right after these names are versions of software or hardware, not results.
VERSIONED = ("Python", "Mesa", "Debian", "Zen", "robomimic", "LeRobot", "Zarr", "torchvision")

FENCE = re.compile(r"^(```|~~~).*?^\1[^\n]*$", re.M | re.S)
INLINE_CODE = re.compile(r"`([^`\n]*)`")
LINK = re.compile(r"(!?\[[^\]]*\])\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
ITEM = re.compile(r"^\s*(?:[-*+]|\d+\.)\s")
NUM = r"\d+(?:\.\d+)?"
SEP = r"\s*(?:,|–|-|and|or|to)\s*"
VERSION = re.compile(
    rf"\bv{NUM}|\d+\.\d+\.\d+|\b(?:{'|'.join(VERSIONED)})\s*(?:≥\s*)?{NUM}(?:\s*[–-]\s*{NUM})?"
)
# rule 2: geometry a task file or params sets, not a measured result
GEOMETRY = re.compile(
    rf"(?<![\w.]){NUM}(?:{SEP}{NUM})*\s*(?:mm|cm|m|px|rad|°|kg|Hz)(?:/s)?(?![\w])|\[[^\]\n]*\d[^\]\n]*\]"
)
UNITS = {"ms": 0.001, "s": 1.0, "min": 60.0, "h": 3600.0, "kB": 1e3, "MB": 1e6, "GB": 1e9}
SIZES = ("kB", "MB", "GB")
HOURS_MINUTES = re.compile(rf"(?<![\w.])({NUM})\s*h\s+({NUM})\s*min\b")
DURATION = re.compile(rf"(?<![\w.])({NUM}(?:{SEP}{NUM})*)\s*(ms|s|min|h|kB|MB|GB)\b")
PERCENT = re.compile(rf"(?<![\w.]){NUM}(?:{SEP}{NUM})*\s*%")
FRACTION = re.compile(r"(?<![\w./])(\d+)/(\d+)(?![\w/]|\.\d)")
DECIMAL = re.compile(r"(?<![\w.])\d+\.\d+(?![\w.])")
FILE_NUMBER = re.compile(r"\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
DATA_SUFFIXES = {".json", ".csv", ".yaml"}
WALL = 0.10  # rule 5: "about N min" for a whole pipeline


@dataclasses.dataclass(frozen=True)
class Figure:
    """One result number as the text shows it."""

    text: str  # as written
    value: float  # as written, in the text's unit
    half: float  # half a unit of its last digit
    kind: str  # "number", "percent", "duration" (a size too) or "fraction"
    scale: float = 1.0  # a duration or size: seconds or bytes per unit of ``value``
    denominator: int = 0  # a fraction's M


def _figure(text: str, number: str, kind: str, scale: float = 1.0) -> Figure:
    places = len(number.partition(".")[2])
    return Figure(text, float(number), 0.5 * 10.0**-places, kind, scale)


def figures(prose: str) -> list[Figure]:
    """The result numbers of one block of prose, code and link targets already taken out."""
    text = GEOMETRY.sub(" ", VERSION.sub(" ", prose))
    out: list[Figure] = []
    for m in HOURS_MINUTES.finditer(text):
        minutes = float(m.group(1)) * 60 + float(m.group(2))
        out.append(Figure(m.group(0), minutes, 0.5, "duration", 60.0))
    text = HOURS_MINUTES.sub(" ", text)
    for m in DURATION.finditer(text):
        unit = m.group(2)
        for n in re.findall(NUM, m.group(1)):
            if unit not in SIZES or "." in n:  # a size is a result only as a decimal (rule 2)
                out.append(_figure(f"{n} {unit}", n, "duration", UNITS[unit]))
    text = DURATION.sub(" ", text)
    for m in PERCENT.finditer(text):
        out += [_figure(f"{n} %", n, "percent") for n in re.findall(NUM, m.group(0))]
    text = PERCENT.sub(" ", text)
    for m in FRACTION.finditer(text):
        n, d = m.groups()
        out.append(Figure(m.group(0), float(n), 0.5, "fraction", denominator=int(d)))
    text = FRACTION.sub(" ", text)
    out += [_figure(m.group(0), m.group(0), "number") for m in DECIMAL.finditer(text)]
    return out


def blocks(text: str) -> list[str]:
    """``text`` outside fenced code, as paragraphs, list items, table rows and headings."""
    out: list[list[str]] = []
    open_block = False
    for line in FENCE.sub("\n", text).splitlines():
        stripped = line.strip()
        if not stripped:
            open_block = False
            continue
        single = stripped.startswith(("|", "#"))
        if single or ITEM.match(line) or not open_block:
            out.append([line])
        else:
            out[-1].append(line)
        open_block = not single
    return ["\n".join(lines) for lines in out]


def is_source(path: Path, root: Path) -> bool:
    """A committed file whose numbers may back the text (rule 3)."""
    if not path.is_file() or not path.resolve().is_relative_to(root.resolve()):
        return False
    if path.name == "dvc.lock":
        return True
    if path.name == "report.md":
        return path.parent.name == "report"
    return path.suffix in DATA_SUFFIXES and path.name != "dvc.yaml"


def sources(block: str, page: Path, root: Path) -> list[Path]:
    """The sources ``block`` cites: link targets (from the page) and backticked paths (from
    the repository root)."""
    cited = [page.parent / t.partition("#")[0] for _, t in LINK.findall(INLINE_CODE.sub("", block))]
    cited += [root / c for c in INLINE_CODE.findall(block)]
    return sorted({p.resolve() for p in cited if is_source(p, root)})


def prose(block: str) -> str:
    """``block`` without inline code and link targets (the link text stays)."""
    return LINK.sub(r"\1", INLINE_CODE.sub(" ", block))


@functools.cache
def numbers_in(path: Path) -> list[float]:
    """Every number written in ``path`` (a ``dvc.lock``: its pipeline's whole time and its
    longest chain's), sorted."""
    if path.name == "dvc.lock":
        return sorted({pipeline_seconds(path), max(chain_seconds(path).values())})
    return sorted(float(n) for n in FILE_NUMBER.findall(path.read_text()))


def _root(path: Path) -> Path:
    root = path.resolve().parent
    while not (root / ".git").exists() and root != root.parent:
        root = root.parent
    return root


def _pipeline_files(lock: Path) -> list[str]:
    """The ``dvc.yaml`` of ``lock``'s pipeline and of its studies (``suite/<study>/``), from
    the repository root."""
    root, folder = _root(lock), lock.resolve().parent
    studies = sorted(folder.glob("*/dvc.lock")) if folder != root else []
    return [
        (p.parent / "dvc.yaml").relative_to(root).as_posix() for p in (lock.resolve(), *studies)
    ]


def stage_seconds(wdir: Path, stage: dict) -> float:
    """One stage's time: ``wall_seconds`` over the timings files of the metrics files its lock
    entry records as outputs (paths from ``wdir``), a training's divided by its trainings
    side by side (rule 5)."""
    total = 0.0
    for out in stage.get("outs", []):
        out_path = wdir / out["path"]
        # a folder of metrics (an ablation run's) counts each file in it
        folder = out_path.is_dir() and "metrics" in out_path.parts
        for m in sorted(out_path.rglob("*.json")) if folder else [out_path]:
            path = timings_file(m)
            if path.suffix == ".json" and path.is_file():
                timings = json.loads(path.read_text())
                if isinstance(timings, dict):
                    metrics = json.loads(m.read_text()) if m.is_file() else {}
                    side_by_side = metrics.get("trainings_side_by_side") or 1
                    total += float(timings.get("wall_seconds", 0.0)) / side_by_side
    return total


@functools.cache
def all_locks(root: Path) -> LockGraph:
    """The graph of every pipeline's lock under ``root``."""
    return lock_graph(locks(root), root)


def _seconds(graph: LockGraph, key: Stage) -> float:
    return stage_seconds(graph.wdir[key], graph.body[key])


def pipeline_seconds(lock: Path) -> float:
    """The sum of ``stage_seconds`` over the stages of ``lock`` and of its pipeline's
    studies (rule 5)."""
    graph, files = all_locks(_root(lock)), _pipeline_files(lock)
    return sum(_seconds(graph, key) for key in graph.body if key[0] in files)


@functools.cache
def chain_seconds(lock: Path) -> dict[str, float]:
    """Each chain of ``lock``'s pipeline -> its time: the ``stage_seconds`` of its stages and
    of every stage upstream of them, in any pipeline's lock, each counted once. The suite's
    chains are its tasks, per pipeline file (``suite/robomimic/dvc.yaml``'s stages of a task
    are one chain, the suite's own stages of that task another; a stage's task is its matrix
    key up to the first ``-``; its report, which reads every task, is no task's); every
    other pipeline is one chain."""
    graph, files = all_locks(_root(lock)), _pipeline_files(lock)
    per_task = files[0] == "suite/dvc.yaml"
    chains: dict[str, set[Stage]] = {}
    for key in graph.body:
        dvc_file, name = key
        if dvc_file not in files:
            continue
        folder = Path(dvc_file).parent.as_posix()
        if not per_task:
            chain = folder
        elif "@" in name:
            chain = f"{folder}:{name.split('@')[1].split('-')[0]}"
        else:
            continue
        graph.upstream(key, chains.setdefault(chain, set()))
    return {chain: sum(_seconds(graph, k) for k in keys) for chain, keys in chains.items()}


def _near(values: list[float], x: float, tol: float) -> bool:
    i = bisect.bisect_left(values, x - tol - 1e-9)
    return i < len(values) and values[i] <= x + tol + 1e-9


def found(fig: Figure, values: list[float], whole: bool = False) -> bool:
    """Whether ``fig`` is one of ``values`` (rule 4), or, ``whole``, the pipeline's time."""
    if fig.kind == "fraction":
        return _near(values, fig.value, 0) and _near(values, fig.denominator, 0)
    if whole:
        return any(abs(v - fig.value * fig.scale) <= WALL * v for v in values)
    if _near(values, fig.value, fig.half):
        return True
    if fig.kind == "percent":
        return _near(values, fig.value / 100, fig.half / 100)
    if fig.kind == "duration":
        return _near(values, fig.value * fig.scale, fig.half * fig.scale)
    return False


def unbacked(page: Path, root: Path = REPO, text: str | None = None) -> list[str]:
    """Each result number of ``page`` (or of ``text`` as if it were ``page``) that breaks
    rules 3-5, with its block's first words."""
    problems = []
    header = previous = ""
    for block in blocks(page.read_text() if text is None else text):
        if block.startswith("|") and not previous.startswith("|"):
            header = block
        previous = block
        figs = figures(prose(block))
        if not figs:
            continue
        where = f"{page.name}: {' '.join(block.split())[:70]!r}"
        cited = sources(block + (header if block.startswith("|") else ""), page, root)
        if not cited:
            problems.append(f"{where} -> cites no source for {[f.text for f in figs]}")
            continue
        locks = [p for p in cited if p.name == "dvc.lock"]
        for fig in figs:
            if fig.kind == "duration" and locks:
                ok = any(found(fig, numbers_in(lock), whole=True) for lock in locks)
            else:
                ok = any(found(fig, numbers_in(p)) for p in cited if p.name != "dvc.lock")
            if not ok:
                names = ", ".join(str(p.relative_to(root.resolve())) for p in cited)
                problems.append(f"{where} -> {fig.text!r} is not in {names}")
    return problems


def test_figures_are_the_result_numbers_and_only_those() -> None:
    prose_ = (
        "DGR 90.9 (0.143), 38 % and 2, 16, 34 % at epochs 50–200; 22–75 s, about 5 h 30 min,"
        " 1.2 ms, 22.6 MB; kept 187/200. Not: 5 GB, v3.0, robomimic 0.3.0, Python 3.10–3.11,"
        " Mesa ≥ 24.3,"
        " 0.76 m, 1.2–1.7 cm/s, x ∈ [−0.1, 0.05], Table O.1, 200 epochs, 2×100, lr 1e-3."
    )
    assert [f.text for f in figures(prose_)] == [
        "5 h 30 min", "22 s", "75 s", "1.2 ms", "22.6 MB", "38 %", "2 %", "16 %", "34 %", "187/200",
        "90.9", "0.143",
    ]  # fmt: skip


def _repo(tmp_path: Path, metrics: dict[str, float]) -> Path:
    (tmp_path / ".git").mkdir()
    (tmp_path / "metrics").mkdir()
    (tmp_path / "metrics" / "m.json").write_text(json.dumps(metrics))
    (tmp_path / "docs").mkdir()
    return tmp_path / "docs" / "page.md"


def test_each_number_must_be_in_a_file_its_block_cites(tmp_path: Path) -> None:
    page = _repo(
        tmp_path,
        {"dgr": 96.2464, "kept": 187, "attempts": 200, "wall_seconds": 137.1, "bytes": 22573056},
    )
    page.write_text(
        "Kept 187/200, DGR 96.2 % in 2.3 min ([m](../metrics/m.json)).\n\n"
        "- DGR 0.96 (a share) and 96 %, `metrics/m.json`.\n"
        "- DGR 96.3 %, `metrics/m.json`.\n"
        "| 187/201 | [m](../metrics/m.json) |\n\n"
        "| case | [m](../metrics/m.json) |\n|---|---|\n| peak | 22.6 MB |\n| DGR | 96.1 |\n\n"
        "No source: 12.5 %.\n\n"
        "```\nin code: 99.9 %\n```\nand `inline 99.9 %` and prose without numbers.\n"
    )
    found_ = [p.split(" -> ")[1] for p in unbacked(page, root=tmp_path)]
    assert found_ == [
        "'0.96' is not in metrics/m.json",
        "'96.3 %' is not in metrics/m.json",
        "'187/201' is not in metrics/m.json",
        "'96.1' is not in metrics/m.json",
        "cites no source for ['12.5 %']",
    ]


def test_a_pipeline_time_is_its_stages_wall_seconds(tmp_path: Path) -> None:
    page = _repo(tmp_path, {"dgr": 90.0})
    (tmp_path / "timings").mkdir()
    (tmp_path / "timings" / "m.json").write_text(json.dumps({"wall_seconds": 1500.0}))
    (tmp_path / "dvc.lock").write_text(
        "schema: '2.0'\nstages:\n  a:\n    outs:\n    - path: metrics/m.json\n"
        "    - path: data/store.zarr\n"
    )
    page.write_text(
        "It takes about 25 min ([lock](../dvc.lock)).\n\n"
        "It takes about 27 min ([lock](../dvc.lock)).\n\n"
        "It takes about 40 min ([lock](../dvc.lock)).\n"
    )
    assert [p.split(" -> ")[1] for p in unbacked(page, root=tmp_path)] == [
        "'40 min' is not in dvc.lock"
    ]


def test_trainings_side_by_side_count_their_shared_time_once(tmp_path: Path) -> None:
    """Two trainings of 1200 s each, side by side, are 20 min of the pipeline, not 40."""
    page = _repo(tmp_path, {"dgr": 90.0})
    (tmp_path / "timings").mkdir()
    lock = "schema: '2.0'\nstages:\n  train:\n    outs:\n"
    for name in ("a", "b"):
        (tmp_path / "metrics" / f"{name}.json").write_text('{"trainings_side_by_side": 2}')
        (tmp_path / "timings" / f"{name}.json").write_text('{"wall_seconds": 1200.0}')
        lock += f"    - path: metrics/{name}.json\n"
    (tmp_path / "dvc.lock").write_text(lock)
    page.write_text("About 20 min ([lock](../dvc.lock)).\n\nAbout 40 min ([lock](../dvc.lock)).\n")
    assert [p.split(" -> ")[1] for p in unbacked(page, root=tmp_path)] == [
        "'40 min' is not in dvc.lock"
    ]


def test_changing_one_number_of_results_md_is_caught() -> None:
    page = REPO / "docs" / "results.md"
    text = page.read_text()
    assert unbacked(page, text=text) == []
    block, fig = next(
        (b, f) for b in blocks(text) for f in figures(prose(b)) if f.kind in ("number", "percent")
    )
    # the shown number moved by a few units of its last digit, to a value no source holds
    cited = [numbers_in(p) for p in sources(block, page, REPO)]
    step = 2 * fig.half
    new = next(
        v
        for k in range(1, 100)
        for v in (fig.value + k * step, fig.value - k * step)
        if v > 0 and not any(found(dataclasses.replace(fig, value=v), c) for c in cited)
    )
    shown = f"{new:.{len(fig.text.split()[0].partition('.')[2])}f}"
    old = fig.text.split()[0]
    changed = block.replace(old, shown, 1)
    problems = unbacked(page, text=text.replace(block, changed, 1))
    assert len(problems) == 1 and repr(shown) in problems[0].replace(" %", ""), problems


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(REPO)))
def test_every_result_number_is_in_a_file_its_block_cites(page: Path) -> None:
    assert unbacked(page) == []


def _suite(tmp_path: Path, seconds: dict[str, float]) -> Path:
    """A repository whose suite has a source stage per task, a train stage per task reading
    it, a report reading both trainings, and a study whose stage of task ``a`` reads ``a``'s
    source: each stage's metrics file with ``seconds[stage]`` in its timings file."""
    (tmp_path / ".git").mkdir()
    for folder, stages in {
        "suite": {
            "source@a": [], "source@b": [], "train@a-D0": ["data/a"], "train@b-D0": ["data/b"],
            "report": ["data/a-D0", "data/b-D0"],
        },
        "suite/robomimic": {"study@a-raw": ["data/a"]},
    }.items():  # fmt: skip
        (tmp_path / folder).mkdir(parents=True, exist_ok=True)
        names = {n.split("@")[0] for n in stages}
        (tmp_path / folder / "dvc.yaml").write_text(
            "stages:\n"
            + "".join(f"  {n}:\n    wdir: {'../' * folder.count('/')}..\n" for n in names)
        )
        lock = "schema: '2.0'\nstages:\n"
        for name, deps in stages.items():
            out = "data/" + name.split("@")[1] if "@" in name else "data/report"
            metrics = f"suite/metrics/{name.replace('@', '_')}.json"
            timings = tmp_path / timings_file(metrics)
            timings.parent.mkdir(parents=True, exist_ok=True)
            timings.write_text(json.dumps({"wall_seconds": seconds.get(name, 0.0)}))
            lock += f"  {name}:\n    deps:\n" + "".join(f"    - path: {d}\n" for d in deps)
            lock += f"    - path: x\n    outs:\n    - path: {out}\n    - path: {metrics}\n"
        (tmp_path / folder / "dvc.lock").write_text(lock)
    return tmp_path / "suite" / "dvc.lock"


def test_a_chain_is_one_tasks_stages_in_one_file_with_all_they_read(tmp_path: Path) -> None:
    times = {"source@a": 100.0, "source@b": 10.0, "train@a-D0": 1000.0, "train@b-D0": 2000.0,
             "report": 5.0, "study@a-raw": 3000.0}  # fmt: skip
    lock = _suite(tmp_path, times)
    # the study's chain counts a's source once, and neither b nor the report
    chains = {"suite:a": 1100.0, "suite:b": 2010.0, "suite/robomimic:a": 3100.0}
    assert chain_seconds(lock) == chains
    assert pipeline_seconds(lock) == sum(times.values())
    page = tmp_path / "docs" / "page.md"
    page.parent.mkdir()
    page.write_text(
        "About 1 h 40 min in all, its longest chain about 52 min ([lock](../suite/dvc.lock)).\n"
        "\nIts longest chain takes about 40 min ([lock](../suite/dvc.lock)).\n"
    )
    assert [p.split(" -> ")[1] for p in unbacked(page, root=tmp_path)] == [
        "'40 min' is not in suite/dvc.lock"
    ]


# A chain runs end to end in one sitting on 2 cores: 2 h, leaving a 3-hour session the time
# to check and commit its lock whole; the image agents' pipeline is one chain of 2.5 h.
CHAIN_HOURS = {"images/dvc.lock": 2.5}


@pytest.mark.parametrize(
    "lock", [p.replace("dvc.yaml", "dvc.lock") for p in PIPELINES if p.count("/") <= 1]
)  # a study's lock is in its pipeline's chains
def test_each_chain_fits_one_sitting(lock: str) -> None:
    limit = CHAIN_HOURS.get(lock, 2.0)
    over = {
        c: round(s / 3600, 2) for c, s in chain_seconds(REPO / lock).items() if s > limit * 3600
    }
    assert not over, f"{lock}: chains over {limit} h on 2 cores: {over}"
