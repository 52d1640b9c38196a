"""The MimicGen generation method (paper 3.2, L, M): segment transform, interpolation,
source selection, action noise, and one generation attempt over an env protocol object."""

from __future__ import annotations

from collections.abc import Generator, Mapping
from dataclasses import dataclass
from typing import cast

import numpy as np

from mimicgen_pipe import poses
from mimicgen_pipe.contracts import ArmEnv, Env, MultiArmEnv, PlanningEnv
from mimicgen_pipe.controller import clip_actions
from mimicgen_pipe.observations import arms_observation_values, observation_values
from mimicgen_pipe.pose_noise import PoseNoise, generation_rng, perturb_pose
from mimicgen_pipe.registry import load
from mimicgen_pipe.segments import segment_bounds
from mimicgen_pipe.selection import Candidates
from mimicgen_pipe.taskspec import ARM, TaskSpec, arm_key
from mimicgen_pipe.transit import PlannerSettings, approach_start


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


@dataclass
class _Segment:
    """An arm's transformed segment being executed: subtask ``index`` (the task's order),
    its targets (K, 4, 4) world, gripper commands (K,), action noise (K, 6), and the next
    step ``k``."""

    index: int
    targets: np.ndarray
    grips: np.ndarray
    noise: np.ndarray
    k: int = 0


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
    (alone, or as one slot of a batch stepped together, mimicgen_pipe.batched); it returns
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
    alone, in the order the subtasks start."""
    rng = np.random.default_rng(seed)
    pose_rng = generation_rng(seed)
    env.reset(seed=seed, variant=variant)
    initial_state = env.get_state()
    obj_now = env.object_poses()
    initial_object_poses = np.stack([obj_now[o] for o in spec.objects])
    offsets = np.array(
        [
            int(rng.integers(spec.subtasks[i].term_offset_range[0],
                             spec.subtasks[i].term_offset_range[1] + 1))
            for i in spec.ending_subtasks
        ],
        dtype=np.int64,
    )  # fmt: skip
    starts = sources.episode_starts
    bounds = sources.segment_bounds(spec, offsets)  # arm -> (N, M_arm, 2)
    arms = arm_envs(env, spec.arms)
    order = {arm: spec.arm_indices(arm) for arm in spec.arms}  # arm -> its subtasks' indices
    after, partner = constraint_maps(spec)

    recorder = StepRecorder(spec.objects, spec.arms)
    chosen = np.full(len(spec.subtasks), -1, dtype=np.int64)
    reached = np.zeros(len(spec.subtasks), dtype=bool)
    ended = np.zeros(len(spec.subtasks), dtype=bool)
    demo = dict.fromkeys(spec.arms, -1)
    running: dict[str, _Segment | None] = dict.fromkeys(spec.arms)
    done = dict.fromkeys(spec.arms, 0)  # subtasks each arm has finished
    hold: dict[str, tuple[np.ndarray, float]] = {}  # a waiting arm's target and gripper
    started = np.full(len(spec.subtasks), len(spec.subtasks))  # the order subtasks started in
    ik_failed = planner_failed = False

    def waiting(arm: str) -> int | None:
        """The subtask ``arm`` starts next if it may start now, else None."""
        if running[arm] is not None or done[arm] == len(order[arm]):
            return None
        i = order[arm][done[arm]]
        return i if all(ended[j] for j in after[i]) else None

    def segment(arm: str, i: int, ref_now: np.ndarray, j: int) -> tuple[np.ndarray, np.ndarray]:
        """Subtask i's segment of source demo j, carried to ``ref_now``: targets, grippers."""
        sub = spec.subtasks[i]
        s, e = starts[j] + bounds[arm][j, order[arm].index(i)]
        seg = transform_segment(
            sources.target_poses[arm][s:e], sources.object_poses[sub.reference_object][s], ref_now
        )
        return seg, sources.gripper[arm][s:e]

    def start(group: list[tuple[str, int]]) -> bool:
        """Start subtasks ``group`` (one, or coordinated ones) on their arms; False when an
        arm cannot reach its targets or no transit is found."""
        nonlocal ik_failed, planner_failed
        lead_arm, lead = group[0]
        sub = spec.subtasks[lead]
        # the reference object's pose as a pose estimator reports it (paper T); the
        # simulator's true poses are untouched, and they are what gets recorded
        ref_now = perturb_pose(obj_now[sub.reference_object], config.pose_noise, pose_rng)
        if demo[lead_arm] < 0 or config.per_subtask or len(group) > 1:
            seg_starts = starts + bounds[lead_arm][:, order[lead_arm].index(lead), 0]
            src_objects = sources.object_poses[sub.reference_object][seg_starts]
            candidates = Candidates(
                src_objects,
                ref_now,
                transform_segment(sources.target_poses[lead_arm][seg_starts], src_objects, ref_now),
                arms[lead_arm].eef_pose(),
            )
            picked = select_source(config.selection, candidates, rng, config.nn_k)
            for arm, _ in group:
                demo[arm] = picked
        plans = []
        for arm, i in group:
            chosen[i] = demo[arm]
            started[i] = int(np.count_nonzero(chosen >= 0))
            seg, grip = segment(arm, i, ref_now, demo[arm])
            if config.transit == "planned":
                k = approach_start(seg, ref_now, config.planner.approach_distance)
                seg, grip = seg[k:], grip[k:]
                path, _ = cast(PlanningEnv, env).plan_transit(seg[0], config.planner, rng)
                if path is None:
                    planner_failed = True
                    return False
                interp = np.concatenate([path, np.repeat(seg[:1], config.n_fixed, axis=0)])
            else:
                eef = arms[arm].eef_pose()
                interp = interpolation(eef, seg[0], config.n_interp, config.n_fixed)
            targets = np.concatenate([interp, seg])
            grips = np.concatenate([np.full(len(interp), grip[0]), grip])
            if not arms[arm].reachable(targets).all():
                ik_failed = True
                return False
            plans.append((arm, i, targets, grips))
        steps = max(len(t) for _, _, t, _ in plans)
        for arm, i, targets, grips in plans:
            # step-aligned: a coordinated segment shorter than its partner's holds its end
            pad = steps - len(targets)
            targets = np.concatenate([targets, np.repeat(targets[-1:], pad, axis=0)])
            grips = np.concatenate([grips, np.repeat(grips[-1:], pad)])
            sigma = np.full(len(targets), config.action_noise)
            radius = spec.subtasks[i].noise_free_radius
            if radius is not None:
                near = np.linalg.norm(targets[:, :3, 3] - ref_now[:3, 3], axis=-1)
                sigma[near <= radius] = 0.0
            running[arm] = _Segment(i, targets, grips, action_noise(sigma, rng))
        return True

    arm_list = list(arms.items())
    starting = True  # at the start, and once a segment has ended: which arms may start
    while True:
        if starting:
            for arm in spec.arms:
                i = waiting(arm)
                if i is None:
                    continue
                group = [(arm, i)]
                if i in partner:
                    j = partner[i]
                    other = spec.subtasks[j].arm
                    if waiting(other) != j:
                        continue  # its partner is not ready: hold
                    group.append((other, j))
                if not start(group):
                    break
            active = {arm: s.index for arm, s in running.items() if s is not None}
            if ik_failed or planner_failed or not active:
                break  # stopped, or every arm has done its subtasks (a checked spec cannot stall)
            segments = [(arm, running[arm]) for arm in active]
            starting = False
        eefs, targets, parts = {}, {}, []
        for arm, a in arm_list:
            eefs[arm] = a.eef_pose()
            seg = running[arm]
            if seg is None:  # waiting: hold where its last segment ended (or where it began)
                targets[arm], grip = hold.get(arm) or (eefs[arm], _first_grip(sources, arm))
                hold[arm] = (targets[arm], grip)
                parts.append(clip_actions(a.target_pose_to_action(targets[arm], grip)))
                continue
            targets[arm] = seg.targets[seg.k]
            action = add_action_noise(a.target_pose_to_action(targets[arm], seg.grips[seg.k]),
                                      seg.noise[seg.k])  # fmt: skip
            parts.append(clip_actions(action))
        action = (parts[0] if len(parts) == 1 else np.concatenate(parts)).astype(np.float32)
        sig = recorder.record(env, eefs, obj_now, action, targets, active)
        for i in active.values():
            term = spec.subtasks[i].term_signal
            if term is not None and sig[term]:
                reached[i] = True
        yield action
        obj_now = env.object_poses()
        for arm, seg in segments:
            seg.k += 1
            if seg.k < len(seg.targets):
                continue
            term = spec.subtasks[seg.index].term_signal
            if term is not None and env.subtask_signals()[term]:
                reached[seg.index] = True
            ended[seg.index] = True
            hold[arm] = (seg.targets[-1], float(seg.grips[-1]))
            running[arm], done[arm] = None, done[arm] + 1
            starting = True
    success = not (ik_failed or planner_failed) and bool(env.is_success())
    final = np.zeros(len(spec.subtasks), dtype=bool)
    for arm in spec.arms:
        final[order[arm][-1]], reached[order[arm][-1]] = True, success
    failed = -1 if success else first_failure(reached, started, final)
    return Attempt(
        seed,
        recorder.arrays(),
        success,
        failed,
        ik_failed,
        chosen,
        initial_state,
        initial_object_poses,
        planner_failed,
    )


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
    subtask_signals/<name>, and the policy observation obs/<key> (mimicgen_pipe.observations).
    With several arms, each arm's eef_pose, target_pose and gripper as ``<key>/<arm>``
    (arm_key) and ``subtask/<arm>``, the subtask it runs (-1: holding). One list per array,
    its names fixed at the first step.
    """

    def __init__(self, objects: tuple[str, ...], arms: tuple[str, ...] = (ARM,)) -> None:
        self.objects, self.arms = objects, arms
        self.several = len(arms) > 1
        self.columns: dict[str, list] = {}
        self._arm_envs: tuple[Env, dict[str, ArmEnv]] | None = None  # found once per env

    def record(
        self,
        env: Env,
        eefs: Mapping[str, np.ndarray],
        object_poses: Mapping[str, np.ndarray],
        action: np.ndarray,
        targets: Mapping[str, np.ndarray],
        active: Mapping[str, int] | None = None,
    ) -> dict[str, bool]:
        """Append one step: the arms' end-effector poses and targets (arm -> pose), and with
        several arms each one's subtask (``active``: arm -> subtask index, an arm without
        one holding); returns the subtask signals it recorded."""
        sig = env.subtask_signals()
        several = self.several
        if several:
            if self._arm_envs is None or self._arm_envs[0] is not env:
                self._arm_envs = (env, arm_envs(env, self.arms))
            arms = self._arm_envs[1]
            grippers = {arm: arms[arm].gripper_state() for arm in self.arms}
            obs = arms_observation_values(eefs, grippers, object_poses, self.objects)
            own = [eefs[a] for a in self.arms] + [targets[a] for a in self.arms]
            own += [(active or {}).get(a, -1) for a in self.arms]
        else:
            eef = eefs[self.arms[0]]
            obs = observation_values(eef, env.gripper_state(), object_poses, self.objects)
            own = [eef, targets[self.arms[0]]]
        values = (
            action,
            *own,
            env.get_state(),
            *(object_poses[o] for o in self.objects),
            *sig.values(),
            *obs.values(),
        )
        if not self.columns:
            names = ["actions"]
            names += [arm_key("eef_pose", a) for a in self.arms]
            names += [arm_key("target_pose", a) for a in self.arms]
            names += [f"subtask/{a}" for a in self.arms] if several else []
            names += ["env_state"]
            names += [f"object_poses/{o}" for o in self.objects]
            names += [f"subtask_signals/{n}" for n in sig]
            names += [f"obs/{k}" for k in obs]
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
        recorder.record(env, eefs, env.object_poses(), action, targets)
        env.step(action)
    return recorder.arrays(), bool(env.is_success())
