"""ManiSkill3 / SAPIEN back end (CPU PhysX, pd_ee_delta_pose); tasks one file each under
envs/maniskill/tasks/."""

from envs.maniskill import tasks
from envs.maniskill.tasks import ROBOTS as PANDA_ROBOTS
from mimicgen_pipe.errors import InputError

# the Panda (envs/maniskill/env.py) and the xArm6 with the Franka hand (envs/maniskill/xarm6.py)
ROBOTS = (*PANDA_ROBOTS, "xarm6")


def check_robot(robot: str) -> None:
    if robot not in ROBOTS:
        raise InputError(f"robot {robot!r}: unknown for maniskill (known: {', '.join(ROBOTS)})")


def make_env(task: str, robot: str = "panda", fast_step: bool = True):
    if robot == "xarm6":
        from envs.maniskill.xarm6 import XArm6ManiSkillEnv

        return XArm6ManiSkillEnv(task, robot, fast_step)
    from envs.maniskill.env import ManiSkillEnv

    return ManiSkillEnv(task, robot, fast_step)


def source_episodes(env, num_demos, seed, from_file, work_dir):
    from envs.maniskill import source

    return source.source_episodes(env, num_demos, seed, from_file, work_dir)


__all__ = ["ROBOTS", "check_robot", "make_env", "source_episodes", "tasks"]
