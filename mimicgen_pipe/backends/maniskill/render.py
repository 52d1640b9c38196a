"""Rendering stored ManiSkill states on the CPU (SAPIEN's renderer on lavapipe): the render
stage's video view and the observation cameras (mimicgen_pipe.backends.CAMERAS, placed by
mimicgen_pipe/core/cameras.py)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mimicgen_pipe.core import poses
from mimicgen_pipe.core.cameras import (
    AGENTVIEW_EYE,
    AGENTVIEW_FOV,
    AGENTVIEW_TARGET,
    VIDEO,
    WRIST_FORWARD,
    WRIST_FOV,
    WRIST_POS,
    WRIST_UP,
    CameraRenderer,
)
from mimicgen_pipe.core.errors import InputError

# the render stage's view: the whole arm and the workspace, closer than ManiSkill's default
EYE, TARGET, FOV = (0.3, 0.55, 0.65), (-0.3, 0.0, 0.1), 1.0
# SAPIEN's cheapest shader; "default" gives the same colours to within one level at 3x the
# picture size (float32), and costs more per frame (benchmarks/observe.py)
SHADER = "minimal"


class Renderer(CameraRenderer):
    """Images of flat states (ManiSkillEnv.get_state() layout) of ``task`` with ``robot`` (the
    Panda only) from ``cameras``: ``video`` (the render stage's view) and those of CAMERAS,
    each (height, width, 3) uint8 RGB. A second env of the same task, built with a renderer,
    that is only ever set, never stepped; all cameras see one scene update per state.
    ``shader``: SAPIEN's shader pack of the observation cameras."""

    def __init__(
        self,
        task: str,
        robot: str,
        width: int,
        height: int,
        cameras: Sequence[str] = (VIDEO,),
        shader: str = SHADER,
    ) -> None:
        if robot != "panda":  # the arm ManiSkill's own task registers
            raise InputError(f"render: robot {robot!r}: the maniskill renderer shows panda only")
        super().__init__(cameras)
        import gymnasium as gym
        import torch
        from mani_skill.utils import sapien_utils

        from mimicgen_pipe.backends import load_task
        from mimicgen_pipe.backends.maniskill.env import ManiSkillEnv

        self._torch = torch
        task = load_task("maniskill", task)
        # a task of several arms keeps ManiSkill's own agents
        # (mimicgen_pipe/backends/maniskill/two_arm.py)
        agents = {} if task.arm_agents else {"robot_uids": ManiSkillEnv.agent_uid_for(task, robot)}
        self._env = gym.make(
            ManiSkillEnv.env_id_for(task),
            obs_mode="none",
            reward_mode="none",
            control_mode=ManiSkillEnv.control_mode,
            sim_backend="physx_cpu",
            render_backend="cpu",
            render_mode="rgb_array",
            **agents,
            **task.env_kwargs,
            human_render_camera_configs={
                "width": width, "height": height, "fov": FOV,
                "pose": sapien_utils.look_at(*map(list, task.video_view or (EYE, TARGET))),
            },
        )  # fmt: skip
        self._env.reset(seed=0)  # gym renders only after a reset
        u = self._env.unwrapped
        self._scene = u.scene
        made = {VIDEO: next(iter(u.scene.human_render_cameras.values()))}
        for name in self.cameras:
            if name != VIDEO:
                made[name] = self._camera(u, name, width, height, shader)
        # SAPIEN's own cameras: reading their pictures directly skips ManiSkill's batched
        # torch wrapping of each image
        self._render_cameras = {n: made[n].camera._render_cameras[0] for n in self.cameras}
        self._float = {n: made[n].config.shader_pack != "minimal" for n in self.cameras}

    @staticmethod
    def _camera(u, name: str, width: int, height: int, shader: str):
        """ManiSkill camera ``name`` of CAMERAS in the env ``u``'s scene."""
        from mani_skill.sensors.camera import Camera, CameraConfig
        from mani_skill.utils import sapien_utils
        from mani_skill.utils.structs.pose import Pose

        if name == "agentview":
            pose = sapien_utils.look_at(list(AGENTVIEW_EYE), list(AGENTVIEW_TARGET))
            config = CameraConfig(name, pose, width, height, AGENTVIEW_FOV, 0.01, 100)
        else:
            # SAPIEN's camera frame: x forward, y left, z up
            left = np.cross(WRIST_UP, WRIST_FORWARD)
            rot = np.stack([WRIST_FORWARD, left, WRIST_UP], axis=1)
            q = poses.matrix_to_quat_wxyz(rot)
            pose = Pose.create_from_pq(p=WRIST_POS.tolist(), q=q.tolist())
            hand = u.agent.robot.links_map["panda_hand"]
            config = CameraConfig(name, pose, width, height, WRIST_FOV, 0.01, 100, mount=hand)
        config.shader_pack, config.shader_config = shader, None
        config.__post_init__()  # the shader pack's config
        return Camera(config, u.scene)

    def _set_scene(self, state: np.ndarray) -> None:
        self._env.unwrapped.set_state(self._torch.as_tensor(np.asarray(state, np.float32))[None])
        self._scene.update_render(update_sensors=False, update_human_render_cameras=True)

    def _picture(self, camera: str) -> np.ndarray:
        render_camera = self._render_cameras[camera]
        render_camera.take_picture()
        rgba = render_camera.get_picture("Color")
        if self._float[camera]:  # as ManiSkill converts the default shader's floats
            rgba = (rgba * 255).astype(np.uint8)
        return np.ascontiguousarray(rgba[..., :3])

    def close(self) -> None:
        self._env.close()
