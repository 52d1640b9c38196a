"""Rendering stored ManiSkill states on the CPU (SAPIEN's renderer on lavapipe): the render
stage's video view and the observation cameras (mimicgen_pipe.backends.CAMERAS, placed by
mimicgen_pipe/core/cameras.py).

The observation cameras see a lean copy of the scene (:func:`lean_scene`) through a one-pass
Lambert shader (shaders/lambert/). On lavapipe a small picture's time is almost all the
vertices and triangles drawn, not its pixels: the Panda's visual meshes are 136k triangles
(unindexed, 400k vertices) and the ground a 20k-triangle grid, and SAPIEN's minimal shader
inverts a matrix per vertex and samples its environment map per pixel. The lean scene and
shader draw an 84x84 agentview picture ~12x faster and a wrist one ~7x, with the same poses
and fields of view (metrics/benchmarks/render.json, lab/notes/render_speed.md).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mimicgen_pipe.core import poses
from mimicgen_pipe.core.cameras import (
    AGENTVIEW_EYE,
    AGENTVIEW_FOV,
    AGENTVIEW_TARGET,
    VIDEO,
    WRIST_FORWARD,
    WRIST_FOV,
    WRIST_LINK,
    WRIST_POS,
    WRIST_UP,
    CameraRenderer,
)
from mimicgen_pipe.core.errors import InputError

# the render stage's view: the whole arm and the workspace, closer than ManiSkill's default
EYE, TARGET, FOV = (0.3, 0.55, 0.65), (-0.3, 0.0, 0.1), 1.0
# SAPIEN's cheapest shader of its own; "default" gives the same colours to within one level
# at 3x the picture size (float32), and costs more per frame (benchmarks/observe.py)
SHADER = "minimal"
# the lean scene's shader pack: base colour, ambient and directional lights (Lambert), one pass
LEAN_SHADER = str(Path(__file__).parent / "shaders" / "lambert")

# the lean scene's vertex-clustering cells [m] at 84 px (an agentview pixel is ~13 mm at the
# arm), finer in proportion for larger pictures: the arm's links, and the wrist link that the
# eye_in_hand camera looks along from centimetres
LINK_CELL, WRIST_CELL, CELL_PX = 0.015, 0.004, 84
# mesh parts of fewer triangles are kept as they are: cheap already, and small (fingers, marks)
KEEP_TRIANGLES = 1000


class Renderer(CameraRenderer):
    """Images of flat states (ManiSkillEnv.get_state() layout) of ``task`` with ``robot`` (the
    Panda only) from ``cameras``: ``video`` (the render stage's view) and those of CAMERAS,
    each (height, width, 3) uint8 RGB. A second env of the same task, built with a renderer,
    that is only ever set, never stepped; all cameras see one scene update per state.
    ``lean``: the scene made lean (:func:`lean_scene`) and drawn by LEAN_SHADER; by default
    when ``video`` is not among the cameras (the render stage's videos keep every triangle).
    ``shader``: SAPIEN's shader pack (a name, or a directory) of the observation cameras; by
    default LEAN_SHADER when lean, else SHADER. ``lean=False, shader=SHADER`` is the renderer
    before the lean scene, kept for benchmarks/render.py."""

    def __init__(
        self,
        task: str,
        robot: str,
        width: int,
        height: int,
        cameras: Sequence[str] = (VIDEO,),
        shader: str | None = None,
        lean: bool | None = None,
    ) -> None:
        if robot != "panda":  # the arm ManiSkill's own task registers
            raise InputError(f"render: robot {robot!r}: the maniskill renderer shows panda only")
        super().__init__(cameras)
        if lean is None:
            lean = VIDEO not in self.cameras
        if shader is None:
            shader = LEAN_SHADER if lean else SHADER
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
        if lean:
            lean_scene(u, min(1.0, CELL_PX / max(width, height)))

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
        if Path(shader).is_absolute():  # a shader pack's directory, drawing Color alone
            import sapien
            from mani_skill.render.shaders import ShaderConfig

            # ManiSkill sets this global format only for its own packs' cameras
            sapien.render.set_picture_format("Color", "r8g8b8a8unorm")
            config.shader_config = ShaderConfig(shader, texture_names={"Color": ["rgb"]})
        else:
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
        if rgba.dtype != np.uint8:  # as ManiSkill converts the default shader's floats
            rgba = (rgba * 255).astype(np.uint8)
        return np.ascontiguousarray(rgba[..., :3])

    def close(self) -> None:
        self._env.close()


def lean_scene(u: Any, scale: float = 1.0) -> None:
    """The render bodies of the env ``u``'s scene made cheap to draw, where they look the same
    at a camera's pixel: every arm link's mesh parts of KEEP_TRIANGLES or more triangles
    vertex-clustered (:func:`cluster_mesh`) at LINK_CELL, the wrist link's at WRIST_CELL
    (cells times ``scale``), and a flat ground grid (ManiSkill's build_ground, 20k triangles)
    drawn as the one quad it spans (:func:`flat_quad`)."""
    import sapien

    for agent in getattr(u.agent, "agents", [u.agent]):
        for link in agent.robot.links:
            cell = (WRIST_CELL if link.name == WRIST_LINK else LINK_CELL) * scale
            for obj in link._objs:
                _replace_meshes(obj.entity, lambda v, t, n, uv, c=cell: _clustered(v, t, n, c))
    for entity in u.scene.sub_scenes[0].entities:
        if entity.name.endswith("ground") and entity.find_component_by_type(
            sapien.render.RenderBodyComponent
        ):
            _replace_meshes(entity, flat_quad)


# a mesh part's (vertices, triangles, normals, uvs) -> its replacement, or None: kept
Mesh = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
MeshChange = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], Mesh | None]


def _replace_meshes(entity: Any, change: MeshChange) -> None:
    """``entity``'s render body rebuilt with each triangle-mesh part as ``change`` makes it
    (materials, local poses and faces kept); a body no part of which changes is kept."""
    import sapien

    body = entity.find_component_by_type(sapien.render.RenderBodyComponent)
    if body is None:
        return
    shapes, changed = [], False
    for shape in body.render_shapes:
        if not isinstance(shape, sapien.render.RenderShapeTriangleMesh):
            shapes.append(shape.clone())
            continue
        scale = np.asarray(shape.scale, np.float32)
        for part in shape.parts:
            mesh = (part.vertices, part.triangles, part.get_vertex_normal(),
                    part.get_vertex_uv())  # fmt: skip
            new = change(mesh[0] * scale, *mesh[1:])
            changed |= new is not None
            # SAPIEN's shape from a file keeps its scale aside; a new one has it baked in
            v, t, n, uv = new if new is not None else (mesh[0] * scale, *mesh[1:])
            if len(t) == 0:  # a part smaller than a cell
                continue
            made = sapien.render.RenderShapeTriangleMesh(
                v.astype(np.float32), t.astype(np.uint32), n.astype(np.float32),
                uv.astype(np.float32), part.material,
            )  # fmt: skip
            made.local_pose, made.front_face = shape.local_pose, shape.front_face
            shapes.append(made)
    if not changed:
        return
    lean = sapien.render.RenderBodyComponent()
    lean.name = body.name
    for shape in shapes:
        lean.attach(shape)
    entity.remove_component(body)
    entity.add_component(lean)


def _clustered(v: np.ndarray, t: np.ndarray, n: np.ndarray, cell: float) -> Mesh | None:
    """A link's mesh part clustered at ``cell`` (:func:`cluster_mesh`); None: kept."""
    if len(t) < KEEP_TRIANGLES:
        return None
    v, t, n = cluster_mesh(v, t, n, cell)
    return v, t, n, np.zeros((len(v), 2), np.float32)  # the arm's materials have no textures


def cluster_mesh(
    vertices: np.ndarray, triangles: np.ndarray, normals: np.ndarray, cell: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices, triangles, normals) of a mesh simplified by vertex clustering: the vertices
    in one cube of side ``cell`` merged into one at their mean (its normal their normals'
    mean), triangles left with fewer than three corners dropped, each kept once (winding
    kept). The mesh is indexed after, so a vertex is shaded once, not once per triangle."""
    keys = np.floor(np.asarray(vertices, np.float64) / cell).astype(np.int64)
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    count = np.bincount(inverse)[:, None]
    v = np.zeros((len(count), 3))
    np.add.at(v, inverse, vertices)
    nrm = np.zeros((len(count), 3))
    np.add.at(nrm, inverse, normals)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    t = inverse[np.asarray(triangles, np.int64)]
    t = t[(t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 0] != t[:, 2])]
    first = np.argmin(t, axis=1)  # each triangle from its smallest corner, its winding kept
    rows = np.arange(len(t))[:, None]
    t = np.unique(t[rows, (first[:, None] + np.arange(3)) % 3], axis=0)
    return v / count, t, nrm


def flat_quad(v: np.ndarray, t: np.ndarray, n: np.ndarray, uv: np.ndarray) -> Mesh | None:
    """A flat mesh of many triangles as the two triangles of the rectangle its vertices span,
    where it is one: an axis-aligned rectangle in a plane z = const whose normals are +z and
    whose UVs are affine in x, y (so the quad's interpolated UVs are the mesh's, and its
    texture looks the same); None otherwise."""
    if len(t) <= 2 or np.ptp(v[:, 2]) > 1e-6 or not np.allclose(n, [0.0, 0.0, 1.0]):
        return None
    lo, hi = v[:, :2].min(axis=0), v[:, :2].max(axis=0)
    xy1 = np.c_[v[:, :2], np.ones(len(v))]
    affine, *_ = np.linalg.lstsq(xy1, uv, rcond=None)
    if not np.allclose(xy1 @ affine, uv, atol=1e-5):
        return None
    t = np.asarray(t, np.int64)
    signed = np.cross(v[t[:, 1], :2] - v[t[:, 0], :2], v[t[:, 2], :2] - v[t[:, 0], :2])
    if not (np.all(signed > 0) or np.all(signed < 0)):  # one winding, the quad's
        return None
    if not np.isclose(np.abs(signed).sum() / 2, np.prod(hi - lo), rtol=1e-4):  # holes, or
        return None  # not a rectangle
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    quad_uv = np.c_[corners, np.ones(4)] @ affine
    quad = np.c_[corners, np.full(4, v[0, 2])]
    tri = np.array([[0, 1, 2], [0, 2, 3]])  # counter-clockwise seen from +z
    if signed[0] < 0:
        tri = tri[:, ::-1]
    return quad, tri, np.tile([0.0, 0.0, 1.0], (4, 1)), quad_uv
