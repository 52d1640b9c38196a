"""Where the source stage's demos come from: the back end's demonstrator or a file format of
its own (envs/<backend>/), or a robomimic ``.hdf5`` on any back end (as the export stage
writes it, laid out as mimicgen_pipe/exporters/robomimic.py describes), read here."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from mimicgen_pipe.contracts import Env, SourceEpisode
from mimicgen_pipe.errors import InputError

ROBOMIMIC_SUFFIXES = (".hdf5", ".hdf")

# a back end's demonstrator (contracts.Backend.source_episodes): (env, num_demos, first reset
# seed, source.from_file, a scratch directory) -> (demos, failures dropped, seeds tried)
Demonstrator = Callable[[Env, int, int, "str | None", Path], tuple[list[SourceEpisode], int, int]]


def is_robomimic_file(path: str) -> bool:
    return Path(path).suffix.lower() in ROBOMIMIC_SUFFIXES


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


def robomimic_demos(path: str | os.PathLike, backend: str, task: str) -> list[RobomimicDemo]:
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


def source_episodes(
    backend: str,
    demonstrator: Demonstrator,
    env: Env,
    num_demos: int,
    seed: int,
    from_file: str | None,
    work_dir: Path,
) -> tuple[list[SourceEpisode], int, int]:
    """Up to ``num_demos`` source demos on ``env`` of back end ``backend`` (its name) from
    that back end's ``demonstrator``, drawn from reset seeds seed, seed + 1, ... (or
    ``from_file``'s: a robomimic ``.hdf5`` of this back end and task, e.g. one the export
    stage wrote, or a file format of the back end's own), how many the demonstrator dropped
    as failures, and how many seeds it tried (0 for a file)."""
    if from_file is None or not is_robomimic_file(from_file):
        return demonstrator(env, num_demos, seed, from_file, work_dir)
    demos = robomimic_demos(from_file, backend, env.spec.name)[:num_demos]
    width = env.get_state().shape[-1]
    for demo in demos:
        if demo.initial_state.shape[-1] != width:
            raise InputError(
                f"{from_file}: data/{demo.name}/states has {demo.initial_state.shape[-1]} "
                f"values per step, expected {width} (the {backend} {env.spec.name} state with "
                f"{env.robot})"
            )
    return [SourceEpisode(d.seed, d.initial_state, d.actions) for d in demos], 0, 0
