#!/usr/bin/env python
"""Each sub-pipeline's params file, written from the default pipeline's params.yaml and that
pipeline's own params.overrides.yaml, so that a default is written once.

DVC reads every pipeline's params from one whole file (``<pipeline>/params.yaml``: its
stages' ``params:`` and the ``vars`` of its dvc.yaml), and its templating cannot layer one
file over another. So the whole file is generated, and the differences are what is edited:

    <pipeline>/params.overrides.yaml
      # The generated file's header (these leading comment lines).
      leave_out: [train.cpu_image, render]  # keys of params.yaml its stages never read
      generate:             # every other key: a value it changes, or a section of its own
        num_demos: 20       # a comment here replaces params.yaml's for this key

``--write`` rewrites the generated files; ``--check`` (run by the tests) names each one that
differs from what ``--write`` would give. Comments and key order are params.yaml's, so the
generated files read like it.
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path
from typing import Any

from ruamel.yaml import YAML
from ruamel.yaml.comments import CommentedMap

PIPELINES = ("quickstart", "suite", "transfer", "transit", "images")
OVERRIDES = "params.overrides.yaml"
NOTE = (
    "# Written by `scripts/params_files.py --write` from ../params.yaml and\n"
    f"# {OVERRIDES}: edit those (a `dvc exp run -S` may still set a key here).\n"
)


def _yaml() -> YAML:
    y = YAML()
    y.width = 4096  # params.yaml's long comments stay on their lines
    y.preserve_quotes = True
    y.representer.add_representer(
        type(None), lambda r, _: r.represent_scalar("tag:yaml.org,2002:null", "null")
    )
    return y


def header(text: str) -> str:
    """The leading comment lines of an overrides file."""
    lines = []
    for line in text.splitlines(keepends=True):
        if not line.startswith("#"):
            break
        lines.append(line)
    return "".join(lines)


def _line(comment: str) -> str:
    """A comment token's own line, without the lines ruamel keeps after it."""
    return comment.split("\n", 1)[0] + "\n"


def _comment(mapping: CommentedMap, key: Any) -> Any:
    """The comment token after ``key``'s value in ``mapping`` (None: it has none)."""
    return (mapping.ca.items.get(key) or [None] * 4)[2]


def _last_leaf(node: CommentedMap) -> tuple[CommentedMap, Any]:
    """The mapping and key whose comment holds the lines after ``node``'s last line."""
    key = list(node)[-1]
    value = node[key]
    return _last_leaf(value) if isinstance(value, dict) and value else (node, key)


def _leave_out(tree: CommentedMap, dotted: str, where: str) -> None:
    *parents, last = dotted.split(".")
    node = tree
    for key in parents:
        node = node.get(key) if isinstance(node, dict) else None
    if not isinstance(node, dict) or last not in node:
        raise SystemExit(f"{where}: leave_out: {dotted!r} is not a key of params.yaml")
    # ruamel keeps the lines after a value (a blank line, the next key's heading) in the
    # comment of its last key: hand them to the key before the one left out
    owner, key = _last_leaf(node[last]) if isinstance(node[last], dict) else (node, last)
    token = _comment(owner, key)
    keys = list(node)
    del node[last]
    i = keys.index(last)
    if token is None or "\n" not in token.value or i == 0:
        return
    tail = token.value.split("\n", 1)[1]
    before, at = node, keys[i - 1]
    if isinstance(node[at], dict) and node[at]:
        before, at = _last_leaf(node[at])
    mine = _comment(before, at)
    if mine is not None:
        mine.value = _line(mine.value) + tail
    else:
        token.value = "\n" + tail
        before.ca.items[at] = [None, None, token, None]


def _set(tree: CommentedMap, changes: CommentedMap) -> None:
    for key, value in changes.items():
        known = key in tree
        section = known and isinstance(value, dict) and isinstance(tree[key], dict)
        theirs = _comment(tree, key)
        if not known and tree:  # a section of its own, after a blank line
            owner, last = _last_leaf(tree)
            token = _comment(owner, last)
            if token is not None:
                token.value = _line(token.value) + "\n"
        if section:
            _set(tree[key], value)
        else:
            tree[key] = value
        ours = _comment(changes, key)
        if ours is None:
            continue
        # the override's own comment replaces params.yaml's; params.yaml's lines after it
        # (a blank line, the next key's heading) stay
        if section:
            tree[key].ca.comment = [ours, None]
        elif known:
            ours.value = _line(ours.value) + (theirs.value.split("\n", 1)[1] if theirs else "")
        tree.ca.items[key] = [None, None, ours, None]


def generated(root: Path, pipeline: str) -> str:
    """The text of ``<pipeline>/params.yaml`` as params.yaml and its overrides make it."""
    y = _yaml()
    path = root / pipeline / OVERRIDES
    text = path.read_text()
    spec: Any = y.load(text)
    if not isinstance(spec, dict):
        raise SystemExit(f"{path}: expected a mapping of params.yaml's keys")
    tree: Any = y.load((root / "params.yaml").read_text())
    tree.ca.comment = None  # params.yaml's own header
    for dotted in spec.pop("leave_out", None) or []:
        _leave_out(tree, dotted, str(path))
    _set(tree, spec)
    out = io.StringIO()
    y.dump(tree, out)
    return header(text) + NOTE + out.getvalue().rstrip("\n") + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--write", action="store_true", help="rewrite the generated files")
    mode.add_argument("--check", action="store_true", help="fail on a file --write would change")
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1])
    args = parser.parse_args(argv)
    stale = []
    for pipeline in PIPELINES:
        target = args.root / pipeline / "params.yaml"
        text = generated(args.root, pipeline)
        if not target.exists() or target.read_text() != text:
            if args.write:
                target.write_text(text)
                print(f"wrote {target.relative_to(args.root)}")
            else:
                stale.append(str(target.relative_to(args.root)))
    if stale:
        print(
            f"{', '.join(stale)}: not as params.yaml and {OVERRIDES} make them; run "
            "scripts/params_files.py --write",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
