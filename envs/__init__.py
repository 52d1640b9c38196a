"""Simulator back ends behind one protocol (mimicgen_pipe.generation.Env).

A back end is a package ``envs/<backend>/`` with its tasks one file each under
``envs/<backend>/tasks/``, looked up by name. Simulator packages are imported only when an
env is made, so ``task_spec`` and the library stay importable without them.
"""

from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from mimicgen_pipe.errors import InputError
from mimicgen_pipe.taskspec import TaskSpec

BACKENDS = ("maniskill", "pybullet")


def _module(backend: str):
    if backend == "maniskill":
        from envs import maniskill

        return maniskill
    if backend == "pybullet":
        from envs import pybullet

        return pybullet
    raise InputError(f"backend {backend!r}: unknown (known: {', '.join(BACKENDS)})")


def task_names(backend: str) -> tuple[str, ...]:
    """The tasks ``backend`` has: the files in envs/<backend>/tasks/."""
    tasks = _module(backend).tasks
    return tuple(sorted(m.name for m in pkgutil.iter_modules(tasks.__path__) if not m.ispkg))


def load_task(backend: str, name: str):
    """The back end's task object (``TASK``) defined in envs/<backend>/tasks/<name>.py;
    InputError for an unknown name."""
    known = task_names(backend)
    if name not in known:
        raise InputError(
            f"task {name!r}: unknown for backend {backend} (known: {', '.join(known)})"
        )
    task = importlib.import_module(f"envs.{backend}.tasks.{name}").TASK
    if task.spec.name != name:
        raise ValueError(f"envs/{backend}/tasks/{name}.py defines task {task.spec.name!r}")
    return task


def task_spec(backend: str, task: str) -> TaskSpec:
    """The task spec of ``task`` on ``backend``; InputError for an unknown name."""
    return load_task(backend, task).spec


def check_variant(spec: TaskSpec, variant: str) -> None:
    if variant not in spec.reset_variants:
        raise InputError(
            f"variant {variant!r}: unknown for task {spec.name} (known: {', '.join(spec.variants)})"
        )


def check_obs_keys(spec: TaskSpec, keys, where: str) -> None:
    """InputError naming ``where`` when an observation key is not one ``spec``'s task
    records."""
    unknown = [k for k in keys if k not in spec.provided_obs_keys]
    if unknown:
        raise InputError(
            f"{where}: {', '.join(map(repr, unknown))} not an observation of task {spec.name} "
            f"(known: {', '.join(spec.provided_obs_keys)})"
        )


def check_robot(backend: str, robot: str) -> None:
    """InputError for an arm ``backend`` does not have, or whose URDF files are missing."""
    _module(backend).check_robot(robot)


def make_env(backend: str, task: str, robot: str = "panda", fast_step: bool = True):
    """A fresh env of ``task`` on ``backend`` that implements the env protocol. fast_step
    (maniskill): the lean control step, the same simulation without ManiSkill's per-step
    bookkeeping (envs/maniskill/lean.py); False: ManiSkill's own ``env.step``.

    It also puts numpy's BLAS on one thread for the rest of the process: OpenBLAS splits some
    products across its threads, whose number defaults to the machine's core count (Ray
    workers: 1), and the order of the partial sums changes the last bits, which a simulated
    episode amplifies into other demos. On one thread, the data do not depend on the
    machine's core count or the executor."""
    task_spec(backend, task)
    check_robot(backend, robot)
    threadpool_limits(1, user_api="blas")
    if backend == "maniskill":
        return _module(backend).make_env(task, robot, fast_step)
    return _module(backend).make_env(task, robot)


def make_renderer(backend: str, task: str, robot: str, width: int, height: int):
    """A renderer of stored states of ``task`` on ``backend``: ``.frame(state)`` gives an
    (height, width, 3) uint8 RGB image on the CPU, ``.close()``. ManiSkill's renders the Panda
    only (the arm ManiSkill's own task registers)."""
    task_spec(backend, task)
    check_robot(backend, robot)
    if backend == "maniskill":
        if robot != "panda":
            raise InputError(f"render: robot {robot!r}: the maniskill renderer shows panda only")
        from envs.maniskill.render import Renderer
    else:
        from envs.pybullet.render import Renderer
    return Renderer(task, robot, width, height)


@dataclass(frozen=True)
class SourceEpisode:
    """One source demo before recording: its reset seed (D0), the env state before the first
    action (the back end's get_state()), and its actions (T, 7)."""

    seed: int
    initial_state: np.ndarray
    actions: np.ndarray


def source_episodes(
    backend: str,
    env,
    num_demos: int,
    seed: int,
    from_file: str | None,
    work_dir: Path,
) -> tuple[list[SourceEpisode], int, int]:
    """Up to ``num_demos`` source demos on ``env`` from the back end's demonstrator, drawn
    from reset seeds seed, seed + 1, ... (or ``from_file``'s: a robomimic ``.hdf5`` of this
    back end and task, e.g. one the export stage wrote, or a file format of the back end's
    own), how many the demonstrator dropped as failures, and how many seeds it tried (0 for
    a file)."""
    if from_file is not None and Path(from_file).suffix.lower() in (".hdf5", ".hdf"):
        return _robomimic_episodes(backend, env, num_demos, from_file), 0, 0
    return _module(backend).source_episodes(env, num_demos, seed, from_file, work_dir)


def _robomimic_episodes(backend: str, env, num_demos: int, path: str) -> list[SourceEpisode]:
    from mimicgen_pipe.exporters import robomimic

    demos = robomimic.read(path, backend, env.spec.name)[:num_demos]
    width = env.get_state().shape[-1]
    for demo in demos:
        if demo.initial_state.shape[-1] != width:
            raise InputError(
                f"{path}: data/{demo.name}/states has {demo.initial_state.shape[-1]} values per "
                f"step, expected {width} (the {backend} {env.spec.name} state with {env.robot})"
            )
    return [SourceEpisode(d.seed, d.initial_state, d.actions) for d in demos]
