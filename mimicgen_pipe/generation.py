"""The MimicGen generation method (paper 3.2, L, M): segment transform, interpolation,
source selection, action noise, and one generation attempt over an env protocol object."""

from __future__ import annotations

from collections.abc import Generator, Mapping
from dataclasses import dataclass
from typing import Protocol, cast

import numpy as np

from mimicgen_pipe import poses
from mimicgen_pipe.controller import clip_actions
from mimicgen_pipe.observations import observation_values
from mimicgen_pipe.pose_noise import PoseNoise, generation_rng, perturb_pose
from mimicgen_pipe.registry import load
from mimicgen_pipe.segments import segment_bounds
from mimicgen_pipe.selection import Candidates
from mimicgen_pipe.taskspec import TaskSpec
from mimicgen_pipe.transit import PlannerSettings, approach_start


class Env(Protocol):
    """Everything the generator and the stages call on a simulator back end's env (see
    docs/extending.md, the env protocol); a back end's env implements all of it. All poses are 4x4
    homogeneous transforms in the world frame [m]."""

    spec: TaskSpec  # the task (envs/<backend>/tasks/<task>.py)
    robot: str  # the arm's name, e.g. panda
    control_mode: str  # the action space, e.g. ManiSkill's pd_ee_delta_pose
    control_freq: int  # control steps per second [Hz]

    def reset(self, seed: int, variant: str) -> None:
        """A new scene drawn from reset variant ``variant`` (D0, D1, ...) with ``seed``."""

    def rebuild(self) -> None:
        """Rebuild the scene, dropping whatever the simulator carries between episodes."""

    def eef_pose(self) -> np.ndarray:
        """The end effector's (TCP's) pose, world frame."""

    def object_poses(self) -> dict[str, np.ndarray]:
        """Object name -> pose, world frame, for every object of the task spec."""

    def gripper_state(self) -> np.ndarray:
        """Finger joint positions [m]."""

    def step(self, action: np.ndarray) -> None:
        """One control step of a (7,) delta-pose action: translation, rotation, gripper."""

    def subtask_signals(self) -> dict[str, bool]:
        """Signal name -> value now, for every signal the task's subtasks read."""

    def is_success(self) -> bool: ...

    def get_state(self) -> np.ndarray:
        """The whole simulator state as a flat float32 array (for replay and rendering)."""

    def set_state(self, state: np.ndarray) -> None: ...

    def target_pose_to_action(self, target: np.ndarray, gripper: float) -> np.ndarray:
        """The (7,) action that moves the TCP from where it is to ``target`` (world)."""

    def action_to_target_pose(self, action: np.ndarray) -> np.ndarray:
        """The TCP target (world) that ``action`` commands from where the TCP is."""

    def reachable(self, targets: np.ndarray) -> np.ndarray:
        """(K,) bool: whether the arm has an IK solution for each TCP target (K, 4, 4)."""

    def close(self) -> None: ...


class PlanningEnv(Env, Protocol):
    """An env whose back end has a motion planner (generate.transit: planned)."""

    def plan_transit(
        self, target: np.ndarray, settings: PlannerSettings, rng: np.random.Generator
    ) -> tuple[np.ndarray | None, str]:
        """TCP targets (K, 4, 4), world, one per control step, along a collision-free path
        from the TCP's pose now to ``target``, drawing from ``rng``; or None and why there is
        none."""


def transform_segment(
    target_poses: np.ndarray, src_object_pose: np.ndarray, new_object_pose: np.ndarray
) -> np.ndarray:
    """Re-target a source segment to a new object pose (paper L).

    target_poses: (K, 4, 4) controller targets T_W^C in the world frame.
    src_object_pose / new_object_pose: (4, 4) world poses of the reference object at the start
    of the source segment and in the new scene. Returns T_W^O' (T_W^O)^-1 T_W^C, which keeps
    every target's pose relative to the object.
    """
    return new_object_pose @ poses.pose_inv(src_object_pose) @ target_poses


def interpolation(
    from_pose: np.ndarray, to_pose: np.ndarray, n_interp: int, n_fixed: int
) -> np.ndarray:
    """(n_interp + n_fixed, 4, 4) poses: n_interp poses from ``from_pose`` to ``to_pose``
    inclusive (linear in position, slerp in rotation), then ``to_pose`` held n_fixed times
    (paper M.2)."""
    if n_interp < 0 or n_fixed < 0:
        raise ValueError("n_interp and n_fixed must be >= 0")
    alphas = np.linspace(0.0, 1.0, n_interp) if n_interp > 1 else np.ones(n_interp)
    alphas = np.concatenate([alphas, np.ones(n_fixed)])
    out = np.zeros((len(alphas), 4, 4))
    out[:, :3, 3] = (1 - alphas)[:, None] * from_pose[:3, 3] + alphas[:, None] * to_pose[:3, 3]
    out[:, :3, :3] = poses.slerp_matrix(from_pose[:3, :3], to_pose[:3, :3], alphas)
    out[:, 3, 3] = 1.0
    return out


def pose_distance(candidates: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Paper M.3's distance from each candidate (N, 4, 4) to ``pose`` (4, 4): L2 position
    distance [m] plus the angle [rad] of the relative rotation."""
    dpos = np.linalg.norm(candidates[:, :3, 3] - pose[:3, 3], axis=-1)
    return dpos + poses.rotation_angle(candidates[:, :3, :3], pose[:3, :3])


def draw_nearest(distances: np.ndarray, rng: np.random.Generator, nn_k: int) -> int:
    """Index of one of the ``nn_k`` smallest ``distances`` (N,), drawn uniformly; ties are
    ranked in index order."""
    order = np.argsort(distances, kind="stable")
    return int(order[rng.integers(min(nn_k, len(distances)))])


def select_source(
    strategy: str, candidates: Candidates, rng: np.random.Generator, nn_k: int = 3
) -> int:
    """Index of the source demo to follow (paper M.3), as selection strategy ``strategy``
    (a module of mimicgen_pipe.selection) picks it from ``candidates``."""
    return load("mimicgen_pipe.selection", strategy).select(candidates, rng, nn_k)


def action_noise(sigma: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(K, 6) noise for K actions' translation and rotation, sigma (K,) * N(0, 1) each; a
    (7,) action's gripper gets none (paper M.4). Drawn in one call: the same numbers as K
    draws of one row each."""
    sigma = np.asarray(sigma, dtype=np.float64)
    return sigma[:, None] * rng.standard_normal((len(sigma), 6))


def add_action_noise(action: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """A (7,) action plus ``noise`` (6,) on every dimension but the gripper, as float64."""
    noisy = np.array(action, dtype=np.float64, copy=True)
    noisy[:-1] += noise
    return noisy


@dataclass(frozen=True)
class GenerationConfig:
    """The method's knobs (paper M.6 defaults). selection: a selection strategy, the name of a
    module of mimicgen_pipe.selection. pose_noise: the pose-estimation error on the reference
    object's pose observed at the start of each subtask (paper T). transit: "linear" (paper
    M.2) or "planned" (mimicgen_pipe.transit, with ``planner``'s settings)."""

    action_noise: float = 0.05
    n_interp: int = 5
    n_fixed: int = 0
    selection: str = "random"
    nn_k: int = 3
    per_subtask: bool = False
    pose_noise: PoseNoise = PoseNoise()
    transit: str = "linear"
    planner: PlannerSettings = PlannerSettings()


@dataclass(frozen=True)
class SourceDemos:
    """Parsed source demos, concatenated over episodes.

    target_poses: (S, 4, 4) controller targets, world frame. gripper: (S,) gripper actions.
    object_poses: object name -> (S, 4, 4) world poses observed before each step.
    episode_ends: (N,) cumulative exclusive ends. term_index: (N, M-1) detected subtask ends,
    relative to each episode's start.
    """

    target_poses: np.ndarray
    gripper: np.ndarray
    object_poses: Mapping[str, np.ndarray]
    episode_ends: np.ndarray
    term_index: np.ndarray

    @property
    def episode_starts(self) -> np.ndarray:
        return np.concatenate([[0], self.episode_ends[:-1]])

    @property
    def lengths(self) -> np.ndarray:
        return np.diff(np.concatenate([[0], self.episode_ends]))


@dataclass
class Attempt:
    """One generation attempt: per-step arrays (T, ...) and per-episode fields."""

    seed: int  # the attempt's reset seed
    steps: dict[str, np.ndarray]
    success: bool
    failed_subtask: int  # index of the first subtask not achieved; -1 on success
    ik_failed: bool  # stopped before failed_subtask: the arm cannot reach one of its targets
    source_demo: np.ndarray  # (M,) source demo followed in each subtask
    initial_state: np.ndarray
    initial_object_poses: np.ndarray  # (n_objects, 4, 4) world
    planner_failed: bool = False  # stopped before failed_subtask: no planned transit found


def run_attempt(
    env: Env,
    sources: SourceDemos,
    spec: TaskSpec,
    config: GenerationConfig,
    variant: str,
    seed: int,
) -> Attempt:
    """One generation attempt (paper Fig. 2) on ``env``: :func:`attempt_actions` with every
    action stepped as it comes."""
    actions = attempt_actions(env, sources, spec, config, variant, seed)
    try:
        while True:
            env.step(next(actions))
    except StopIteration as done:
        return done.value


AttemptActions = Generator[np.ndarray, None, Attempt]


def attempt_actions(
    env: Env,
    sources: SourceDemos,
    spec: TaskSpec,
    config: GenerationConfig,
    variant: str,
    seed: int,
) -> AttemptActions:
    """One generation attempt as a coroutine that steps nothing itself: it yields each
    control step's action ((7,) float32) and is resumed once ``env`` has stepped it (alone,
    or as one slot of a batch stepped together, mimicgen_pipe.batched); it returns the
    Attempt.

    The attempt (paper Fig. 2): reset the scene, then for each subtask select a source demo,
    transform its segment to the reference object's current pose, prepend the interpolation
    from the current end-effector pose, and execute it as noisy delta-pose actions. Success
    is the task's success after the last step. An attempt whose next targets the arm cannot
    reach (env.reachable) stops there, as an IK failure of that subtask; with planned
    transit, one whose transit the planner cannot find stops there too, as a planner failure
    of that subtask. Everything drawn (scene, source demos, offsets, noise) comes from
    ``seed`` alone."""
    rng = np.random.default_rng(seed)
    pose_rng = generation_rng(seed)
    env.reset(seed=seed, variant=variant)
    initial_state = env.get_state()
    obj_now = env.object_poses()
    initial_object_poses = np.stack([obj_now[o] for o in spec.objects])
    offsets = [
        int(rng.integers(s.term_offset_range[0], s.term_offset_range[1] + 1))
        for s in spec.subtasks[:-1]
    ]
    starts, lengths = sources.episode_starts, sources.lengths
    bounds = np.stack(
        [
            segment_bounds(sources.term_index[j], offsets, int(lengths[j]))
            for j in range(len(lengths))
        ]
    )  # (N, M, 2)

    recorder = StepRecorder(spec.objects)
    chosen = np.full(len(spec.subtasks), -1, dtype=np.int64)
    reached = np.zeros(len(spec.subtasks), dtype=bool)
    demo = -1
    ik_failed = planner_failed = False
    for i, sub in enumerate(spec.subtasks):
        # the reference object's pose as a pose estimator reports it (paper T); the simulator's
        # true poses are untouched, and they are what gets recorded
        ref_now = perturb_pose(obj_now[sub.reference_object], config.pose_noise, pose_rng)
        if demo < 0 or config.per_subtask:
            seg_starts = starts + bounds[:, i, 0]
            src_objects = sources.object_poses[sub.reference_object][seg_starts]
            candidates = Candidates(
                src_objects,
                ref_now,
                transform_segment(sources.target_poses[seg_starts], src_objects, ref_now),
                env.eef_pose(),
            )
            demo = select_source(config.selection, candidates, rng, config.nn_k)
        chosen[i] = demo
        s, e = starts[demo] + bounds[demo, i]
        seg = transform_segment(
            sources.target_poses[s:e], sources.object_poses[sub.reference_object][s], ref_now
        )
        grip = sources.gripper[s:e]
        if config.transit == "planned":
            k = approach_start(seg, ref_now, config.planner.approach_distance)
            seg, grip = seg[k:], grip[k:]
            path, _ = cast(PlanningEnv, env).plan_transit(seg[0], config.planner, rng)
            if path is None:
                planner_failed = True
                break
            interp = np.concatenate([path, np.repeat(seg[:1], config.n_fixed, axis=0)])
        else:
            interp = interpolation(env.eef_pose(), seg[0], config.n_interp, config.n_fixed)
        targets = np.concatenate([interp, seg])
        grips = np.concatenate([np.full(len(interp), grip[0]), grip])
        if not env.reachable(targets).all():
            ik_failed = True
            break
        sigma = np.full(len(targets), config.action_noise)
        if sub.noise_free_radius is not None:
            near = np.linalg.norm(targets[:, :3, 3] - ref_now[:3, 3], axis=-1)
            sigma[near <= sub.noise_free_radius] = 0.0
        noise = action_noise(sigma, rng)
        for k in range(len(targets)):
            eef = env.eef_pose()
            action = add_action_noise(env.target_pose_to_action(targets[k], grips[k]), noise[k])
            action = clip_actions(action).astype(np.float32)
            sig = recorder.record(env, eef, obj_now, action, targets[k])
            if sub.term_signal is not None and sig[sub.term_signal]:
                reached[i] = True
            yield action
            obj_now = env.object_poses()
        if sub.term_signal is not None and env.subtask_signals()[sub.term_signal]:
            reached[i] = True
    success = not (ik_failed or planner_failed) and bool(env.is_success())
    reached[-1] = success
    failed = -1 if success else int(np.argmin(reached))
    steps = recorder.arrays()
    return Attempt(
        seed,
        steps,
        success,
        failed,
        ik_failed,
        chosen,
        initial_state,
        initial_object_poses,
        planner_failed,
    )


def reachable_scenes(
    env: Env, sources: SourceDemos, spec: TaskSpec, variant: str, seeds: list[int]
) -> int:
    """How many of the scenes reset from ``seeds`` the arm can work in: every target of the
    first source demo's segments, moved to the scene's initial object poses, has an IK
    solution. A cheap check of a robot's workspace before generating."""
    bounds = segment_bounds(
        sources.term_index[0], [0] * (len(spec.subtasks) - 1), int(sources.lengths[0])
    )
    start = int(sources.episode_starts[0])
    ok = 0
    for seed in seeds:
        env.reset(seed=seed, variant=variant)
        obj = env.object_poses()
        targets = [
            transform_segment(
                sources.target_poses[start + b0 : start + b1],
                sources.object_poses[sub.reference_object][start + b0],
                obj[sub.reference_object],
            )
            for sub, (b0, b1) in zip(spec.subtasks, bounds, strict=True)
        ]
        ok += bool(env.reachable(np.concatenate(targets)).all())
    return ok


class StepRecorder:
    """Collects the per-step record of an episode, observed before each step's action:
    actions, eef_pose, target_pose, gripper, env_state, object_poses/<obj>,
    subtask_signals/<name>, and the policy observation obs/<key> (mimicgen_pipe.observations).
    One list per array, its names fixed at the first step.
    """

    def __init__(self, objects: tuple[str, ...]) -> None:
        self.objects = objects
        self.columns: dict[str, list] = {}

    def record(
        self,
        env: Env,
        eef: np.ndarray,
        object_poses: Mapping[str, np.ndarray],
        action: np.ndarray,
        target: np.ndarray,
    ) -> dict[str, bool]:
        """Append one step; returns the subtask signals it recorded."""
        sig = env.subtask_signals()
        obs = observation_values(eef, env.gripper_state(), object_poses, self.objects)
        values = (
            action,
            eef,
            target,
            env.get_state(),
            *(object_poses[o] for o in self.objects),
            *sig.values(),
            *obs.values(),
        )
        if not self.columns:
            names = ("actions", "eef_pose", "target_pose", "env_state")
            names += tuple(f"object_poses/{o}" for o in self.objects)
            names += tuple(f"subtask_signals/{n}" for n in sig)
            names += tuple(f"obs/{k}" for k in obs)
            self.columns = {name: [] for name in names}
        for column, value in zip(self.columns.values(), values, strict=True):
            column.append(value)
        return sig

    def arrays(self) -> dict[str, np.ndarray]:
        out = {
            k: np.asarray(v, np.float32) if k.startswith("obs/") else np.asarray(v)
            for k, v in self.columns.items()
        }
        if "actions" in out:
            out["gripper"] = out["actions"][:, -1].astype(np.float32)
        return out


def replay_actions(
    env: Env, initial_state: np.ndarray, actions: np.ndarray, objects: tuple[str, ...]
) -> tuple[dict[str, np.ndarray], bool]:
    """Restore ``initial_state``, execute ``actions`` (T, 7) and record every step, with the
    controller target each action implies (paper M.1). Returns (steps, task success)."""
    env.set_state(initial_state)
    recorder = StepRecorder(objects)
    for action in np.asarray(actions, dtype=np.float32):
        eef = env.eef_pose()
        target = env.action_to_target_pose(action)
        recorder.record(env, eef, env.object_poses(), action, target)
        env.step(action)
    return recorder.arrays(), bool(env.is_success())
