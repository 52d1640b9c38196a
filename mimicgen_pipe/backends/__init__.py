"""Simulator back ends behind the contracts of mimicgen_pipe/core/contracts.py: each back end is a
package ``mimicgen_pipe/backends/<backend>/`` implementing ``contracts.Backend``, a choice of the
registry ``mimicgen_pipe.backends`` (mimicgen_pipe.core.registry), its tasks under
mimicgen_pipe/tasks/<backend>/. The functions here choose a back end by name through that registry
and check what is asked of it before any simulator starts. Imports only core: the rest of the
package reaches a back end through these functions and the contracts.
"""

from __future__ import annotations

import types
from collections.abc import Sequence
from pathlib import Path

from threadpoolctl import threadpool_limits

from mimicgen_pipe.core.cameras import (  # noqa: F401  (CAMERAS: mimicgen_pipe.backends.CAMERAS)
    CAMERAS,
    calibration,
)
from mimicgen_pipe.core.contracts import Renderer, SourceEpisode, check_batch_size
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.registry import choices, load
from mimicgen_pipe.core.taskspec import TaskSpec


def backend_package(backend: str) -> types.ModuleType:
    """The back end ``mimicgen_pipe.backends.<backend>``; InputError naming the back ends for
    another name."""
    known = choices("mimicgen_pipe.backends")
    if backend not in known:
        raise InputError(f"backend {backend!r}: unknown (known: {', '.join(known)})")
    return load("mimicgen_pipe.backends", backend)


def task_names(backend: str) -> tuple[str, ...]:
    """The tasks ``backend`` has: the files in mimicgen_pipe/tasks/<backend>/."""
    return backend_package(backend).task_names()


def load_task(backend: str, name: str):
    """The back end's task object (``TASK``) defined in
    mimicgen_pipe/tasks/<backend>/<name>.py; InputError for an unknown name."""
    known = task_names(backend)
    if name not in known:
        raise InputError(
            f"task {name!r}: unknown for backend {backend} (known: {', '.join(known)})"
        )
    task = backend_package(backend).load_task(name)
    if task.spec.name != name:
        raise ValueError(f"mimicgen_pipe/tasks/{backend}/{name}.py defines task {task.spec.name!r}")
    return task


def control(backend: str) -> tuple[str, int]:
    """The controller of ``backend``'s envs and its rate [Hz]: what its stores record as
    control_mode and control_freq."""
    return backend_package(backend).CONTROL


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
    backend_package(backend).check_robot(robot)


def check_transit(backend: str, robot: str, transit: str, arms: int = 1) -> None:
    """InputError for ``transit`` "planned" where ``robot`` on ``backend`` has no motion
    planner (a back end's ``PLANNER_ROBOTS``: the arms it plans for; none when absent), or
    for a task of several ``arms`` (a planner plans for one)."""
    if transit != "planned":
        return
    if arms > 1:
        raise InputError(
            f"generate.transit: planned: the task has {arms} arms and the motion planner plans "
            "for one; use transit: linear"
        )
    arms = getattr(backend_package(backend), "PLANNER_ROBOTS", ())
    if robot not in arms:
        where = (
            f"backend {backend} plans for {', '.join(arms)}"
            if arms
            else f"backend {backend} has no motion planner"
        )
        raise InputError(
            f"generate.transit: planned: no motion planner for robot {robot!r} ({where}); "
            "use transit: linear"
        )


def check_cameras(backend: str, robot: str, cameras, where: str) -> None:
    """InputError naming ``where`` when a camera is not one ``robot`` has on ``backend``."""
    known = backend_package(backend).cameras(robot)
    unknown = [c for c in cameras if c not in known]
    if unknown:
        raise InputError(
            f"{where}: {', '.join(map(repr, unknown))} not a camera of {robot} on {backend} "
            f"(known: {', '.join(known) or 'none'})"
        )


def camera_calibration(cameras: Sequence[str], height: int, width: int) -> dict[str, dict]:
    """Camera -> its calibration for images ``height`` x ``width`` [px]
    (mimicgen_pipe/core/cameras.py's ``calibration``: K [px], its pose in the world or on the
    hand link [m]), the same on every back end: each renders the cameras where
    mimicgen_pipe/core/cameras.py places them."""
    return {c: calibration(c, height, width) for c in cameras}


def make_env(backend: str, task: str, robot: str = "panda", lean_step: bool = True):
    """A fresh env of ``task`` on ``backend`` that implements the env protocol. lean_step
    (maniskill): the lean control step, the same simulation without ManiSkill's per-step
    bookkeeping (mimicgen_pipe/backends/maniskill/lean.py); False: ManiSkill's own ``env.step``.

    It also puts numpy's BLAS on one thread for the rest of the process: OpenBLAS splits some
    products across its threads, whose number defaults to the machine's core count (Ray
    workers: 1), and the order of the partial sums changes the last bits, which a simulated
    episode amplifies into other demos. On one thread, the data do not depend on the
    machine's core count or the executor."""
    task_spec(backend, task)
    check_robot(backend, robot)
    threadpool_limits(1, user_api="blas")
    return backend_package(backend).make_env(task, robot, lean_step)


def make_renderer(
    backend: str,
    task: str,
    robot: str,
    width: int,
    height: int,
    cameras: Sequence[str] = ("video",),
) -> Renderer:
    """A renderer of stored states of ``task`` on ``backend`` (contracts.Renderer), images
    ``width`` x ``height`` [px] from ``cameras``: ``video``, the render stage's view, or
    those of CAMERAS (placed by mimicgen_pipe/core/cameras.py)."""
    task_spec(backend, task)
    check_robot(backend, robot)
    return backend_package(backend).make_renderer(task, robot, width, height, cameras)


def check_batched(
    backend: str, task: str, robot: str, num_envs: int, sim_backend: str | None, transit: str
) -> None:
    """InputError, before any work, unless ``backend`` can step ``num_envs`` scenes of
    ``task`` with ``robot`` together on ``sim_backend`` (its simulation, where it has a
    choice; None where not): a back end without a batched form, a bad batch size, or a
    planned transit (a batch has no planner)."""
    check_batch_size(num_envs)
    package = backend_package(backend)
    if not hasattr(package, "check_batched"):
        raise InputError(
            f"generate.num_envs {num_envs}: backend {backend} has no batched form (its "
            "simulator holds one scene per process); use generate.num_envs 1 and "
            "generate.workers for more processes"
        )
    if transit == "planned":
        raise InputError(
            "generate.transit: planned: a batch of scenes has no motion planner; use "
            "transit: linear, or generate.num_envs 1"
        )
    package.check_batched(task, robot, num_envs, sim_backend)


def make_batch_env(backend: str, task: str, robot: str, num_envs: int, sim_backend: str | None):
    """A fresh batch of ``num_envs`` scenes of ``task`` (mimicgen_pipe.core.contracts.BatchEnv),
    after :func:`check_batched`; numpy's BLAS on one thread, as :func:`make_env`."""
    threadpool_limits(1, user_api="blas")
    return backend_package(backend).make_batch(task, robot, num_envs, sim_backend)


def source_episodes(
    backend: str,
    env,
    num_demos: int,
    seed: int,
    from_file: str | None,
    work_dir: Path,
) -> tuple[list[SourceEpisode], int, int]:
    """Up to ``num_demos`` source demos on ``env`` from the back end's demonstrator, drawn
    from reset seeds seed, seed + 1, ... (or ``from_file``'s, a file format of the back
    end's own), how many the demonstrator dropped as failures, and how many seeds it tried
    (0 for a file)."""
    return backend_package(backend).source_episodes(env, num_demos, seed, from_file, work_dir)


def source_file_episodes(backend: str, path: str, task: str) -> int | None:
    """The number of episodes of ``path``, a source file in ``backend``'s own format, read
    and checked whole (InputError naming the file and key when it is broken); None where
    the back end reads no file format of its own."""
    package = backend_package(backend)
    if not hasattr(package, "source_file_episodes"):
        return None
    return package.source_file_episodes(path, task)
