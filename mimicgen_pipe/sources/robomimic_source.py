"""robomimic HDF5 files given as source demos (source.from_file), on any back end: the files
the export stage writes (laid out as mimicgen_pipe/formats/exporters/robomimic.py describes), read
and checked whole before any simulation."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from mimicgen_pipe.core import plain_files
from mimicgen_pipe.core.errors import InputError

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


def read(path: str | os.PathLike, backend: str, task: str) -> list[RobomimicDemo]:
    """Every demo of a robomimic HDF5 file, checked before any simulation: a plain HDF5 file
    (plain_files.check_plain), data/env_args must name this back end and task (as our
    export writes them), demos named data/demo_<n>, each with actions (T, 7) and states
    (T, S) of little-endian floats with 1 <= T <= plain_files.MAX_STEPS and finite values,
    and a reset seed in plain_files.SEED_RANGE if any. Raises InputError naming the file and
    key (also for a file that is not a regular file, not HDF5 or cut short)."""
    path = Path(path)
    with plain_files.open_hdf5(path, "robomimic file") as f:
        data = _data_group(f, path)
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
        for name in plain_files.numbered(list(data), "demo_", path, "data/"):
            try:
                demos.append(_read_demo(path, data, name))
            except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
                # a damaged group or dataset, or one of strings where numbers belong
                raise InputError(f"{path}: data/{name}: unreadable ({exc})") from exc
    if not demos:
        raise InputError(f"{path}: no demos under data/")
    return demos


def _data_group(f: h5py.File, path: Path) -> h5py.Group:
    if not isinstance(f.get("data"), h5py.Group):
        raise InputError(f"{path}: no 'data' group (not a robomimic file)")
    return f["data"]


def _demo_group(path: Path, data: h5py.Group, name: str, keys: tuple[str, ...]) -> h5py.Group:
    """data/<name>, a group with datasets ``keys`` (InputError naming the key)."""
    g = data[name]
    if not isinstance(g, h5py.Group):
        raise InputError(f"{path}: data/{name} is not a demo group")
    for key in keys:
        if not isinstance(g.get(key), h5py.Dataset):
            raise InputError(f"{path}: data/{name}/{key} missing")
    return g


def _read_demo(path: Path, data: h5py.Group, name: str) -> RobomimicDemo:
    """One demo group, checked (InputError naming the key): shapes and dtypes from the
    file's declarations before anything is read."""
    g = _demo_group(path, data, name, ("actions", "states"))
    where = f"{path}: data/{name}"
    steps = plain_files.check_float_array(g["actions"], f"{where}/actions", 7)
    if plain_files.check_float_array(g["states"], f"{where}/states") != steps:
        raise InputError(f"{where}/states has shape {g['states'].shape}, expected ({steps}, S)")
    actions = np.asarray(g["actions"], np.float32)
    states = np.asarray(g["states"], np.float32)
    if not (np.isfinite(actions).all() and np.isfinite(states).all()):
        raise InputError(f"{where}: NaN or infinite action or state")
    seed = g.attrs.get("seed", -1)
    # an integer scalar (numpy's or Python's); a bool, float or string is not a seed
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise InputError(f"{where}.attrs['seed'] is {seed!r}, expected an integer")
    seed = plain_files.check_seed(int(seed), f"{where}.attrs['seed']")
    return RobomimicDemo(name, seed, states[0], actions)


def check_training_file(path: str | os.PathLike) -> int:
    """The number of demos of a robomimic dataset to train on, checked from its metadata
    before robomimic opens it: a plain HDF5 file (plain_files.check_plain), demos named
    data/demo_<n>, each with actions (T, A) of floats and observations of T rows.
    InputError naming the file and key otherwise."""
    path = Path(path)
    with plain_files.open_hdf5(path, "robomimic dataset") as f:
        data = _data_group(f, path)
        names = plain_files.numbered(list(data), "demo_", path, "data/")
        for name in names:
            g = _demo_group(path, data, name, ("actions",))
            steps = plain_files.check_float_array(g["actions"], f"{path}: data/{name}/actions")
            for key in ("obs", "next_obs"):
                for obs, d in g.get(key, {}).items():
                    if not isinstance(d, h5py.Dataset) or d.shape[:1] != (steps,):
                        raise InputError(
                            f"{path}: data/{name}/{key}/{obs} has shape "
                            f"{getattr(d, 'shape', 'a group')}, expected ({steps}, ...)"
                        )
    if not names:
        raise InputError(f"{path}: no demos under data/")
    return len(names)
