"""The MimicGen generation method (paper 3.2, L, M): segment transform, interpolation,
source selection, action noise, and one generation attempt over an env protocol object."""

from __future__ import annotations

from collections.abc import Generator, Mapping
from dataclasses import dataclass, replace
from typing import Literal, cast

import numpy as np

from mimicgen_pipe.core import poses
from mimicgen_pipe.core.contracts import ArmEnv, Env, MultiArmEnv, PlanningEnv, StateLayout
from mimicgen_pipe.core.controller import clip_actions
from mimicgen_pipe.core.observations import arms_observation_values, observation_values
from mimicgen_pipe.core.registry import load
from mimicgen_pipe.core.taskspec import ARM, TaskSpec, arm_key
from mimicgen_pipe.core.transit import PlannerSettings, approach_start
from mimicgen_pipe.method.pose_noise import PoseNoise, generation_rng, perturb_pose
from mimicgen_pipe.method.segments import segment_bounds
from mimicgen_pipe.method.selection import Candidates


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
    (a module of mimicgen_pipe.method.selection) picks it from ``candidates``."""
    return load("mimicgen_pipe.method.selection", strategy).select(candidates, rng, nn_k)


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
    module of mimicgen_pipe.method.selection. pose_noise: the pose-estimation error on the reference
    object's pose observed at the start of each subtask (paper T). transit: "linear" (paper
    M.2) or "planned" (mimicgen_pipe.core.transit, with ``planner``'s settings)."""

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

    target_poses: arm -> (S, 4, 4) the arm's controller targets, world frame. gripper: arm ->
    (S,) the arm's gripper actions. A one-arm task's arm is taskspec.ARM.
    object_poses: object name -> (S, 4, 4) world poses observed before each step.
    episode_ends: (N,) cumulative exclusive ends. term_index: (N, K) detected ends of the K
    subtasks with a term signal (every arm's but its last), in the task's subtask order,
    relative to each episode's start.
    """

    target_poses: Mapping[str, np.ndarray]
    gripper: Mapping[str, np.ndarray]
    object_poses: Mapping[str, np.ndarray]
    episode_ends: np.ndarray
    term_index: np.ndarray

    @property
    def episode_starts(self) -> np.ndarray:
        return np.concatenate([[0], self.episode_ends[:-1]])

    @property
    def lengths(self) -> np.ndarray:
        return np.diff(np.concatenate([[0], self.episode_ends]))

    def segment_bounds(self, spec: TaskSpec, offsets: np.ndarray) -> dict[str, np.ndarray]:
        """Arm -> (N, M_arm, 2) [start, end) steps of each demo's segments of the arm's
        subtasks, relative to the demo's start, with ``offsets`` (K,) (one per term signal,
        as term_index's columns) added to the detected ends."""
        out = {}
        for arm in spec.arms:
            cols = spec.term_columns(arm)
            out[arm] = np.stack(
                [
                    segment_bounds(self.term_index[j, cols], offsets[cols], int(n))
                    for j, n in enumerate(self.lengths)
                ]
            )
        return out


@dataclass
class Attempt:
    """One generation attempt: per-step arrays (T, ...) and per-episode fields. Subtasks are
    indexed in the task's order (every arm's, TaskSpec.subtasks)."""

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

# why an attempt stopped before its last subtask: a target the arm cannot reach (IK), or a
# transit the motion planner cannot find
Stop = Literal["ik", "planner"]


@dataclass(frozen=True)
class SourceSegments:
    """Where the source demos' subtask segments lie in one attempt, the attempt's term offsets
    applied. starts: (N,) each demo's first step in the concatenated source arrays. bounds:
    arm -> (N, M_arm, 2) [start, end) steps of the arm's segments, relative to the demo's
    start. order: arm -> its subtasks' indices, in the task's order."""

    sources: SourceDemos
    starts: np.ndarray
    bounds: Mapping[str, np.ndarray]
    order: Mapping[str, tuple[int, ...]]

    def steps(self, arm: str, subtask: int, demo: int) -> np.ndarray:
        """(2,) [start, end) of source demo ``demo``'s segment of ``subtask`` (one of
        ``arm``'s), in the concatenated source arrays."""
        return self.starts[demo] + self.bounds[arm][demo, self.order[arm].index(subtask)]

    def first_steps(self, arm: str, subtask: int) -> np.ndarray:
        """(N,) every source demo's first step of its segment of ``subtask``, in the
        concatenated source arrays."""
        return self.starts + self.bounds[arm][:, self.order[arm].index(subtask), 0]


@dataclass(frozen=True)
class AttemptSetting:
    """What stays fixed through one attempt: the env and each arm's view of it, the task, the
    method's knobs, the source segments, and the task's constraints by subtask index (the
    task's order): ``after[i]``, the subtasks that must end before i starts (sequential);
    ``partner[i]``, the subtask that starts and ends with i (coordinated), both ways."""

    env: Env
    arms: Mapping[str, ArmEnv]
    spec: TaskSpec
    config: GenerationConfig
    segments: SourceSegments
    after: Mapping[int, list[int]]
    partner: Mapping[int, int]


@dataclass(frozen=True)
class ArmPath:
    """One arm's way through one subtask, a row per control step: the transit, then the
    transformed source segment. targets: (K, 4, 4) TCP target poses, world frame [m].
    grips: (K,) gripper commands, as the source demos' actions give them."""

    targets: np.ndarray
    grips: np.ndarray


@dataclass(frozen=True)
class ArmPlan:
    """What one arm executes for subtask ``subtask`` (the task's order): its path's ``targets``
    (K, 4, 4) TCP target poses, world frame [m], and ``grips`` (K,), step-aligned with a
    coordinated partner's, and ``noise`` (K, 6), the action noise on each step's translation
    and rotation."""

    subtask: int
    targets: np.ndarray
    grips: np.ndarray
    noise: np.ndarray


@dataclass(frozen=True)
class ArmState:
    """One arm during an attempt. plan: what it executes, None while it holds; k: the plan's
    next step. hold: the TCP target pose (4, 4), world frame [m], and gripper command it holds,
    where its last plan ended (or, before its first, where it began). done: how many of its
    subtasks have ended. demo: the source demo it follows, -1 before its first subtask."""

    plan: ArmPlan | None = None
    k: int = 0
    hold: tuple[np.ndarray, float] | None = None
    done: int = 0
    demo: int = -1


@dataclass(frozen=True)
class AttemptState:
    """Where an attempt stands. arms: each arm's state, in the task's arm order. Per subtask
    (the task's order): ``chosen``, the source demo it follows (-1: not started), and
    ``started``, the order it started in (M: never). reached: subtasks whose term signal was
    on during their segment; ended: subtasks whose segment has ended. stop: why the attempt
    stopped early, None while it runs on."""

    arms: Mapping[str, ArmState]
    chosen: tuple[int, ...]
    started: tuple[int, ...]
    reached: frozenset[int] = frozenset()
    ended: frozenset[int] = frozenset()
    stop: Stop | None = None

    @property
    def active(self) -> dict[str, int]:
        """Arm -> the subtask it executes, for every arm not holding."""
        return {arm: s.plan.subtask for arm, s in self.arms.items() if s.plan is not None}


def attempt_actions(
    env: Env,
    sources: SourceDemos,
    spec: TaskSpec,
    config: GenerationConfig,
    variant: str,
    seed: int,
) -> AttemptActions:
    """One generation attempt as a coroutine that steps nothing itself: it yields each
    control step's action (float32, 7 per arm) and is resumed once ``env`` has stepped it
    (alone, or as one slot of a batch stepped together, mimicgen_pipe.method.batched); it returns
    the Attempt.

    The attempt (paper Fig. 2): reset the scene, then for each subtask of each arm select a
    source demo, transform its segment to the reference object's current pose, prepend the
    interpolation from the arm's current end-effector pose, and execute it as noisy
    delta-pose actions. Each arm goes through its own subtasks; one whose next subtask must
    wait (a sequential constraint whose first subtask has not ended, or a coordinated
    partner not yet ready) holds its pose. Coordinated subtasks start together, follow one
    source demo selected once, transformed by one observed pose of their shared reference
    object, and end together (the shorter segment holds its last target). Success is the
    task's success after the last step. An attempt whose next targets an arm cannot reach
    (reachable) stops there, as an IK failure of that subtask; with planned transit, one
    whose transit the planner cannot find stops there too, as a planner failure of that
    subtask. Everything drawn (scene, source demos, offsets, noise) comes from ``seed``
    alone, in the order the subtasks start.

    The steps: start_subtasks, where the constraint gate (constraint_gate) lets subtasks
    start and plan_subtask plans each (the reference object's estimated pose, source
    selection, the transformed segment, the transit, the reach check, action noise); then
    execute, one next_action a control step until a plan ends; then attempt_outcome."""
    rng = np.random.default_rng(seed)
    pose_rng = generation_rng(seed)
    env.reset(seed=seed, variant=variant)
    initial_state = env.get_state()
    obj_now = env.object_poses()
    initial_object_poses = np.stack([obj_now[o] for o in spec.objects])
    setting = attempt_setting(env, sources, spec, config, term_offsets(spec, rng))
    n = len(spec.subtasks)
    state = AttemptState(dict.fromkeys(spec.arms, ArmState()), (-1,) * n, (n,) * n)
    recorder = StepRecorder(spec.objects, spec.arms)
    while True:
        state = start_subtasks(setting, state, obj_now, rng, pose_rng)
        if state.stop is not None or not state.active:
            break  # stopped, or every arm has done its subtasks (a checked spec cannot stall)
        state, obj_now = yield from execute(setting, state, recorder)
    success, failed = attempt_outcome(setting, state)
    return Attempt(
        seed,
        recorder.arrays(),
        success,
        failed,
        state.stop == "ik",
        np.array(state.chosen, dtype=np.int64),
        initial_state,
        initial_object_poses,
        state.stop == "planner",
    )


def term_offsets(spec: TaskSpec, rng: np.random.Generator) -> np.ndarray:
    """(K,) the attempt's offsets [control steps] to the detected subtask ends, one per
    subtask with a term signal (TaskSpec.ending_subtasks), each drawn from its subtask's
    term_offset_range."""
    return np.array(
        [
            int(rng.integers(spec.subtasks[i].term_offset_range[0],
                             spec.subtasks[i].term_offset_range[1] + 1))
            for i in spec.ending_subtasks
        ],
        dtype=np.int64,
    )  # fmt: skip


def attempt_setting(
    env: Env, sources: SourceDemos, spec: TaskSpec, config: GenerationConfig, offsets: np.ndarray
) -> AttemptSetting:
    """An attempt's fixed setting on ``env``, with its term ``offsets`` (term_offsets)."""
    segments = SourceSegments(
        sources,
        sources.episode_starts,
        sources.segment_bounds(spec, offsets),
        {arm: spec.arm_indices(arm) for arm in spec.arms},
    )
    after, partner = constraint_maps(spec)
    return AttemptSetting(env, arm_envs(env, spec.arms), spec, config, segments, after, partner)


def start_subtasks(
    setting: AttemptSetting,
    state: AttemptState,
    obj_now: Mapping[str, np.ndarray],
    rng: np.random.Generator,
    pose_rng: np.random.Generator,
) -> AttemptState:
    """Start every subtask the constraint gate lets start now, arm by arm in the task's order
    (a coordinated pair together), each planned from the object poses ``obj_now`` (world
    frame); the first that cannot start stops the attempt."""
    for arm in setting.spec.arms:
        group = constraint_gate(setting, state, arm)
        if group:
            state = plan_subtask(setting, state, group, obj_now, rng, pose_rng)
            if state.stop is not None:
                break
    return state


def next_subtask(setting: AttemptSetting, state: AttemptState, arm: str) -> int | None:
    """The subtask ``arm`` may start now: its next, once it holds and every subtask that must
    end before that one has ended; None otherwise, and once it has done its subtasks."""
    s, order = state.arms[arm], setting.segments.order[arm]
    if s.plan is not None or s.done == len(order):
        return None
    i = order[s.done]
    return i if all(j in state.ended for j in setting.after[i]) else None


def constraint_gate(
    setting: AttemptSetting, state: AttemptState, arm: str
) -> tuple[tuple[str, int], ...]:
    """(arm, subtask) pairs that start now from ``arm``: its next subtask (next_subtask),
    joined by its coordinated partner on the partner's arm, which must be ready too; none
    while either waits (the arm holds its pose)."""
    i = next_subtask(setting, state, arm)
    if i is None:
        return ()
    if i not in setting.partner:
        return ((arm, i),)
    j = setting.partner[i]
    other = setting.spec.subtasks[j].arm
    if next_subtask(setting, state, other) != j:
        return ()
    return ((arm, i), (other, j))


def plan_subtask(
    setting: AttemptSetting,
    state: AttemptState,
    group: tuple[tuple[str, int], ...],
    obj_now: Mapping[str, np.ndarray],
    rng: np.random.Generator,
    pose_rng: np.random.Generator,
) -> AttemptState:
    """Start subtasks ``group`` ((arm, subtask) pairs: one, or a coordinated pair) from the
    object poses ``obj_now`` (world frame): estimate the reference object's pose, select a
    source demo where one is due (paper M.3), then plan each arm's path (its transformed
    segment after a transit, reach-checked) and, all found, execute them with action noise.
    The state with the plans running, or stopped where a path cannot be had."""
    lead_arm, lead = group[0]
    config = setting.config
    ref_pose = estimated_reference_pose(setting, lead, obj_now, pose_rng)
    if state.arms[lead_arm].demo < 0 or config.per_subtask or len(group) > 1:
        demo = select_source_demo(setting, lead_arm, lead, ref_pose, rng)
        arms = {arm: replace(state.arms[arm], demo=demo) for arm, _ in group}
        state = replace(state, arms={**state.arms, **arms})
    paths = []
    for arm, i in group:
        state = subtask_started(state, i, state.arms[arm].demo)
        path = arm_path(setting, arm, i, state.arms[arm].demo, ref_pose, rng)
        if not isinstance(path, ArmPath):
            return replace(state, stop=path)
        paths.append((arm, i, path))
    plans = noisy_plans(setting, paths, ref_pose, rng)
    arms = {arm: replace(state.arms[arm], plan=plan, k=0) for arm, plan in plans.items()}
    return replace(state, arms={**state.arms, **arms})


def estimated_reference_pose(
    setting: AttemptSetting,
    subtask: int,
    obj_now: Mapping[str, np.ndarray],
    pose_rng: np.random.Generator,
) -> np.ndarray:
    """(4, 4) world pose [m] of ``subtask``'s reference object, as a pose estimator reports it
    (paper T): its pose in ``obj_now`` with the attempt's pose noise. The simulator's true
    poses are untouched, and they are what gets recorded."""
    reference = setting.spec.subtasks[subtask].reference_object
    return perturb_pose(obj_now[reference], setting.config.pose_noise, pose_rng)


def select_source_demo(
    setting: AttemptSetting, arm: str, subtask: int, ref_pose: np.ndarray, rng: np.random.Generator
) -> int:
    """The source demo to follow from ``subtask`` (one of ``arm``'s) on, as the selection
    strategy picks it (paper M.3) from every demo's segment of it: the reference object's
    pose at the segment's start, its pose ``ref_pose`` (4, 4) now, the segments' first targets
    transformed to it, and the arm's TCP pose now, all world frame [m]."""
    sources = setting.segments.sources
    first = setting.segments.first_steps(arm, subtask)
    src_objects = sources.object_poses[setting.spec.subtasks[subtask].reference_object][first]
    candidates = Candidates(
        src_objects,
        ref_pose,
        transform_segment(sources.target_poses[arm][first], src_objects, ref_pose),
        setting.arms[arm].eef_pose(),
    )
    return select_source(setting.config.selection, candidates, rng, setting.config.nn_k)


def subtask_started(state: AttemptState, subtask: int, demo: int) -> AttemptState:
    """``state`` with ``subtask`` following source demo ``demo``, started after all that have."""
    chosen = tuple(demo if k == subtask else c for k, c in enumerate(state.chosen))
    count = sum(c >= 0 for c in chosen)
    started = tuple(count if k == subtask else s for k, s in enumerate(state.started))
    return replace(state, chosen=chosen, started=started)


def arm_path(
    setting: AttemptSetting,
    arm: str,
    subtask: int,
    demo: int,
    ref_pose: np.ndarray,
    rng: np.random.Generator,
) -> ArmPath | Stop:
    """``arm``'s path through ``subtask``: source demo ``demo``'s segment transformed to the
    reference object's pose ``ref_pose`` (4, 4), world frame [m] (paper L), after the
    transit to its first target; with planned transit the segment starts at its approach
    (mimicgen_pipe.core.transit.approach_start). "planner" where no transit is found, "ik" where
    the arm cannot reach one of the targets (the reach check)."""
    segment, grips = transformed_segment(setting, arm, subtask, demo, ref_pose)
    if setting.config.transit == "planned":
        k = approach_start(segment, ref_pose, setting.config.planner.approach_distance)
        segment, grips = segment[k:], grips[k:]
    transit = transit_segment(setting, arm, segment[0], rng)
    if transit is None:
        return "planner"
    targets = np.concatenate([transit, segment])
    grips = np.concatenate([np.full(len(transit), grips[0]), grips])
    if not setting.arms[arm].reachable(targets).all():  # the reach check: IK for every target
        return "ik"
    return ArmPath(targets, grips)


def transformed_segment(
    setting: AttemptSetting, arm: str, subtask: int, demo: int, ref_pose: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Source demo ``demo``'s segment of ``subtask`` carried to the reference object's pose
    ``ref_pose`` (4, 4), world frame [m] (paper L): its TCP targets (K, 4, 4), world frame,
    and its gripper commands (K,)."""
    sources = setting.segments.sources
    s, e = setting.segments.steps(arm, subtask, demo)
    src_object = sources.object_poses[setting.spec.subtasks[subtask].reference_object][s]
    targets = transform_segment(sources.target_poses[arm][s:e], src_object, ref_pose)
    return targets, sources.gripper[arm][s:e]


def transit_segment(
    setting: AttemptSetting, arm: str, start: np.ndarray, rng: np.random.Generator
) -> np.ndarray | None:
    """(K, 4, 4) TCP targets, world frame [m], from ``arm``'s TCP now to ``start`` (a
    transformed segment's first target), then ``start`` held n_fixed steps: the interpolation
    segment (paper M.2), or with planned transit the motion planner's path, drawn from
    ``rng``; None where the planner finds none."""
    config = setting.config
    if config.transit != "planned":
        eef = setting.arms[arm].eef_pose()
        return interpolation(eef, start, config.n_interp, config.n_fixed)
    path, _ = cast(PlanningEnv, setting.env).plan_transit(start, config.planner, rng)
    if path is None:
        return None
    return np.concatenate([path, np.repeat(start[None], config.n_fixed, axis=0)])


def noisy_plans(
    setting: AttemptSetting,
    paths: list[tuple[str, int, ArmPath]],
    ref_pose: np.ndarray,
    rng: np.random.Generator,
) -> dict[str, ArmPlan]:
    """Arm -> its plan, from each (arm, subtask, path) of subtasks that start together:
    step-aligned (a coordinated path shorter than its partner's holds its last target), with
    action noise drawn for every step (paper M.4), in ``paths``' order."""
    steps = max(len(p.targets) for _, _, p in paths)
    plans = {}
    for arm, i, path in paths:
        pad = steps - len(path.targets)
        targets = np.concatenate([path.targets, np.repeat(path.targets[-1:], pad, axis=0)])
        grips = np.concatenate([path.grips, np.repeat(path.grips[-1:], pad)])
        radius = setting.spec.subtasks[i].noise_free_radius
        sigma = noise_scales(targets, setting.config.action_noise, radius, ref_pose)
        plans[arm] = ArmPlan(i, targets, grips, action_noise(sigma, rng))
    return plans


def noise_scales(
    targets: np.ndarray, sigma: float, radius: float | None, ref_pose: np.ndarray
) -> np.ndarray:
    """(K,) the action noise's sigma at each of ``targets`` (K, 4, 4), world frame [m]:
    ``sigma``, but 0 within ``radius`` [m] (None: nowhere) of the reference object's estimated
    position (``ref_pose`` (4, 4), world frame)."""
    scales = np.full(len(targets), sigma)
    if radius is not None:
        near = np.linalg.norm(targets[:, :3, 3] - ref_pose[:3, 3], axis=-1)
        scales[near <= radius] = 0.0
    return scales


ExecutedSteps = Generator[np.ndarray, None, tuple[AttemptState, dict[str, np.ndarray]]]


def execute(setting: AttemptSetting, state: AttemptState, recorder: StepRecorder) -> ExecutedSteps:
    """Execute the running plans step by step until one of them ends: record each step
    before its action, yield the action and, once it is stepped, move the plans on. Returns
    the state and the object poses after the last step (world frame), which the next
    subtasks start from; the steps' own object poses the recorder has."""
    env, active = setting.env, state.active
    while True:
        action, eefs, targets, state = next_action(setting, state)
        signals = recorder.record(env, eefs, action, targets, active)
        state = signals_reached(setting, state, active, signals)
        yield action
        state, ended = step_taken(setting, state)
        if ended:
            return state, env.object_poses()


def next_action(
    setting: AttemptSetting, state: AttemptState
) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, np.ndarray], AttemptState]:
    """The next control step's action (float32, 7 per arm, the task's arm order) with each
    arm's TCP pose and target now (arm -> (4, 4), world frame [m]): a running arm's
    delta-pose action toward its plan's next target (paper M.1) plus that step's action
    noise (M.4); a holding arm's toward the pose it holds. Also the state with the pose each
    arm holding for the first time keeps (its TCP pose now, the source demos' first grip)."""
    eefs, targets, parts, held = {}, {}, [], {}
    for arm, a in setting.arms.items():
        eefs[arm] = a.eef_pose()
        s = state.arms[arm]
        if s.plan is None:
            hold = s.hold or (eefs[arm], _first_grip(setting.segments.sources, arm))
            if s.hold is None:
                held[arm] = replace(s, hold=hold)
            targets[arm], grip = hold
            parts.append(clip_actions(a.target_pose_to_action(targets[arm], grip)))
            continue
        targets[arm] = s.plan.targets[s.k]
        action = add_action_noise(a.target_pose_to_action(targets[arm], s.plan.grips[s.k]),
                                  s.plan.noise[s.k])  # fmt: skip
        parts.append(clip_actions(action))
    action = (parts[0] if len(parts) == 1 else np.concatenate(parts)).astype(np.float32)
    if held:
        state = replace(state, arms={**state.arms, **held})
    return action, eefs, targets, state


def signals_reached(
    setting: AttemptSetting,
    state: AttemptState,
    active: Mapping[str, int],
    signals: Mapping[str, bool],
) -> AttemptState:
    """``state`` with each running subtask of ``active`` (arm -> subtask) whose term signal
    is on in ``signals`` reached."""
    on = {
        i
        for i in active.values()
        if (term := setting.spec.subtasks[i].term_signal) is not None and signals[term]
    }
    return replace(state, reached=state.reached | on) if on - state.reached else state


def step_taken(setting: AttemptSetting, state: AttemptState) -> tuple[AttemptState, bool]:
    """After a step: every running plan one step on. A plan past its last step ends its
    subtask (reached when its term signal is on now) and its arm holds the plan's last target
    and grip. Returns the state and whether any plan ended."""
    arms, reached, ended = dict(state.arms), state.reached, state.ended
    for arm, s in state.arms.items():
        if s.plan is None:
            continue
        if s.k + 1 < len(s.plan.targets):
            arms[arm] = replace(s, k=s.k + 1)
            continue
        i = s.plan.subtask
        term = setting.spec.subtasks[i].term_signal
        if term is not None and setting.env.subtask_signals()[term]:
            reached |= {i}
        ended |= {i}
        hold = (s.plan.targets[-1], float(s.plan.grips[-1]))
        arms[arm] = replace(s, plan=None, k=0, hold=hold, done=s.done + 1)
    return replace(state, arms=arms, reached=reached, ended=ended), ended != state.ended


def attempt_outcome(setting: AttemptSetting, state: AttemptState) -> tuple[bool, int]:
    """Whether the attempt succeeded (it ran to its end and the task succeeds now) and the
    subtask it failed (first_failure; -1 on success). Each arm's last subtask counts as
    reached exactly when the attempt succeeded."""
    success = state.stop is None and bool(setting.env.is_success())
    n = len(setting.spec.subtasks)
    reached = np.array([i in state.reached for i in range(n)], dtype=bool)
    final = np.zeros(n, dtype=bool)
    for order in setting.segments.order.values():
        final[order[-1]], reached[order[-1]] = True, success
    failed = -1 if success else first_failure(reached, np.array(state.started), final)
    return success, failed


def first_failure(reached: np.ndarray, started: np.ndarray, final: np.ndarray) -> int:
    """The subtask an unsuccessful attempt is charged with, of those not achieved
    (``reached`` (M,) False): one with a term signal before an arm's final one (``final``),
    then the one that started first (``started``: their order, a subtask never started
    after all that did), then the task's order. With one arm: the first not achieved."""
    return int(min(np.flatnonzero(~reached), key=lambda i: (final[i], started[i], i)))


def _first_grip(sources: SourceDemos, arm: str) -> float:
    """The gripper command an arm holds before its first subtask: the source demos' first."""
    return float(sources.gripper[arm][0])


def constraint_maps(spec: TaskSpec) -> tuple[dict[int, list[int]], dict[int, int]]:
    """Subtask index -> the subtasks that must end before it starts (sequential
    constraints), and subtask index -> its coordinated partner, both ways."""
    index = {(s.arm, s.name): i for i, s in enumerate(spec.subtasks)}
    after: dict[int, list[int]] = {i: [] for i in range(len(spec.subtasks))}
    partner: dict[int, int] = {}
    for c in spec.constraints:
        a, b = index[c.first], index[c.second]
        if c.kind == "sequential":
            after[b].append(a)
        else:
            partner[a], partner[b] = b, a
    return after, partner


def arm_envs(env: Env, arms: tuple[str, ...]) -> dict[str, ArmEnv]:
    """Each of a task's ``arms`` as what moves it: a one-arm env is its own arm; an env of
    several has ``arm(name)``."""
    if len(arms) == 1:
        return {arms[0]: env}
    return {arm: cast(MultiArmEnv, env).arm(arm) for arm in arms}


def reachable_scenes(
    env: Env, sources: SourceDemos, spec: TaskSpec, variant: str, seeds: list[int]
) -> int:
    """How many of the scenes reset from ``seeds`` the arms can work in: every target of the
    first source demo's segments, moved to the scene's initial object poses, has an IK
    solution. A cheap check of a robot's workspace before generating."""
    bounds = sources.segment_bounds(spec, np.zeros(len(spec.ending_subtasks), np.int64))
    start = int(sources.episode_starts[0])
    arms = arm_envs(env, spec.arms)
    ok = 0
    for seed in seeds:
        env.reset(seed=seed, variant=variant)
        obj = env.object_poses()
        fine = True
        for arm, a in arms.items():
            targets = [
                transform_segment(
                    sources.target_poses[arm][start + b0 : start + b1],
                    sources.object_poses[spec.subtasks[i].reference_object][start + b0],
                    obj[spec.subtasks[i].reference_object],
                )
                for i, (b0, b1) in zip(spec.arm_indices(arm), bounds[arm][0], strict=True)
            ]
            fine = fine and bool(a.reachable(np.concatenate(targets)).all())
        ok += fine
    return ok


class StepRecorder:
    """Collects the per-step record of an episode, observed before each step's action:
    actions, eef_pose, target_pose, gripper, env_state, object_poses/<obj>,
    subtask_signals/<name>, and the policy observation obs/<key> (mimicgen_pipe.core.observations).
    With several arms, each arm's eef_pose, target_pose and gripper as ``<key>/<arm>``
    (arm_key) and ``subtask/<arm>``, the subtask it runs (-1: holding). One list per array,
    its names fixed at the first step.

    Per step it reads only what the stores need and no stored state holds: the state itself,
    the end-effector poses (forward kinematics) and the subtask signals (they read contacts,
    which a state does not carry). The object poses, the fingers' positions and from them the
    observation are derived after the episode, all steps at once, from the stored states,
    where the env's state_layout() says where they lie (the same floats, bit for bit); an env
    without one has its poses and fingers read at every step.
    """

    def __init__(self, objects: tuple[str, ...], arms: tuple[str, ...] = (ARM,)) -> None:
        self.objects, self.arms = objects, arms
        self.several = len(arms) > 1
        self.columns: dict[str, list] = {}
        self._layout: StateLayout | None = None  # the env's, found at the first step
        self._arm_envs: tuple[Env, dict[str, ArmEnv]] | None = None  # found once per env

    def record(
        self,
        env: Env,
        eefs: Mapping[str, np.ndarray],
        action: np.ndarray,
        targets: Mapping[str, np.ndarray],
        active: Mapping[str, int] | None = None,
    ) -> dict[str, bool]:
        """Append one step: the arms' end-effector poses and targets (arm -> pose), and with
        several arms each one's subtask (``active``: arm -> subtask index, an arm without
        one holding); returns the subtask signals it recorded."""
        sig = env.subtask_signals()
        if not self.columns:
            self._layout = None if self.several else env.state_layout()
            self.columns = {name: [] for name in self._names(sig)}
        own = [eefs[a] for a in self.arms] + [targets[a] for a in self.arms]
        if self.several:
            own += [(active or {}).get(a, -1) for a in self.arms]
        read = []
        if self._layout is None:  # what no stored state holds as the env reads it
            poses_now = env.object_poses()
            read = [poses_now[o] for o in self.objects] + self._grippers(env)
        values = (action, *own, env.get_state(), *read, *sig.values())
        for column, value in zip(self.columns.values(), values, strict=True):
            column.append(value)
        return sig

    def _names(self, sig: Mapping[str, bool]) -> list[str]:
        names = ["actions"]
        names += [arm_key("eef_pose", a) for a in self.arms]
        names += [arm_key("target_pose", a) for a in self.arms]
        names += [f"subtask/{a}" for a in self.arms] if self.several else []
        names += ["env_state"]
        if self._layout is None:
            names += [f"object_poses/{o}" for o in self.objects]
            names += [f"fingers/{a}" for a in self.arms]
        return names + [f"subtask_signals/{n}" for n in sig]

    def _grippers(self, env: Env) -> list[np.ndarray]:
        if not self.several:
            return [env.gripper_state()]
        if self._arm_envs is None or self._arm_envs[0] is not env:
            self._arm_envs = (env, arm_envs(env, self.arms))
        return [self._arm_envs[1][a].gripper_state() for a in self.arms]

    def arrays(self) -> dict[str, np.ndarray]:
        """Every array of the episode (T, ...), the derived ones included, in the stores'
        order."""
        if not self.columns:
            return {}
        got = {k: np.asarray(v) for k, v in self.columns.items()}
        if self._layout is not None:
            objects = self._layout.object_poses(got["env_state"])
            fingers = {self.arms[0]: self._layout.gripper_states(got["env_state"])}
        else:
            objects = {o: got.pop(f"object_poses/{o}") for o in self.objects}
            fingers = {a: got.pop(f"fingers/{a}").astype(np.float64) for a in self.arms}
        eefs = {a: got[arm_key("eef_pose", a)] for a in self.arms}
        if self.several:
            obs = arms_observation_values(eefs, fingers, objects, self.objects)
        else:
            arm = self.arms[0]
            obs = observation_values(eefs[arm], fingers[arm], objects, self.objects)
        signals = {k: v for k, v in got.items() if k.startswith("subtask_signals/")}
        out = {k: v for k, v in got.items() if k not in signals}  # actions ... env_state
        out |= {f"object_poses/{o}": objects[o] for o in self.objects}
        out |= signals
        out |= {f"obs/{k}": np.asarray(v, np.float32) for k, v in obs.items()}
        for n, arm in enumerate(self.arms):  # each arm's 7 action entries end with its grip
            out[arm_key("gripper", arm)] = out["actions"][:, 7 * n + 6].astype(np.float32)
        return out


def replay_actions(
    env: Env,
    initial_state: np.ndarray,
    actions: np.ndarray,
    objects: tuple[str, ...],
    arms: tuple[str, ...] = (ARM,),
) -> tuple[dict[str, np.ndarray], bool]:
    """Restore ``initial_state``, execute ``actions`` (T, 7 per arm of ``arms``) and record
    every step, with the controller target each arm's action implies (paper M.1). Returns
    (steps, task success)."""
    env.set_state(initial_state)
    recorder = StepRecorder(objects, arms)
    each = arm_envs(env, arms)
    for action in np.asarray(actions, dtype=np.float32):
        eefs = {arm: a.eef_pose() for arm, a in each.items()}
        targets = {
            arm: a.action_to_target_pose(action[7 * n : 7 * n + 7])
            for n, (arm, a) in enumerate(each.items())
        }
        recorder.record(env, eefs, action, targets)
        env.step(action)
    return recorder.arrays(), bool(env.is_success())
