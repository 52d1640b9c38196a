"""Reading JSON from outside the process (metrics files, dvc's output, zarr.json, checkpoint
configs) with bounds: a regular file of at most a size
(:func:`mimicgen_pipe.core.yamlfile.read_text`), nested at most :data:`MAX_DEPTH` levels, and every
failure one InputError line naming where the JSON came from. Python's json recurses once per level
and raises RecursionError deep down; the depth bound keeps whatever walks the value afterwards
(ours, zarr's) shallow."""

from __future__ import annotations

import json
import os
from typing import Any

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.yamlfile import MAX_BYTES, read_text

MAX_DEPTH = 100  # levels of nested lists and objects; the files read here have a few


def parse_json(text: str | bytes, source: str, max_depth: int = MAX_DEPTH) -> Any:
    """The JSON value of ``text``; InputError naming ``source`` (a file, a key) when it is
    not UTF-8, not JSON, or nested deeper than ``max_depth`` levels."""
    try:
        value = json.loads(text)
    except RecursionError:
        raise InputError(f"{source}: JSON nested deeper than {max_depth} levels") from None
    except json.JSONDecodeError as exc:
        raise InputError(
            f"{source}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})"
        ) from exc
    except UnicodeDecodeError as exc:
        raise InputError(f"{source}: not UTF-8 text (offset {exc.start})") from exc
    if _depth(value, max_depth) > max_depth:
        raise InputError(f"{source}: JSON nested deeper than {max_depth} levels")
    return value


def read_json(path: str | os.PathLike, what: str = "JSON file", max_bytes: int = MAX_BYTES) -> Any:
    """The JSON value of the file at ``path``: a regular file of at most ``max_bytes``, UTF-8,
    nested at most :data:`MAX_DEPTH` levels; one InputError line naming the file otherwise
    (``what`` says what was expected there)."""
    return parse_json(read_text(path, what, max_bytes), str(path))


def _depth(value: Any, limit: int) -> int:
    """The nesting depth of a parsed JSON value (a scalar: 0), counted iteratively and only
    until it passes ``limit``."""
    deepest, stack = 0, [(value, 1)]
    while stack and deepest <= limit:
        node, level = stack.pop()
        if not isinstance(node, dict | list):
            continue
        deepest = max(deepest, level)
        children = node.values() if isinstance(node, dict) else node
        stack.extend((child, level + 1) for child in children if isinstance(child, dict | list))
    return deepest
