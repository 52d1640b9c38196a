"""ManiSkill3 / SAPIEN back end (CPU PhysX, pd_ee_delta_pose)."""

from envs.maniskill.tasks import ROBOTS, TASKS
from mimicgen_pipe.errors import InputError


def check_robot(robot: str) -> None:
    if robot not in ROBOTS:
        raise InputError(f"robot {robot!r}: unknown for maniskill (known: {', '.join(ROBOTS)})")


def make_env(task: str, robot: str = "panda"):
    from envs.maniskill.env import ManiSkillEnv

    return ManiSkillEnv(task, robot)


def source_episodes(env, num_demos, seed, from_file, work_dir):
    from envs.maniskill import source

    return source.source_episodes(env, num_demos, seed, from_file, work_dir)


__all__ = ["ROBOTS", "TASKS", "check_robot", "make_env", "source_episodes"]
