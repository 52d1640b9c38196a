"""The contracts between the library and the simulator back ends: what a back end's env, arm,
batch of scenes, renderer and package provide, and what a source demo is. The library reads
only these; a back end (``mimicgen_pipe/backends/<backend>/``) implements them. Nothing here imports
a simulator.

All poses are 4x4 homogeneous transforms in the world frame [m]; an action is 7 entries per
arm: translation, rotation (a delta pose), gripper.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from mimicgen_pipe.core import poses
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.taskspec import TaskSpec
from mimicgen_pipe.core.transit import PlannerSettings


@dataclass(frozen=True)
class StateLayout:
    """Where an env's flat get_state() vector holds what object_poses() and gripper_state()
    read, bit for bit: ``objects``, object name -> the index of its world position (3, [m])
    followed by its quaternion (4, wxyz); ``frame_fix``, object name -> the (4, 4) transform
    object_poses() right-multiplies onto that pose (an object whose frame sits elsewhere than
    the simulator's); ``fingers``, the indices of the finger joint positions [m]."""

    objects: dict[str, int]
    frame_fix: dict[str, np.ndarray]
    fingers: tuple[int, ...]

    def object_poses(self, states: np.ndarray) -> dict[str, np.ndarray]:
        """Object name -> (T, 4, 4) world poses in ``states`` (T, S), as object_poses() would
        have read them at each state."""
        states = np.asarray(states)
        out = {}
        for name, i in self.objects.items():
            p = states[:, i : i + 3].astype(np.float64)
            q = states[:, i + 3 : i + 7].astype(np.float64)
            out[name] = poses.pose_from_pq_stepwise(p, q)
            if name in self.frame_fix:  # one product a step, as the env takes it
                fix = self.frame_fix[name]
                out[name] = np.stack([m @ fix for m in out[name]])
        return out

    def gripper_states(self, states: np.ndarray) -> np.ndarray:
        """(T, n) finger joint positions [m] in ``states`` (T, S), float64."""
        return np.asarray(states)[:, list(self.fingers)].astype(np.float64)


class Env(Protocol):
    """Everything the generator and the stages call on a simulator back end's env (see
    docs/extending.md, the env protocol); a back end's env implements all of it. All poses are 4x4
    homogeneous transforms in the world frame [m]."""

    spec: TaskSpec  # the task (mimicgen_pipe/tasks/<backend>/<task>.py)
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

    def state_layout(self) -> StateLayout | None:
        """Where get_state() holds the objects' poses and the fingers' positions, so that a
        recorder reads them from an episode's stored states after it instead of at every
        step; None where the state does not hold them as object_poses() and gripper_state()
        return them."""

    def target_pose_to_action(self, target: np.ndarray, gripper: float) -> np.ndarray:
        """The (7,) action that moves the TCP from where it is to ``target`` (world)."""

    def action_to_target_pose(self, action: np.ndarray) -> np.ndarray:
        """The TCP target (world) that ``action`` commands from where the TCP is."""

    def reachable(self, targets: np.ndarray) -> np.ndarray:
        """(K,) bool: whether the arm has an IK solution for each TCP target (K, 4, 4)."""

    def close(self) -> None: ...


class ArmEnv(Protocol):
    """One arm of an env: what the generator reads and commands per arm. Poses are 4x4 in
    the world frame [m]; an action is the arm's 7: translation, rotation, gripper."""

    def eef_pose(self) -> np.ndarray: ...

    def gripper_state(self) -> np.ndarray: ...

    def target_pose_to_action(self, target: np.ndarray, gripper: float) -> np.ndarray: ...

    def action_to_target_pose(self, action: np.ndarray) -> np.ndarray: ...

    def reachable(self, targets: np.ndarray) -> np.ndarray: ...


class MultiArmEnv(Env, Protocol):
    """An env of a task with several arms (TaskSpec.arms): its ``step`` takes 7 action
    entries per arm, in the task's arm order; the scene's reads are the env's own, each
    arm's are ``arm(name)``'s."""

    def arm(self, name: str) -> ArmEnv: ...


class PlanningEnv(Env, Protocol):
    """An env whose back end has a motion planner (generate.transit: planned)."""

    def plan_transit(
        self, target: np.ndarray, settings: PlannerSettings, rng: np.random.Generator
    ) -> tuple[np.ndarray | None, str]:
        """TCP targets (K, 4, 4), world, one per control step, along a collision-free path
        from the TCP's pose now to ``target``, drawing from ``rng``; or None and why there is
        none."""


class BatchEnv(Protocol):
    """``num_envs`` scenes stepped together. ``slot(k)`` is scene k as an env of the env
    protocol (its reads and its reset are its own; its ``step`` is never called by the
    engine); ``step`` advances the scenes whose ``active`` entry is True by their row of
    ``actions`` ((num_envs, 7) delta-pose actions), the others not at all."""

    num_envs: int

    def slot(self, k: int) -> Env: ...

    def step(self, actions: np.ndarray, active: np.ndarray) -> None: ...

    def rebuild(self) -> None: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class Replayed:
    """One episode replayed in the simulator: states (T + 1, S) float32, flat, before the
    first and after every action; success (T,) after each action; joint_actions (T, A) the
    same motion as pd_joint_pos actions (arm drive targets [rad], gripper action);
    last_obs: the low-dim observation after the last action (mimicgen_pipe.core.observations'
    keys -> (d,) float32), which the store does not hold."""

    states: np.ndarray
    success: np.ndarray
    joint_actions: np.ndarray
    last_obs: Mapping[str, np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True)
class SourceEpisode:
    """One source demo before recording: its reset seed (D0), the env state before the first
    action (the back end's get_state()), and its actions (T, 7)."""

    seed: int
    initial_state: np.ndarray
    actions: np.ndarray


class Renderer(Protocol):
    """Pictures of stored states (the env's get_state()) from ``cameras``: ``video``, the
    render stage's view, and the observation cameras (mimicgen_pipe.backends.CAMERAS, placed by
    mimicgen_pipe/core/cameras.py). Images are (height, width, 3) uint8 RGB, on the CPU."""

    cameras: tuple[str, ...]
    seconds: dict[str, float]  # [s] spent per camera in images(), its scene updates included

    def images(self, state: np.ndarray) -> dict[str, np.ndarray]:
        """Camera name -> image of the scene in ``state``."""

    def frame(self, state: np.ndarray) -> np.ndarray:
        """The first camera's image of the scene in ``state``."""

    def close(self) -> None: ...


class Backend(Protocol):
    """A simulator back end: the package ``mimicgen_pipe/backends/<backend>/``, a choice of the
    registry ``mimicgen_pipe.backends`` (mimicgen_pipe.core.registry). Its ``__init__`` imports no
    simulator (its other modules do, when an env is made).

    Optionally a back end also defines

    - ``PLANNER_ROBOTS``: the arms whose envs plan transits (:class:`PlanningEnv`;
      generate.transit: planned);
    - a batched form (:class:`BatchEnv`, generate.num_envs): ``check_batched(task, robot,
      num_envs, sim_backend)``, InputError for a batch it cannot run, and
      ``make_batch(task, robot, num_envs, sim_backend)``;
    - ``RESTORES_CHEAPLY = True``: its envs restore a stored state (``set_state``) and tell
      its success (``is_success``) in about a millisecond, so the export stage evaluates the
      task's success after every stored step (the rewards and dones of the exports);
    - ``source_file_episodes(path, task)``: the number of episodes of a source file in a
      format of its own (source.from_file), read and checked whole before any simulator
      starts (robomimic files are read on every back end:
      mimicgen_pipe/sources/robomimic_source.py).

    Back ends draw the scenes of their reset variants with mimicgen_pipe.core.reset_variants.
    """

    ROBOTS: Sequence[str]  # its arms
    CONTROL: tuple[str, int]  # (control_mode, control_freq [Hz]) of every env it makes

    def check_robot(self, robot: str) -> None:
        """InputError for an arm it does not have, or for one whose files are missing."""

    def cameras(self, robot: str) -> tuple[str, ...]:
        """The observation cameras (of mimicgen_pipe.backends.CAMERAS) that ``robot`` has there."""

    def task_names(self) -> tuple[str, ...]:
        """Its tasks, one file each under ``mimicgen_pipe/tasks/<backend>/`` (the choices
        of the registry ``mimicgen_pipe.tasks.<backend>``)."""

    def load_task(self, name: str) -> Any:
        """The task object ``TASK`` of ``mimicgen_pipe/tasks/<backend>/<name>.py``; its
        task spec is ``TASK.spec``."""

    def make_env(self, task: str, robot: str, lean_step: bool) -> Env:
        """A fresh env of ``task`` (lean_step: the ManiSkill back end's lean control step; a
        back end with one step ignores it)."""

    def source_episodes(
        self, env: Env, num_demos: int, seed: int, from_file: str | None, work_dir: Path
    ) -> tuple[list[SourceEpisode], int, int]:
        """Up to ``num_demos`` source demos on ``env`` from its demonstrator, drawn from reset
        seeds seed, seed + 1, ... (or ``from_file``'s, a file format of its own), how many the
        demonstrator dropped as failures, and how many seeds it tried (0 for a file)."""

    def make_renderer(
        self, task: str, robot: str, width: int, height: int, cameras: Sequence[str]
    ) -> Renderer:
        """A fresh :class:`Renderer` of ``task``'s stored states, images ``width`` x
        ``height`` [px]; its simulator is imported here, by the stages that render alone."""


def check_batch_size(num_envs: int) -> None:
    """InputError unless ``num_envs`` is a positive whole number."""
    if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
        raise InputError(f"batch size num_envs must be an integer >= 1, not {num_envs!r}")
