"""What the ManiSkill tasks share. Each task is one file under mimicgen_pipe/tasks/maniskill/
(``<task>.py`` defines ``TASK``, a ManiSkillTask), found by name (mimicgen_pipe.backends.load_task).
Free of simulator imports: a task file imports ManiSkill only inside its functions.

World frame: ManiSkill's, the table top is z = 0 with its centre at the origin; the Panda's
base is at ``task.robot_base_xy``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from mimicgen_pipe.core.taskspec import TaskSpec

FULL_YAW = (0.0, 2 * math.pi)
PANDA_BASE_XY = (-0.615, 0.0)  # where ManiSkill's table-top tasks put the Panda
# [m] horizontally from the base: beyond ~0.78 m the Panda cannot reach the table top-down
PANDA_REACH = 0.76
ROBOTS = ("panda",)
CONTROL = ("pd_ee_delta_pose", 20)  # every arm's controller here, and its rate [Hz]
CREATION_SEED = 2022  # the seed ManiSkill builds every env's scene with at creation


def cube_on_cube_signals(env, info: dict) -> dict[str, Any]:
    """StackCube-v1's subtask signals from its ``evaluate()`` info (cube A on cube B), one
    per scene."""
    return {"grasp_cubeA": info["is_cubeA_grasped"], "cubeA_on_cubeB": info["is_cubeA_on_cubeB"]}


def cube_on_cube_evaluate(env) -> dict[str, bool]:
    """StackCube-v1's signals and success read straight from SAPIEN (the lean step's)."""
    import numpy as np

    from mimicgen_pipe.backends.maniskill.lean import is_grasping, is_static, pose

    f32 = np.float32
    offset = pose(env.cubeA)[0] - pose(env.cubeB)[0]
    half = env.cube_half_size.numpy()
    on = bool(
        np.linalg.norm(offset[:2]) <= np.linalg.norm(half[:2]) + f32(0.005)
        and abs(offset[2] - half[2] * 2) <= f32(0.005)
    )
    grasped = is_grasping(env, env.cubeA)
    static = is_static(env.cubeA, lin_thresh=1e-2, ang_thresh=0.5)
    return {"grasp_cubeA": grasped, "cubeA_on_cubeB": on, "success": on and static and not grasped}


@dataclass(frozen=True)
class ManiSkillTask:
    """Everything task-specific on the ManiSkill back end.

    spec: the generator's view. base_env_id: ManiSkill's env id (its planner and its reset
    are ManiSkill's); our env with the reset variants is registered as ``env_id``.
    objects: spec object name -> attribute of the ManiSkill env holding the actor.
    signals: (env, info) -> {signal name: bool}: the subtask signals from ManiSkill's
        ``evaluate()`` info and the unwrapped env (e.g. ``env.agent.is_grasping``): the stock
        step's (``maniskill.lean_step: false``). A batched task gives each signal as a
        (num_envs,) bool tensor, one entry per scene.
    evaluate: env -> {signal name: bool, ..., "success": bool}: the same signals and
        ManiSkill's success, from poses and contacts read straight from SAPIEN
        (mimicgen_pipe/backends/maniskill/lean.py): the lean step's, called only when asked.
    initialize: (env, env_idx, variant) -> None: place the scene for a variant that is not
        ManiSkill's own (variant.native); called in place of ManiSkill's
        ``_initialize_episode``, which it may call as ``env.native_initialize(env_idx)``.
        None: mimicgen_pipe.backends.maniskill.env.redraw_planar (ManiSkill's reset, then every
        object redrawn from the variant).
    robot_base_xy: [m] the Panda's base in the world, for the variants' reach cut.
    planner: the source demonstrator: a key of ManiSkill's motion-planning solutions
        (default: base_env_id), or the task's own function (env, seed) -> the last step's
        result or -1, with the signature and conventions of ManiSkill's solutions (it is
        run on the ``pd_joint_pos`` env, recorded, and converted like them).
    env_kwargs: more keyword arguments of ManiSkill's env, for every env of the task (our
        env, the planner's and so ManiSkill's converter, which rebuilds the planner's).
    panda_uid: ManiSkill's agent for our robot "panda": the Panda, or the same arm with a
        wrist camera ("panda_wristcam", never rendered here) where the task resets only that.
    rebuild_seed: the seed a scene is rebuilt (reconfigured) with; a task that draws its
        objects' geometry when it builds the scene gets the same geometry from the same
        seed. 2022 is the one ManiSkill builds every env with at creation.
    variant_scene_seeds: variant -> the seed its scene is built with instead, for a task
        whose geometry comes from that seed: object transfer (paper F, O1), another object
        under the same source demos.
    load_scene: env -> None: add the task's own actors (e.g. an obstacle) to the scene
        ManiSkill's env builds, each held as an attribute of the env; the task's env then
        has an id of its own (``env_id``).
    restore: env -> None: after a stored state is restored, recompute what the task derives
        from object poses at reset and keeps outside the simulator's state (e.g.
        PlugCharger's goal pose, which its success test reads).
    frames: spec object -> its reference frame in its actor's frame, a 4x4 matrix [m] read
        from the built scene (e.g. peg_insertion's hole in its box), for a frame that moves
        on the actor when the scene is built with another seed (O1). The object's pose is
        then the actor's pose times (this scene's frame) (the source scene's frame)^-1: the
        actor's own pose in the scene the source demos were recorded in (ManiSkill's
        creation scene, seed 2022, which such a task must also rebuild with), and in
        another scene the pose that puts the frame where the source scene's box, say, has
        its hole, so that a segment carried in the object's frame follows the frame.
    batched: the task has a batched form (mimicgen_pipe/backends/maniskill/batch.py,
    generate.num_envs): its
        reset draws every scene it is given, its signals are per scene, and its scene and
        frames are the same in every scene of a batch (no per-build geometry, no frames).
    arm_agents: for a task with two arms (spec.arms), each arm's index among ManiSkill's
        agents (mimicgen_pipe/backends/maniskill/two_arm.py); empty for one arm.
    demonstrator: a two-arm task's scripted demonstrator, (env, seed) -> the actions
        (T, 7 per arm) of one demo on the task's env (TwoArmManiSkillEnv, reset to the seed's
        D0 scene), or None when the demo fails.
    video_view: the render stage's camera, (eye, target) in the world frame [m]; None:
        mimicgen_pipe/backends/maniskill/render.py's view of one arm and its workspace.
    env_attributes: class attributes of ManiSkill's env that the task's env class sets anew,
        for geometry ManiSkill fixes as a class constant (e.g. PegInsertionSide's hole
        clearance ``_clearance`` [m]); the task's env then has an id of its own, and its
        source demos are planned in it.
    own_success: the task's success test (``evaluate``) is not its base env's, for a task
        with another goal in the base env's scene (e.g. stack_tower's tower in
        StackPyramid-v1's cubes); the task's env then has an id of its own, and reports the
        task's success where ManiSkill's env reports its own (a task with ``load_scene``
        always does).
    """

    spec: TaskSpec
    base_env_id: str
    objects: dict[str, str]
    signals: Callable[[Any, dict], dict[str, bool]]
    evaluate: Callable[[Any], dict[str, bool]]
    initialize: Callable[[Any, Any, Any], None] | None = None
    robot_base_xy: tuple[float, float] = PANDA_BASE_XY
    planner: str | Callable[..., Any] | None = None
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    panda_uid: str = "panda"
    rebuild_seed: int = 0
    variant_scene_seeds: dict[str, int] = field(default_factory=dict)
    frames: dict[str, Callable[[Any], Any]] = field(default_factory=dict)
    restore: Callable[[Any], None] | None = None
    load_scene: Callable[[Any], None] | None = None
    batched: bool = False
    arm_agents: dict[str, int] = field(default_factory=dict)
    demonstrator: Callable[[Any, int], Any] | None = None
    video_view: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    env_attributes: dict[str, Any] = field(default_factory=dict)
    own_success: bool = False

    def __post_init__(self) -> None:
        if self.frames and self.rebuild_seed != CREATION_SEED:
            raise ValueError(
                f"task {self.spec.name}: frames are measured against ManiSkill's creation "
                f"scene (seed {CREATION_SEED}); give it rebuild_seed {CREATION_SEED}"
            )

    @property
    def task_success(self) -> bool:
        """Whether the task's env reports the task's success, not its base env's."""
        return self.load_scene is not None or self.own_success

    @property
    def own_env(self) -> bool:
        """Whether the task's env is not its base env's: actors of its own, geometry, or a
        success test."""
        return self.task_success or bool(self.env_attributes)

    @property
    def env_id(self) -> str:
        if self.own_env:
            return f"MimicGen{self.spec.name}-{self.base_env_id}"
        return f"MimicGen{self.base_env_id}"
