"""PyBullet back end (headless DIRECT, 20 Hz end-effector delta-pose control); arms from
pybullet_data with the Franka hand (mimicgen_pipe/backends/pybullet/robots.py); tasks one file each
under mimicgen_pipe/tasks/pybullet/."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from mimicgen_pipe.backends.pybullet.robots import CONTROL, ROBOTS, robot_spec, robot_urdf_text
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.registry import choices, load


def check_robot(robot: str) -> None:
    """InputError for an unknown arm or a URDF (arm or hand) that is not on disk."""
    robot_urdf_text(robot_spec(robot))


def cameras(robot: str) -> tuple[str, ...]:
    """Every arm carries the Franka hand, and so the wrist camera."""
    from mimicgen_pipe.backends import CAMERAS

    check_robot(robot)
    return CAMERAS


def task_names() -> tuple[str, ...]:
    return choices("mimicgen_pipe.tasks.pybullet")


def load_task(name: str):
    """The PyBulletTask ``TASK`` of mimicgen_pipe/tasks/pybullet/<name>.py."""
    return load("mimicgen_pipe.tasks.pybullet", name).TASK


def make_env(task: str, robot: str = "panda", lean_step: bool = True):
    """A PyBulletEnv; lean_step is ManiSkill's (PyBullet has one control step)."""
    from mimicgen_pipe.backends.pybullet.env import PyBulletEnv

    return PyBulletEnv(task, robot)


def make_renderer(task: str, robot: str, width: int, height: int, cameras: Sequence[str]):
    """mimicgen_pipe/backends/pybullet/render.py's Renderer (PyBullet's TinyRenderer)."""
    from mimicgen_pipe.backends.pybullet.render import Renderer

    return Renderer(task, robot, width, height, cameras)


def source_episodes(env, num_demos: int, seed: int, from_file: str | None, work_dir: Path):
    """The scripted demonstrator's first ``num_demos`` successful demos from reset seeds
    seed, seed + 1, ... (at most 10 x num_demos tries), the number of failures and the
    seeds tried."""
    from tqdm import tqdm

    from mimicgen_pipe.backends.pybullet.demos import demonstrate
    from mimicgen_pipe.core.contracts import SourceEpisode

    if from_file is not None:
        raise InputError(
            f"source.from_file={from_file!r}: trajectory files are read on the maniskill "
            "back end; pybullet records its source demos with its scripted demonstrator"
        )
    kept, failed, tried = [], 0, 0
    bar = tqdm(total=num_demos, desc=f"source: scripted demos of {env.spec.name}", unit="demo")
    for s in range(seed, seed + 10 * num_demos):
        tried += 1
        demo = demonstrate(env, s)
        if demo.success:
            kept.append(SourceEpisode(s, demo.initial_state, demo.actions))
            bar.update(1)
        else:
            failed += 1
        if len(kept) == num_demos:
            break
    bar.close()
    return kept, failed, tried


__all__ = [
    "CONTROL",
    "ROBOTS",
    "cameras",
    "check_robot",
    "load_task",
    "make_env",
    "make_renderer",
    "source_episodes",
    "task_names",
]
