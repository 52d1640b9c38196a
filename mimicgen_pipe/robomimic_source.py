"""robomimic HDF5 files given as source demos (source.from_file), on any back end: the files
the export stage writes (laid out as mimicgen_pipe/exporters/robomimic.py describes), read
and checked whole before any simulation."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from mimicgen_pipe.errors import InputError

SUFFIXES = (".hdf5", ".hdf")


def is_robomimic_file(path: str) -> bool:
    return Path(path).suffix.lower() in SUFFIXES


@dataclass(frozen=True)
class RobomimicDemo:
    """One demo of a robomimic file: its name, reset seed (-1 when the file has none), the
    flat simulator state before the first action (S,) and the actions (T, 7)."""

    name: str
    seed: int
    initial_state: np.ndarray
    actions: np.ndarray


def _demo_order(names: list[str]) -> list[str]:
    """demo_<i> by i, as robomimic orders them (other names after, alphabetically)."""
    numbered = sorted((int(n[5:]), n) for n in names if n.startswith("demo_") and n[5:].isdigit())
    return [n for _, n in numbered] + sorted(set(names) - {n for _, n in numbered})


def read(path: str | os.PathLike, backend: str, task: str) -> list[RobomimicDemo]:
    """Every demo of a robomimic HDF5 file, checked before any simulation: data/env_args must
    name this back end and task (as our export writes them), each demo must have actions
    (T, 7) and states (T, S) with T >= 1 and finite values, and an integer seed if any.
    Raises InputError naming the file and key (also for a file that is not HDF5 or is cut
    short)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: robomimic file not found")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:  # not HDF5 at all, or truncated (h5py's message says which)
        raise InputError(f"{path}: not a readable HDF5 file ({exc})") from exc
    with f:
        if not isinstance(f.get("data"), h5py.Group):
            raise InputError(f"{path}: no 'data' group (not a robomimic file)")
        data = f["data"]
        try:
            kwargs = json.loads(data.attrs["env_args"])["env_kwargs"]
            if not isinstance(kwargs, dict):
                raise TypeError(kwargs)
        except (KeyError, TypeError, ValueError, OSError) as exc:
            raise InputError(f"{path}: data.attrs['env_args'] missing or not JSON") from exc
        got = (kwargs.get("backend"), kwargs.get("task"))
        if got != (backend, task):
            raise InputError(
                f"{path}: env_args.env_kwargs names backend/task {got[0]!r}/{got[1]!r}, "
                f"expected {backend!r}/{task!r}"
            )
        demos = []
        for name in _demo_order(list(data)):
            try:
                demos.append(_read_demo(path, data, name))
            except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
                # a damaged group or dataset, or one of strings where numbers belong
                raise InputError(f"{path}: data/{name}: unreadable ({exc})") from exc
    if not demos:
        raise InputError(f"{path}: no demos under data/")
    return demos


def _read_demo(path: Path, data: h5py.Group, name: str) -> RobomimicDemo:
    """One demo group, checked (InputError naming the key)."""
    g = data[name]
    if not isinstance(g, h5py.Group):
        raise InputError(f"{path}: data/{name} is not a demo group")
    for key in ("actions", "states"):
        if not isinstance(g.get(key), h5py.Dataset):
            raise InputError(f"{path}: data/{name}/{key} missing")
    actions = np.asarray(g["actions"], np.float32)
    states = np.asarray(g["states"], np.float32)
    if actions.ndim != 2 or actions.shape[1] != 7 or len(actions) == 0:
        raise InputError(f"{path}: data/{name}/actions has shape {actions.shape}, expected (T, 7)")
    if states.ndim != 2 or len(states) != len(actions):
        raise InputError(
            f"{path}: data/{name}/states has shape {states.shape}, expected ({len(actions)}, S)"
        )
    if not (np.isfinite(actions).all() and np.isfinite(states).all()):
        raise InputError(f"{path}: data/{name}: NaN or infinite action or state")
    seed = g.attrs.get("seed", -1)
    # an integer scalar (numpy's or Python's); a bool, float or string is not a seed
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise InputError(f"{path}: data/{name}.attrs['seed'] is {seed!r}, expected an integer")
    return RobomimicDemo(name, int(seed), states[0], actions)
