"""The ManiSkill adapter: one CPU env implementing the generator's env protocol."""

from __future__ import annotations

import gc
import os

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from mani_skill.utils.registration import REGISTERED_ENVS, register_env  # noqa: E402
from mani_skill.utils.structs.pose import Pose  # noqa: E402

from mimicgen_pipe.backends import load_task  # noqa: E402
from mimicgen_pipe.backends.maniskill.lean import LeanStep, is_grasping  # noqa: E402
from mimicgen_pipe.backends.maniskill.planner import TransitPlanner  # noqa: E402
from mimicgen_pipe.backends.maniskill.tasks import CONTROL, ROBOTS, ManiSkillTask  # noqa: E402
from mimicgen_pipe.core import poses  # noqa: E402
from mimicgen_pipe.core.contracts import StateLayout  # noqa: E402
from mimicgen_pipe.core.controller import (  # noqa: E402
    DeltaPoseController,
    actions_to_target_poses,
    target_poses_to_actions,
)
from mimicgen_pipe.core.errors import InputError  # noqa: E402
from mimicgen_pipe.core.reset_variants import sample_planar_poses  # noqa: E402
from mimicgen_pipe.core.taskspec import ResetVariant  # noqa: E402
from mimicgen_pipe.core.transit import PlannerSettings  # noqa: E402


def draw_planar(
    variant: ResetVariant, objects: tuple[str, ...], n: int, base_xy: tuple[float, float]
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Planar initial poses of ``objects`` for ``n`` parallel scenes drawn from ``variant``
    (mimicgen_pipe.core.reset_variants.sample_planar_poses, every position then every yaw): per
    object (n, 2) world x, y [m] and (n,) yaw [rad], float32, from torch's generator, which
    ManiSkill seeds per episode; ``base_xy``: the robot base [m], for the reach cut."""
    return sample_planar_poses(
        variant, objects, base_xy, lambda shape: torch.rand(shape).numpy(), n
    )


def set_planar_poses(actors, xys: list, yaws: list, heights: list) -> None:
    """Put each actor at its (n, 2) x, y and height [m] (a number or (n,); world), turned by
    its (n,) yaw [rad] about world z."""
    for actor, xy, yaw, z in zip(actors, xys, yaws, heights, strict=True):
        xy, yaw = torch.as_tensor(xy), torch.as_tensor(yaw)
        xyz = torch.zeros(len(xy), 3)
        xyz[:, :2], xyz[:, 2] = xy, z
        q = torch.zeros(len(xy), 4)
        q[:, 0], q[:, 3] = torch.cos(yaw / 2), torch.sin(yaw / 2)
        actor.set_pose(Pose.create_from_pq(p=xyz, q=q))


def redraw_planar(env, env_idx: torch.Tensor, variant: ResetVariant) -> None:
    """A variant's scene the common way: ManiSkill's own reset of the task (table, robot,
    goals), then every object of the task redrawn from ``variant`` (draw_planar) at the
    height the task's reset gave it, turned by the drawn yaw about world z."""
    env.native_initialize(env_idx)
    task = env.task
    xys, yaws = draw_planar(variant, task.spec.objects, len(env_idx), task.robot_base_xy)
    actors = [getattr(env, task.objects[o]) for o in task.spec.objects]
    set_planar_poses(actors, xys, yaws, [a.pose.p[:, 2].clone() for a in actors])


class VariantResets:
    """Mixed into a ManiSkill task env: ``reset(options={"variant": "D1"})`` draws the scene
    from the task's variant; ManiSkill's own reset for a native one (D0)."""

    task: ManiSkillTask
    variant = "D0"

    def reset(self, seed=None, options=None):
        options = dict(options or {})
        self.variant = options.pop("variant", self.variant)
        return super().reset(seed=seed, options=options)

    def _load_scene(self, options: dict):
        super()._load_scene(options)
        if self.task.load_scene is not None:
            self.task.load_scene(self)

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        variants = self.task.spec.reset_variants
        if self.variant not in variants:
            raise ValueError(f"unknown variant {self.variant}")
        if variants[self.variant].native:
            return super()._initialize_episode(env_idx, options)
        with torch.device(self.device):
            (self.task.initialize or redraw_planar)(self, env_idx, variants[self.variant])

    def evaluate(self) -> dict:
        """ManiSkill's evaluation; for a task with a scene or a success test of its own
        (``task_success``), its success is the task's (``task.evaluate``), not the base
        env's task's."""
        info = super().evaluate()
        if self.task.task_success:
            info["success"] = torch.tensor([self.task.evaluate(self)["success"]])
        return info

    def native_initialize(self, env_idx: torch.Tensor, options: dict | None = None) -> None:
        """ManiSkill's own _initialize_episode of the task."""
        super()._initialize_episode(env_idx, options or {})


_VARIANT_CLASSES: dict[str, type] = {}


def variant_env_class(task: ManiSkillTask) -> type:
    """ManiSkill's env class of ``task`` with the reset variants, registered (once per
    process) as ``task.env_id``."""
    if task.env_id not in _VARIANT_CLASSES:
        base = REGISTERED_ENVS[task.base_env_id].cls
        body = {"task": task, **task.env_attributes}
        cls = type(f"MimicGen{base.__name__}", (VariantResets, base), body)
        register_env(task.env_id, max_episode_steps=task.spec.horizon)(cls)
        _VARIANT_CLASSES[task.env_id] = cls
    return _VARIANT_CLASSES[task.env_id]


def _pose_of(raw_pose: torch.Tensor) -> np.ndarray:
    pq = raw_pose[0].numpy().astype(np.float64)
    return poses.pose_from_pq(pq[:3], pq[3:])


def _matrix(pose) -> np.ndarray:
    """A sapien.Pose as a 4x4 matrix."""
    return poses.pose_from_pq(np.asarray(pose.p, np.float64), np.asarray(pose.q, np.float64))


_ZERO3 = np.zeros(3, np.float32)


def make_gym_env(env_id: str, task: ManiSkillTask, sim_backend: str = "physx_cpu", **kwargs):
    """ManiSkill's env ``env_id`` of ``task`` as every env here makes it: state only, no
    reward or rendering, pd_ee_delta_pose, on ``sim_backend``, with the task's env_kwargs
    and ``kwargs`` (robot_uids, num_envs)."""
    return gym.make(
        env_id,
        obs_mode="none",
        reward_mode="none",
        control_mode=ManiSkillEnv.control_mode,
        sim_backend=sim_backend,
        render_backend="none",
        **kwargs,
        **task.env_kwargs,
    )


class ManiSkillEnv:
    """One CPU ManiSkill env (physx_cpu, no rendering, state only, pd_ee_delta_pose).

    lean_step: step with the lean control step (mimicgen_pipe/backends/maniskill/lean.py: the same
    simulation, bit for bit, without ManiSkill's per-step bookkeeping) and read the task's signals
    and success from its ``evaluate`` when asked; False: ManiSkill's own ``env.step`` and
    ``evaluate()``.

    Poses are 4x4 in the world frame. Actions are ManiSkill's normalised pd_ee_delta_pose
    actions: translation 0.1 m per unit in the robot root frame, rotation as Euler "XYZ"
    angles of -0.1 rad per unit (ManiSkill inverts the sign), gripper +1 open / -1 closed.
    """

    backend = "maniskill"
    control_mode, control_freq = CONTROL
    # robot name -> ManiSkill agent uid; another arm's env
    # (mimicgen_pipe/backends/maniskill/xarm6.py) swaps in its own, and its own env_id_for
    agent_uids = {r: r for r in ROBOTS}

    @staticmethod
    def env_id_for(task: ManiSkillTask) -> str:
        """The registered env id of ``task`` (with the reset variants) for this arm."""
        variant_env_class(task)  # registers it
        return task.env_id

    @classmethod
    def agent_uid_for(cls, task: ManiSkillTask, robot: str) -> str:
        """ManiSkill's agent uid of ``robot`` in ``task`` (the task's own for the Panda)."""
        return task.panda_uid if robot == "panda" else cls.agent_uids[robot]

    def __init__(self, task: str = "stack_cube", robot: str = "panda", lean_step: bool = True):
        if robot not in self.agent_uids:
            known = ", ".join(self.agent_uids)
            raise InputError(f"robot {robot!r}: unknown for maniskill (known: {known})")
        self.task = load_task("maniskill", task)
        self.spec = self.task.spec
        self.robot = robot
        self.lean_step = lean_step
        self.agent_uid = self.agent_uid_for(self.task, robot)
        self._env = make_gym_env(self.env_id_for(self.task), self.task, robot_uids=self.agent_uid)
        self.unwrapped = self._env.unwrapped
        self._u = self.unwrapped
        if self._u.reconfiguration_freq:
            # the simulator objects held below would go stale at every reset, and a stored
            # state would not carry what the rebuild drew
            raise InputError(
                f"task {task}: {self.task.base_env_id} rebuilds its scene every "
                f"{self._u.reconfiguration_freq} resets; give it env_kwargs "
                "reconfiguration_freq 0 in its task file"
            )
        arm = self._u.agent.controller.controllers["arm"].config
        self.control_freq = int(self._u.control_freq)
        self.controller = DeltaPoseController(
            pos_scale=float(arm.pos_upper),
            rot_scale=float(arm.rot_lower),
            rot_repr="euler_xyz",
            root_pose=_pose_of(self._u.agent.robot.pose.raw_pose),
        )
        self._info: dict | None = None  # the task's evaluation, made when first asked
        self._scene: int | None = None  # the scene seed of a variant with its own objects
        self._eef: np.ndarray | None = None  # cached until the next step/reset/set_state
        self._objects: dict[str, np.ndarray] | None = None
        # the task's frames in ManiSkill's creation scene (the source demos'), then the
        # correction of each object's pose in a scene where its frame sits elsewhere
        self._source_frames = {n: f(self._u) for n, f in self.task.frames.items()}
        self._frame_fix: dict[str, np.ndarray] = {}
        self._bind()
        self.reset(seed=0, variant="D0")
        # ManiSkill's rebuild (once per block of attempts) ends the old scene with a full
        # gc.collect(), ~0.17 s of its ~0.27 s walking what the imports and the first scene
        # made; frozen, they are skipped, and what later scenes leave is still collected
        gc.freeze()

    # -- protocol -------------------------------------------------------------------------
    def reset(self, seed: int, variant: str) -> None:
        scene = self.task.variant_scene_seeds.get(variant)
        if scene != self._scene:  # a variant with other objects (O1) has its own scene
            self._build(scene)
        self._u.reset(seed=int(seed), options={"variant": variant})
        self._changed()

    def rebuild(self) -> None:
        # PhysX keeps contact caches across plain resets; a reconfigure builds a new scene.
        self._build(self._scene)

    def _build(self, scene: int | None) -> None:
        """Build a new scene from seed ``scene`` (None: the task's rebuild_seed)."""
        seed = self.task.rebuild_seed if scene is None else scene
        self._u.reset(seed=seed, options={"variant": "D0", "reconfigure": True})
        self._scene = scene
        self._bind()
        self._changed()

    def _changed(self, info: dict | None = None) -> None:
        self._info, self._eef, self._objects = info, None, None

    def _evaluation(self) -> dict:
        if self._info is None:
            self._info = self.task.evaluate(self._u) if self._lean else self._u.evaluate()
        return self._info

    def _bind(self) -> None:
        """Hold the simulator objects read on every step (a reconfigure replaces them).
        ManiSkill's get_state() goes through batched torch structures (~0.1 ms per call); the
        same values read straight from SAPIEN, in get_state_dict()'s order, cost a tenth."""
        u = self._u
        self._tcp = u.agent.tcp._objs[0]
        self._actors = {n: getattr(u, a)._objs[0] for n, a in self.task.objects.items()}
        self._frame_fix = {}
        for name, frame in self.task.frames.items():
            here, source = frame(u), self._source_frames[name]
            if not np.array_equal(here, source):  # the source scene's poses stay as read
                self._frame_fix[name] = here @ poses.pose_inv(source)
        self._state_actors = []
        # the registry get_state_dict() reads (it also holds actors merged across parallel
        # scenes, e.g. PegInsertionSide's peg, which scene.actors does not)
        registry = u.scene.state_dict_registry
        for name in u.get_state_dict()["actors"]:
            actor = registry.actors[name]
            body = actor._bodies[0] if actor.px_body_type == "dynamic" else None
            self._state_actors.append((actor._objs[0], body))
        self._state_arts = [
            registry.articulations[n]._objs[0] for n in u.get_state_dict()["articulations"]
        ]
        robot = u.agent.robot
        self._robot = robot._objs[0]
        self._finger_index = [
            robot.active_joints.index(j) for j in robot.active_joints if "finger" in j.name
        ]
        self._lean = LeanStep(u) if self.lean_step else None
        self._planner: TransitPlanner | None = None  # built when first asked, per scene
        self._layout = self._state_layout()

    def _state_layout(self) -> StateLayout | None:
        """Where get_state() holds each object's pose and the fingers' positions: an actor's
        13 entries start with its position and quaternion, an articulation's 13 root entries
        precede its qpos and qvel. None where an object is not one of the state's actors."""
        entities = [entity for entity, _ in self._state_actors]
        objects = {}
        for name, actor in self._actors.items():
            found = [i for i, e in enumerate(entities) if e is actor]
            if not found:
                return None
            objects[name] = 13 * found[0]
        start = 13 * len(entities)
        for art in self._state_arts:
            if art is self._robot:
                fingers = tuple(start + 13 + i for i in self._finger_index)
                return StateLayout(objects, dict(self._frame_fix), fingers)
            start += 13 + 2 * len(art.qpos)
        return None

    def step(self, action: np.ndarray) -> None:
        if self._lean:
            self._lean.step(action)
            self._changed()
        else:
            self._changed(self._u.step(np.asarray(action, dtype=np.float32))[4])

    def eef_pose(self) -> np.ndarray:
        if self._eef is None:
            self._eef = _matrix(self._tcp.entity_pose)
        return self._eef

    def object_poses(self) -> dict[str, np.ndarray]:
        if self._objects is None:
            self._objects = {name: _matrix(a.pose) for name, a in self._actors.items()}
            for name, fix in self._frame_fix.items():
                self._objects[name] = self._objects[name] @ fix
        return self._objects

    def gripper_state(self) -> np.ndarray:
        return np.asarray(self._robot.qpos, np.float64)[self._finger_index]

    def subtask_signals(self) -> dict[str, bool]:
        info = self._evaluation()
        if self._lean:
            return {k: v for k, v in info.items() if k != "success"}
        return {name: bool(v) for name, v in self.task.signals(self._u, info).items()}

    def is_success(self) -> bool:
        return bool(self._evaluation()["success"])

    def get_state(self) -> np.ndarray:
        parts = []
        for entity, body in self._state_actors:
            pose = entity.pose
            vel = (body.linear_velocity, body.angular_velocity) if body else (_ZERO3, _ZERO3)
            parts += [pose.p, pose.q, *vel]
        for art in self._state_arts:
            root = art.root_pose
            parts += [
                root.p,
                root.q,
                art.root_linear_velocity,
                art.root_angular_velocity,
                art.qpos,
                art.qvel,
            ]
        return np.concatenate(parts).astype(np.float32)

    def state_layout(self) -> StateLayout | None:
        return self._layout

    def set_state(self, state: np.ndarray) -> None:
        self._u.set_state(torch.as_tensor(np.asarray(state, dtype=np.float32))[None])
        self._restored()

    def set_state_dict(self, state: dict) -> None:
        """Restore a ManiSkill state dict ({"actors": {...}, "articulations": {...}})."""
        self._u.set_state_dict(state)
        self._restored()

    def _restored(self) -> None:
        if self.task.restore:  # e.g. a goal the task derived from poses at its last reset
            self.task.restore(self._u)
        self._changed()

    def target_pose_to_action(self, target: np.ndarray, gripper: float) -> np.ndarray:
        return target_poses_to_actions(self.eef_pose(), target, gripper, self.controller)

    def action_to_target_pose(self, action: np.ndarray) -> np.ndarray:
        return actions_to_target_poses(self.eef_pose(), action, self.controller)

    def reachable(self, targets: np.ndarray) -> np.ndarray:
        """All True: ManiSkill's controller solves its own IK each step, and a target it
        cannot reach leaves the arm where it is, which shows up as a task failure."""
        return np.ones(len(targets), bool)

    def plan_transit(
        self, target: np.ndarray, settings: PlannerSettings, rng: np.random.Generator
    ) -> tuple[np.ndarray | None, str]:
        """TCP targets (K, 4, 4), world, one per control step, along a collision-free path
        from the TCP's pose now to ``target`` among the scene's actors as they are now, a
        grasped task object carried along (mimicgen_pipe/backends/maniskill/planner.py); or None and
        why there is none."""
        if self._planner is None:
            self._planner = TransitPlanner(self._u)
        actor = {o: getattr(self._u, a) for o, a in self.task.objects.items()}
        objects = {a.name: a for a in actor.values()}
        held = {name: a for name, a in objects.items() if is_grasping(self._u, a)}
        # the arm works on the table and on the objects subtasks refer to: the planner keeps
        # its clearance from everything else
        worked = {n for n in self._u.scene.actors if n.startswith("table")}
        worked |= {actor[s.reference_object].name for s in self.spec.subtasks}
        # the task's objects too: an actor merged across parallel scenes (PegInsertionSide's
        # peg) is not among the scene's actors; and the links of the scene's articulations
        # but the robot (e.g. a cabinet and its drawer)
        links = {
            link.name: link
            for art in self._u.scene.articulations.values()
            if art is not self._u.agent.robot
            for link in art.links
        }
        self._planner.sync(self._u.scene.actors | links | objects, held, worked, settings.clearance)
        return self._planner.plan(target, settings, rng)

    def close(self) -> None:
        self._env.close()
