"""ManiSkill3 / SAPIEN back end (CPU PhysX, pd_ee_delta_pose); tasks one file each under
mimicgen_pipe/tasks/maniskill/. Imports no simulator: ManiSkill is imported when an env is
made."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from mimicgen_pipe.backends.maniskill.tasks import (
    CONTROL,  # noqa: F401 (the back end's, contracts.Backend)
)
from mimicgen_pipe.backends.maniskill.tasks import ROBOTS as PANDA_ROBOTS
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.registry import choices, load

# the Panda (mimicgen_pipe/backends/maniskill/env.py) and the xArm6 with the Franka hand
# (mimicgen_pipe/backends/maniskill/xarm6.py)
ROBOTS = (*PANDA_ROBOTS, "xarm6")
PLANNER_ROBOTS = (
    "panda",
)  # mimicgen_pipe/backends/maniskill/planner.py plans with the Panda's URDF
# set_state + is_success: 0.43 ms a state (stack_cube, 2 CPU cores); PyBullet's set_state
# rebuilds its scene (125 ms a state), so it does not declare it (contracts.Backend)
RESTORES_CHEAPLY = True


def check_robot(robot: str) -> None:
    if robot not in ROBOTS:
        raise InputError(f"robot {robot!r}: unknown for maniskill (known: {', '.join(ROBOTS)})")


def cameras(robot: str) -> tuple[str, ...]:
    """The Panda's (mimicgen_pipe/backends/maniskill/render.py renders the Panda only)."""
    from mimicgen_pipe.backends import CAMERAS

    check_robot(robot)
    return CAMERAS if robot == "panda" else ()


def task_names() -> tuple[str, ...]:
    return choices("mimicgen_pipe.tasks.maniskill")


def load_task(name: str):
    """The ManiSkillTask ``TASK`` of mimicgen_pipe/tasks/maniskill/<name>.py."""
    return load("mimicgen_pipe.tasks.maniskill", name).TASK


def make_env(task: str, robot: str = "panda", lean_step: bool = True):
    if load_task(task).arm_agents:
        from mimicgen_pipe.backends.maniskill.two_arm import TwoArmManiSkillEnv

        return TwoArmManiSkillEnv(task, robot, lean_step)
    if robot == "xarm6":
        from mimicgen_pipe.backends.maniskill.xarm6 import XArm6ManiSkillEnv

        return XArm6ManiSkillEnv(task, robot, lean_step)
    from mimicgen_pipe.backends.maniskill.env import ManiSkillEnv

    return ManiSkillEnv(task, robot, lean_step)


def make_renderer(task: str, robot: str, width: int, height: int, cameras: Sequence[str]):
    """mimicgen_pipe/backends/maniskill/render.py's Renderer (SAPIEN's CPU renderer)."""
    from mimicgen_pipe.backends.maniskill.render import Renderer

    return Renderer(task, robot, width, height, cameras)


def check_batched(task: str, robot: str, num_envs: int, sim_backend: str | None) -> None:
    """InputError for a batch ManiSkill cannot run (mimicgen_pipe/backends/maniskill/batch.py)."""
    from mimicgen_pipe.backends.maniskill.batch import check_batched

    check_robot(robot)
    if robot != "panda":
        raise InputError(f"robot {robot!r}: the batched ManiSkill form has the Panda only")
    check_batched(load_task(task), sim_backend or "physx_cpu", num_envs)


def make_batch(task: str, robot: str, num_envs: int, sim_backend: str | None):
    from mimicgen_pipe.backends.maniskill.batch import ManiSkillBatch

    return ManiSkillBatch(task, num_envs, sim_backend or "physx_cpu", robot)


def source_episodes(env, num_demos: int, seed: int, from_file: str | None, work_dir: Path):
    if hasattr(env, "demonstrate"):  # a task with its own scripted demonstrator on its env
        return scripted_episodes(env, num_demos, seed, from_file)
    from mimicgen_pipe.backends.maniskill import source

    return source.source_episodes(env, num_demos, seed, from_file, work_dir)


def source_file_episodes(path: str, task: str) -> int:
    """The number of episodes of a ManiSkill trajectory file (``.h5`` with its ``.json``),
    read and checked whole (mimicgen_pipe/backends/maniskill/source.py)."""
    from mimicgen_pipe.backends.maniskill.source import read_trajectory_file

    return len(read_trajectory_file(path, task))


def scripted_episodes(env, num_demos: int, seed: int, from_file: str | None):
    """Up to ``num_demos`` demos of ``env.demonstrate`` from reset seeds seed, seed + 1, ...
    (at most 10 per demo wanted), the seeds it failed on, and the seeds tried."""
    from mimicgen_pipe.core.contracts import SourceEpisode

    if from_file is not None:
        raise InputError(f"source.from_file: task {env.spec.name} records its own demos only")
    out, tried = [], 0
    while len(out) < num_demos and tried < 10 * num_demos:
        s = seed + tried
        tried += 1
        env.reset(s, "D0")
        state = env.get_state()
        actions = env.demonstrate(s)
        if actions is not None:
            out.append(SourceEpisode(s, state, actions))
    return out, tried - len(out), tried
