"""Simulator back ends behind one protocol (mimicgen_pipe.generation.Env).

Simulator packages are imported only when an env is made, so ``task_spec`` and the
library stay importable without them.
"""

from __future__ import annotations

from mimicgen_pipe.errors import InputError
from mimicgen_pipe.taskspec import TaskSpec

BACKENDS = ("maniskill",)


def _module(backend: str):
    if backend == "maniskill":
        from envs import maniskill

        return maniskill
    raise InputError(f"backend {backend!r}: unknown (known: {', '.join(BACKENDS)})")


def task_spec(backend: str, task: str) -> TaskSpec:
    """The task spec of ``task`` on ``backend``; InputError for an unknown name."""
    tasks = _module(backend).TASKS
    if task not in tasks:
        raise InputError(
            f"task {task!r}: unknown for backend {backend} (known: {', '.join(tasks)})"
        )
    return tasks[task].spec


def check_variant(spec: TaskSpec, variant: str) -> None:
    if variant not in spec.reset_bounds:
        raise InputError(
            f"variant {variant!r}: unknown for task {spec.name} (known: {', '.join(spec.variants)})"
        )


def make_env(backend: str, task: str, robot: str = "panda"):
    """A fresh env of ``task`` on ``backend`` that implements the env protocol."""
    task_spec(backend, task)
    return _module(backend).make_env(task, robot)
