"""A run's generation settings (the params keys an ablation may change) and their
comparison, with each other and with the settings the paper names for its numbers."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from mimicgen_pipe.core.noise_levels import NAMED_LEVELS
from mimicgen_pipe.data.params import Params

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


def same_value(a: Any, b: Any) -> bool:
    if isinstance(a, bool) or isinstance(b, bool):
        return a is b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(a, b, abs_tol=1e-12)
    return a == b


def matches(settings: Mapping[str, Any], named: Mapping[str, Any]) -> bool:
    """Whether a run with ``settings`` has every value ``named`` (e.g. a paper entry's)."""
    return all(same_value(settings.get(k), v) for k, v in named.items())


def changed_settings(base: Mapping[str, Any], run: Mapping[str, Any]) -> dict[str, Any]:
    return {k: run[k] for k in METHOD_KEYS if not same_value(base.get(k), run.get(k))}
