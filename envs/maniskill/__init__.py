"""ManiSkill3 / SAPIEN back end (CPU PhysX, pd_ee_delta_pose)."""

from envs.maniskill.tasks import TASKS


def make_env(task: str, robot: str = "panda"):
    from envs.maniskill.env import ManiSkillEnv

    return ManiSkillEnv(task, robot)


__all__ = ["TASKS", "make_env"]
