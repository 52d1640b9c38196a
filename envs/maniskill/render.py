"""Rendering stored ManiSkill states on the CPU (SAPIEN's renderer on lavapipe)."""

from __future__ import annotations

import numpy as np

from mimicgen_pipe.errors import InputError

# a camera that holds the whole arm and the workspace, closer than ManiSkill's default view
EYE, TARGET, FOV = (0.3, 0.55, 0.65), (-0.3, 0.0, 0.1), 1.0


class Renderer:
    """Frames of flat states (ManiSkillEnv.get_state() layout) of ``task`` with ``robot`` (the
    Panda only): a second env of the same task, built with a renderer, that is only ever set,
    never stepped."""

    def __init__(self, task: str, robot: str, width: int, height: int) -> None:
        if robot != "panda":  # the arm ManiSkill's own task registers
            raise InputError(f"render: robot {robot!r}: the maniskill renderer shows panda only")
        import gymnasium as gym
        import torch
        from mani_skill.utils import sapien_utils

        from envs import load_task
        from envs.maniskill.env import ManiSkillEnv

        self._torch = torch
        task = load_task("maniskill", task)
        self._env = gym.make(
            ManiSkillEnv.env_id_for(task),
            obs_mode="none",
            reward_mode="none",
            control_mode=ManiSkillEnv.control_mode,
            sim_backend="physx_cpu",
            render_backend="cpu",
            render_mode="rgb_array",
            robot_uids=ManiSkillEnv.agent_uid_for(task, robot),
            **task.env_kwargs,
            human_render_camera_configs={
                "width": width, "height": height, "fov": FOV,
                "pose": sapien_utils.look_at(list(EYE), list(TARGET)),
            },
        )  # fmt: skip
        self._env.reset(seed=0)  # gym renders only after a reset

    def frame(self, state: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 RGB of the scene in ``state``."""
        self._env.unwrapped.set_state(self._torch.as_tensor(np.asarray(state, np.float32))[None])
        return np.asarray(self._env.render()[0].cpu().numpy(), np.uint8)

    def close(self) -> None:
        self._env.close()
