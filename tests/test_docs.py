"""The documentation: README.md stays short, says the test command CI runs, every relative
link in README.md, docs/ and lab/README.md leads to a file (and heading) the repository has,
every `python <file>.py` command they give names a file the repository has, and every params
key has its row in docs/stages-and-params.md."""

from __future__ import annotations

import dataclasses
import fnmatch
import re
import shlex
import typing
from pathlib import Path

import pytest
import yaml

from mimicgen_pipe.data.params import Params

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
README_MAX_LINES = 200
PAGES = [README, *sorted((REPO / "docs").rglob("*.md")), REPO / "lab" / "README.md"]

FENCE = re.compile(r"^(```|~~~).*?^\1[^\n]*$", re.M | re.S)
INLINE_CODE = re.compile(r"`[^`\n]*`")
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*#*\s*$", re.M)
SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")
PYTHON_FILE = re.compile(r"\bpython3?\s+([\w./-]+\.py)\b")


def _prose(text: str) -> str:
    """``text`` without fenced code blocks and inline code, where links are not links."""
    return INLINE_CODE.sub("", FENCE.sub("", text))


def links(text: str) -> list[str]:
    """The targets of the Markdown links and images in ``text``, outside code."""
    return LINK.findall(_prose(text))


def anchors(text: str) -> set[str]:
    """The anchors GitHub gives the headings of ``text``: lower case, punctuation dropped,
    spaces as hyphens, a repeated one numbered -1, -2, ..."""
    seen: dict[str, int] = {}
    out = set()
    for heading in HEADING.findall(FENCE.sub("", text)):
        slug = re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def broken_links(page: Path, root: Path = REPO) -> list[str]:
    """Each relative link of ``page`` that leads outside ``root``, to no file, or to a
    heading a Markdown file does not have, with why."""
    broken = []
    for target in links(page.read_text()):
        if SCHEME.match(target):  # http(s), mailto: not a file of the repository
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page.resolve()
        if not dest.is_relative_to(root.resolve()):
            broken.append(f"{target}: outside {root}")
        elif not dest.exists():
            broken.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest.read_text()):
            broken.append(f"{target}: no heading #{anchor} in {dest.name}")
    return broken


def test_the_link_check_finds_broken_links_and_only_those(tmp_path: Path) -> None:
    (tmp_path / "other.md").write_text("# Other page\n\n## Policies (paper P.1)\n")
    page = tmp_path / "page.md"
    page.write_text(
        "[ok](other.md) [ok](other.md#policies-paper-p1) [ok](#here) [web](https://example.org)\n"
        "[gone](missing.md) [bad anchor](other.md#nowhere) [up](../x.md)\n"
        "`[in code](also-missing.md)`\n```\n[in a block](block-missing.md)\n# not a heading\n```\n"
        "## Here\n"
    )
    found = [b.split(": ")[0] for b in broken_links(page, root=tmp_path)]
    assert found == ["missing.md", "other.md#nowhere", "../x.md"]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(REPO)))
def test_every_relative_link_resolves(page: Path) -> None:
    assert broken_links(page) == []


def missing_scripts(page: Path, root: Path = REPO) -> list[str]:
    """Each ``python <file>.py`` of ``page`` (in code or prose) whose file, a path from the
    repository root, ``root`` lacks."""
    return [f for f in PYTHON_FILE.findall(page.read_text()) if not (root / f).is_file()]


def test_the_script_check_finds_missing_scripts(tmp_path: Path) -> None:
    (tmp_path / "tools").mkdir()
    (tmp_path / "tools" / "there.py").write_text("")
    page = tmp_path / "page.md"
    page.write_text(
        "Run `python tools/there.py --help` or\n```bash\n.venv/bin/python tools/gone.py\n```\n"
        "and `python -m pytest`, then python3 old/place.py.\n"
    )
    assert missing_scripts(page, root=tmp_path) == ["tools/gone.py", "old/place.py"]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(REPO)))
def test_every_python_command_names_a_file_of_the_repository(page: Path) -> None:
    assert missing_scripts(page) == []


def test_readme_is_short() -> None:
    lines = README.read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md: {len(lines)} lines"


def test_readme_gives_the_test_command_ci_runs() -> None:
    """The command CI runs after setting up is a line of README.md, character for character,
    inside a code block."""
    ci = (REPO / ".ci" / "run").read_text().splitlines()
    commands = [line.strip() for line in ci if "pytest" in line and '"not slow"' in line]
    assert len(commands) == 1, f".ci/run: expected one 'not slow' test command, got {commands}"
    blocks = "\n".join(m.group(0) for m in FENCE.finditer(README.read_text()))
    assert commands[0] in blocks.splitlines()


def params_keys(cls: type = Params) -> dict[str, list[str]]:
    """Section -> its keys (a nested section's keys by their last name, e.g. train.cpu's
    ``hidden`` under ``train``); the top-level keys under ``Top level``."""
    out: dict[str, list[str]] = {}
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(hints[f.name]):
            out[f.name] = sorted(_leaves(hints[f.name]))
        else:
            out.setdefault("Top level", []).append(f.name)
    return out


def _leaves(cls: type) -> set[str]:
    hints = typing.get_type_hints(cls)
    leaves = set()
    for f in dataclasses.fields(cls):
        is_section = dataclasses.is_dataclass(hints[f.name])
        leaves |= _leaves(hints[f.name]) if is_section else {f.name}
    return leaves


def test_every_params_key_has_a_row_in_stages_and_params() -> None:
    text = (REPO / "docs" / "stages-and-params.md").read_text()
    text = text[text.index("\n## params.yaml, section by section") :]  # not the stages
    undocumented = []
    for section, keys in params_keys().items():
        part = re.search(rf"^### {re.escape(section)}\n(.*?)(?=^##|\Z)", text, re.M | re.S)
        rows = set(re.findall(r"^\| `([^`]+)` \|", part.group(1), re.M)) if part else set()
        undocumented += [f"{section}: {k}" for k in keys if k not in rows]
    assert undocumented == []


def _shell_commands(line: str) -> list[list[str]]:
    """The words of each command of a shell line (split at ``&&``, ``;``, ``|``, quotes
    respected, comments dropped; a redirection cuts a command there)."""
    lexer = shlex.shlex(line, posix=True, punctuation_chars=";&|")
    lexer.whitespace_split = True
    commands: list[list[str]] = [[]]
    for word in lexer:
        if word and set(word) <= set(";&|"):
            commands.append([])
        else:
            commands[-1].append(word)
    return commands


def doc_commands(
    tool: str, pages: list[Path] = PAGES, root: Path = REPO
) -> list[tuple[str, list[str]]]:
    """Every ``<tool> <subcommand> ...`` in the fenced code of ``pages``, as (page, argv
    after the tool's name): continued lines joined, cut at a comment, a pipe or redirection,
    ``&&`` or ``;``, and error messages quoted in the docs (``tool stage: error: ...``) left
    out."""
    found = []
    for page in pages:
        for block in FENCE.finditer(page.read_text()):
            for line in block.group(0).replace("\\\n", " ").splitlines()[1:-1]:
                for words in _shell_commands(line):
                    if tool not in words:
                        continue
                    argv = words[words.index(tool) + 1 :]
                    argv = argv[: next((i for i, w in enumerate(argv) if w[0] in "<>"), None)]
                    if argv and not argv[0].endswith(":"):
                        found.append((str(page.relative_to(root)), argv))
    return found


def test_the_command_finder_reads_code_blocks_as_a_shell_would(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(
        "`mimicgen-pipe prose --no`\n```bash\n. x && mimicgen-pipe export --variant D1 \\\n"
        "  --formats robomimic   # a comment\nmimicgen-pipe boundaries > ends.yaml\n"
        "mimicgen-pipe parse: error: quoted output\n```\n"
    )
    page = page.relative_to(tmp_path)
    found = [argv for _, argv in doc_commands("mimicgen-pipe", [tmp_path / page], tmp_path)]
    assert found == [["export", "--variant", "D1", "--formats", "robomimic"], ["boundaries"]]


def test_every_documented_stage_command_parses_as_written() -> None:
    """Each `mimicgen-pipe ...` of the docs names a stage and only options it has, with
    values its parser accepts (the stages' own parser, without running them)."""
    from mimicgen_pipe.cli import build_parser

    parser, _ = build_parser()
    commands = doc_commands("mimicgen-pipe")
    assert len(commands) >= 8
    for page, argv in commands:
        try:
            parser.parse_args(argv)
        except SystemExit:
            pytest.fail(f"{page}: mimicgen-pipe {' '.join(argv)}: not accepted")


def _params_key(file: Path, key: str) -> bool:
    node = yaml.safe_load(file.read_text())
    for part in key.lstrip("+").split("."):
        if not isinstance(node, dict) or part not in node:
            return False
        node = node[part]
    return True


def test_every_documented_dvc_command_names_real_stages_and_params() -> None:
    """Each `dvc repro` / `dvc exp run` of the docs names pipelines and stages that exist
    (with ``--glob``: patterns that match a stage), and each `-S [file:]key=value` a key of
    that params file (DVC's default: params.yaml)."""
    from dvc.repo import Repo

    with Repo(str(REPO)) as repo:
        stages = {(s.dvcfile.relpath, s.addressing.split(":")[-1]) for s in repo.index.stages}
    groups = {(f, name.split("@")[0]) for f, name in stages}
    bad = []
    for page, argv in doc_commands("dvc"):
        if argv[:1] != ["repro"] and argv[:2] != ["exp", "run"]:
            continue
        args = argv[1 if argv[0] == "repro" else 2 :]
        i = 0
        while i < len(args):
            a = args[i]
            if a in ("-S", "--set-param"):
                file, _, key = args[i + 1].split("=")[0].rpartition(":")
                if not _params_key(REPO / (file or "params.yaml"), key):
                    bad.append(f"{page}: -S {args[i + 1]}: no such key")
                i += 2
                continue
            if a in ("-n", "--name", "-j"):
                i += 2
                continue
            if not a.startswith("-"):  # a pipeline, a stage of dvc.yaml, or <file>:<stage>
                file, stage = (a, "") if a.endswith(".yaml") else (a.rpartition(":")[::2])
                file = file or "dvc.yaml"
                if "--glob" in args:  # a pattern names at least one stage
                    if not any(f == file and fnmatch.fnmatchcase(n, stage) for f, n in stages):
                        bad.append(f"{page}: {a}: no such stage")
                elif stage and (file, stage) not in stages and (file, stage) not in groups:
                    bad.append(f"{page}: {a}: no such stage")
                if not (REPO / file).is_file():
                    bad.append(f"{page}: {a}: no such pipeline")
            i += 1
    assert bad == []
