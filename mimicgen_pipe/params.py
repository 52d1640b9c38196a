"""params.yaml, validated into frozen dataclasses before any work.

Every knob of every stage lives in params.yaml; a wrong type, an out-of-range value or an
unknown key stops the stage with one message naming the key.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml

from mimicgen_pipe.errors import InputError


@dataclass(frozen=True)
class SourceParams:
    """num_demos: successful source demos wanted (D0). seed: first reset seed.
    from_file: a ManiSkill trajectory .h5 (pd_ee_delta_pose) to use instead of the
    motion-planning demonstrator; null to use the demonstrator."""

    num_demos: int = 10
    seed: int = 0
    from_file: str | None = None


@dataclass(frozen=True)
class GenerateParams:
    """Generation knobs (paper M.6 defaults). mode "guarantee" runs until num_demos
    successes (failing loudly after max_attempts); "fixed_attempts" runs exactly
    max_attempts attempts. workers: simulator processes (spawn)."""

    variants: list[str] = field(default_factory=lambda: ["D0", "D1"])
    num_demos: int = 1000
    mode: Literal["guarantee", "fixed_attempts"] = "guarantee"
    max_attempts: int = 3000
    action_noise: float = 0.05
    n_interp: int = 5
    n_fixed: int = 0
    selection: Literal["random", "nearest_neighbor"] = "random"
    nn_k: int = 3
    per_subtask: bool = False
    seed: int = 0
    workers: int = 2


@dataclass(frozen=True)
class Params:
    task: str = "stack_cube"
    backend: Literal["maniskill"] = "maniskill"
    robot: str = "panda"
    source: SourceParams = field(default_factory=SourceParams)
    generate: GenerateParams = field(default_factory=GenerateParams)


_RANGES: dict[str, tuple[float, float]] = {
    "source.num_demos": (1, 10_000),
    "generate.num_demos": (0, 10_000_000),
    "generate.max_attempts": (1, 10_000_000),
    "generate.action_noise": (0.0, 1.0),
    "generate.n_interp": (0, 1000),
    "generate.n_fixed": (0, 1000),
    "generate.nn_k": (1, 10_000),
    "generate.workers": (1, 256),
}


def _describe(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_describe(a) for a in typing.get_args(tp))
    if origin is list:
        return f"a list of {_describe(typing.get_args(tp)[0])}"
    return {
        int: "an integer",
        float: "a number",
        bool: "true/false",
        str: "a string",
        type(None): "null",
    }.get(tp, str(tp))


def _check(value: Any, tp: Any) -> bool:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return value in typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return any(_check(value, a) for a in typing.get_args(tp))
    if origin is list:
        return isinstance(value, list) and all(_check(v, typing.get_args(tp)[0]) for v in value)
    if tp is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if tp is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if tp is type(None):
        return value is None
    return isinstance(value, tp)


def _build(cls: type, raw: Any, where: str, path: Path) -> Any:
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise InputError(f"{path}: {where or 'top level'}: expected a mapping, got {raw!r}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(raw) - names)
    if unknown:
        key = f"{where}.{unknown[0]}" if where else unknown[0]
        raise InputError(f"{path}: {key}: unknown key (known: {', '.join(sorted(names))})")
    kwargs = {}
    for name in names & set(raw):
        key = f"{where}.{name}" if where else name
        tp, value = hints[name], raw[name]
        if dataclasses.is_dataclass(tp):
            kwargs[name] = _build(tp, value, key, path)
            continue
        if not _check(value, tp):
            raise InputError(f"{path}: {key}: expected {_describe(tp)}, got {value!r}")
        if key in _RANGES:
            lo, hi = _RANGES[key]
            if not lo <= value <= hi:
                raise InputError(f"{path}: {key}: expected a value in [{lo}, {hi}], got {value!r}")
        kwargs[name] = float(value) if tp is float else value
    return cls(**kwargs)


def load_params(path: str | Path = "params.yaml") -> Params:
    """Read and validate params.yaml; raises InputError naming the file and key."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: params file not found")
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML ({exc})") from exc
    return _build(Params, raw, "", path)


def as_dict(params: Any) -> dict[str, Any]:
    """Params as plain data, for store attributes and metrics."""
    return dataclasses.asdict(params)
