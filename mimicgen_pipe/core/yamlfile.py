"""Reading the YAML files a user writes (params.yaml, boundaries files) strictly: a key given
twice in one mapping is an error (plain YAML loaders keep the last one silently), and every
failure is one InputError line naming the file and, where YAML knows it, the line."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.plain_files import regular_file

_MERGE_TAG = "tag:yaml.org,2002:merge"
# what a user's YAML file may hold, counted as its nodes with every alias expanded: a params
# file has a few hundred; aliases nested ten deep expand a 1 kB file to billions, which any
# walk over the loaded values (a check, an error message) would never finish
MAX_NODES = 100_000


class ExpansionError(yaml.YAMLError):
    """A document whose aliases expand it past :data:`MAX_NODES` nodes."""


class DuplicateKeyError(yaml.constructor.ConstructorError):
    """A key given twice in one YAML mapping; ``problem`` names it and both lines."""


class UniqueKeyLoader(yaml.SafeLoader):
    """yaml.SafeLoader that refuses a mapping with the same key twice. Keys are compared as
    the values they load to, so ``1`` and ``1.0`` (one key to Python) count as the same key.
    Keys brought in by a ``<<`` merge may still be overridden, as YAML intends."""

    def get_single_node(self) -> yaml.Node | None:
        node = super().get_single_node()
        if node is not None and (n := _expanded_nodes(node, {})) > MAX_NODES:
            raise ExpansionError(
                f"its aliases expand it to {n} nodes, more than the {MAX_NODES} a file here "
                "may hold; write the values out, or use fewer nested aliases"
            )
        return node

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, tuple[Any, yaml.Node]] = {}
            for key_node, _ in node.value:
                if key_node.tag == _MERGE_TAG:
                    continue
                key = self.construct_object(key_node, deep=deep)
                try:
                    first, first_node = seen.setdefault(key, (key, key_node))
                except TypeError:  # an unhashable key: the base class explains it
                    continue
                if first_node is not key_node:
                    a, b = first_node.start_mark.line + 1, key_node.start_mark.line + 1
                    name = repr(key) if repr(first) == repr(key) else f"{first!r} / {key!r}"
                    why = f"key {name} appears twice in one mapping (lines {a} and {b})"
                    raise DuplicateKeyError(
                        None, None, f"{why}; give each key once", key_node.start_mark
                    )
        return super().construct_mapping(node, deep=deep)


def _expanded_nodes(node: yaml.Node, memo: dict[int, int]) -> int:
    """The number of nodes under ``node``, an alias counted as a copy of what it names
    (each node's count computed once: linear in the file, not in its expansion)."""
    if id(node) in memo:
        return memo[id(node)]
    memo[id(node)] = 1  # a node that contains itself through an alias counts once there
    children: list[yaml.Node] = []
    if isinstance(node, yaml.SequenceNode):
        children = list(node.value)
    elif isinstance(node, yaml.MappingNode):
        children = [n for pair in node.value for n in pair]
    memo[id(node)] = 1 + sum(_expanded_nodes(c, memo) for c in children)
    return memo[id(node)]


def _one_line(exc: yaml.YAMLError) -> str:
    """A YAML error as one line: what is wrong and where (1-based line and column)."""
    if isinstance(exc, DuplicateKeyError):
        return str(exc.problem)
    if isinstance(exc, yaml.reader.ReaderError):  # e.g. a NUL byte: a binary file
        ch = exc.character
        code = ch if isinstance(ch, int) else ord(ch)
        return f"character U+{code:04X} at offset {exc.position} is not allowed in YAML text"
    if isinstance(exc, yaml.MarkedYAMLError) and exc.problem_mark is not None:
        mark = exc.problem_mark
        context = f"{exc.context}; " if exc.context else ""
        return f"line {mark.line + 1}, column {mark.column + 1}: {context}{exc.problem}"
    return " ".join(str(exc).split())


# a file a user gives is read whole: larger than this, it is not one of ours (a params file
# is a few kB, a metrics file or a trajectory's JSON a few MB at most)
MAX_BYTES = 64 << 20


def read_text(path: str | Path, what: str, max_bytes: int = MAX_BYTES) -> str:
    """The UTF-8 text of a user's file; InputError naming the file when it is missing
    (``what`` says what was expected there), not a regular file (a folder, a device such as
    /dev/zero, a pipe), larger than ``max_bytes``, unreadable or not UTF-8 text (e.g. a
    binary file given by mistake)."""
    path = Path(path)
    regular_file(path, what, max_bytes)
    try:
        with path.open("rb") as f:
            data = f.read(max_bytes + 1)  # a file that grew since: still bounded
    except OSError as exc:
        raise InputError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from exc
    if len(data) > max_bytes:
        raise InputError(f"{path}: more than the {max_bytes} bytes a {what} may have")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{path}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}); "
            f"expected a {what}"
        ) from exc


def load_yaml(path: str | Path, what: str) -> Any:
    """The YAML document at ``path``, loaded with UniqueKeyLoader (plain data only: no
    Python objects). InputError naming the file when it is missing (``what`` says what was
    expected there), unreadable, not UTF-8 text, not valid YAML, or has a key twice."""
    path = Path(path)
    text = read_text(path, what)
    try:
        return yaml.load(text, Loader=UniqueKeyLoader)  # noqa: S506 (a SafeLoader subclass)
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML: {_one_line(exc)}") from exc
