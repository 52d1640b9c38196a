"""A two-arm task without a simulator, for the generator's two-arm logic: each end effector
goes exactly where its delta-pose action sends it, and the objects stay where the scene put
them. The right arm touches the cube, then reaches the tray's right side; the left arm
reaches the tray's left side once the right arm has touched the cube (sequential); both
then lift the tray together (coordinated). Success: both hands 0.15 m above their handles.
"""

from __future__ import annotations

import numpy as np

from mimicgen_pipe.core.controller import (
    DeltaPoseController,
    actions_to_target_poses,
    target_poses_to_actions,
)
from mimicgen_pipe.core.taskspec import (
    ObjectBounds,
    ResetVariant,
    SubtaskConstraint,
    SubtaskSpec,
    TaskSpec,
)
from mimicgen_pipe.method.generation import SourceDemos, replay_actions
from mimicgen_pipe.method.segments import subtask_ends

ARMS = ("right", "left")
OBJECTS = ("tray", "cube")
BOX = ObjectBounds((-0.1, 0.1), (-0.1, 0.1), (0.0, 0.0))
SPEC = TaskSpec(
    "toy_tray_lift",
    OBJECTS,
    (
        SubtaskSpec("touch_cube", "cube", "right_at_cube", arm="right"),
        SubtaskSpec("reach_tray_right", "tray", "right_at_tray", arm="right"),
        SubtaskSpec("lift_right", "tray", None, arm="right"),
        SubtaskSpec("reach_tray_left", "tray", "left_at_tray", arm="left"),
        SubtaskSpec("lift_left", "tray", None, arm="left"),
    ),
    {"D0": ResetVariant({"tray": BOX, "cube": BOX})},
    horizon=200,
    constraints=(
        SubtaskConstraint("sequential", ("right", "touch_cube"), ("left", "reach_tray_left")),
        SubtaskConstraint("coordinated", ("left", "lift_left"), ("right", "lift_right")),
    ),
)
CONTROLLER = DeltaPoseController(pos_scale=0.1, rot_scale=0.5, rot_repr="axis_angle")
START = {"right": (-0.3, -0.3, 0.3), "left": (-0.3, 0.3, 0.3)}
HANDLE = {"right": (0.0, -0.1, 0.02), "left": (0.0, 0.1, 0.02)}  # in the tray's frame [m]
NEAR, LIFT = 0.01, 0.15  # [m]


def at(xyz) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = xyz
    return t


class ToyArm:
    def __init__(self, env: ToyTwoArmEnv, name: str) -> None:
        self.env, self.name = env, name

    def eef_pose(self) -> np.ndarray:
        return self.env.eefs[self.name].copy()

    def gripper_state(self) -> np.ndarray:
        return np.full(2, 0.04 if self.env.grips[self.name] > 0 else 0.0)

    def target_pose_to_action(self, target: np.ndarray, gripper: float) -> np.ndarray:
        return target_poses_to_actions(self.eef_pose(), target, gripper, CONTROLLER)

    def action_to_target_pose(self, action: np.ndarray) -> np.ndarray:
        return actions_to_target_poses(self.eef_pose(), action, CONTROLLER)

    def reachable(self, targets: np.ndarray) -> np.ndarray:
        return np.ones(len(targets), bool)


class ToyTwoArmEnv:
    """The env protocol for SPEC, with ``arm(name)``; actions are 7 per arm, right first."""

    spec, robot, control_mode, control_freq = SPEC, "toy", "delta_pose", 10

    def __init__(self) -> None:
        self.arms = {a: ToyArm(self, a) for a in ARMS}
        self.reset(0, "D0")

    def arm(self, name: str) -> ToyArm:
        return self.arms[name]

    def reset(self, seed: int, variant: str) -> None:
        rng = np.random.default_rng(seed)
        self.objects = {o: at((*rng.uniform(-0.1, 0.1, 2), 0.0)) for o in OBJECTS}
        self.objects["cube"][:3, 3] += (0.2, -0.2, 0.0)  # the cube to the right of the tray
        self.eefs = {a: at(START[a]) for a in ARMS}
        self.grips = dict.fromkeys(ARMS, 1.0)

    def rebuild(self) -> None:
        pass

    def eef_pose(self) -> np.ndarray:
        raise AttributeError("a two-arm env has no one end effector: arm(name)")

    def object_poses(self) -> dict[str, np.ndarray]:
        return {o: t.copy() for o, t in self.objects.items()}

    def step(self, action: np.ndarray) -> None:
        for n, a in enumerate(ARMS):
            part = np.asarray(action[7 * n : 7 * n + 7], np.float64)
            self.eefs[a] = actions_to_target_poses(self.eefs[a], part, CONTROLLER)
            self.grips[a] = float(part[6])

    def _near(self, arm: str, goal: np.ndarray) -> bool:
        return bool(np.linalg.norm(self.eefs[arm][:3, 3] - goal[:3, 3]) < NEAR)

    def subtask_signals(self) -> dict[str, bool]:
        tray = self.objects["tray"]
        return {
            "right_at_cube": self._near("right", self.objects["cube"] @ at((0, 0, 0.02))),
            "right_at_tray": self._near("right", tray @ at(HANDLE["right"])),
            "left_at_tray": self._near("left", tray @ at(HANDLE["left"])),
        }

    def is_success(self) -> bool:
        """Each hand 0.15 m above its handle (within 1 cm)."""
        tray = self.objects["tray"]
        return all(self._near(a, tray @ at(HANDLE[a]) @ at((0, 0, LIFT))) for a in ARMS)

    def get_state(self) -> np.ndarray:
        parts = [self.eefs[a].ravel() for a in ARMS] + [self.objects[o].ravel() for o in OBJECTS]
        return np.concatenate([*parts, [self.grips[a] for a in ARMS]]).astype(np.float32)

    def set_state(self, state: np.ndarray) -> None:
        s = np.asarray(state, np.float64)
        mats = s[:64].reshape(4, 4, 4)
        self.eefs = {a: mats[n].copy() for n, a in enumerate(ARMS)}
        self.objects = {o: mats[2 + n].copy() for n, o in enumerate(OBJECTS)}
        self.grips = {a: float(g) for a, g in zip(ARMS, s[64:], strict=True)}

    def close(self) -> None:
        pass


def path(start: np.ndarray, goal: np.ndarray, steps: int) -> list[np.ndarray]:
    return [at(start[:3, 3] + (goal[:3, 3] - start[:3, 3]) * (k + 1) / steps) for k in range(steps)]


def demonstrate(env: ToyTwoArmEnv, seed: int) -> tuple[dict[str, np.ndarray], bool]:
    """One source demo from ``seed``, recorded (replay_actions): the right arm touches the
    cube in 15 steps while the left holds, then both reach the tray in 10, then lift in 10."""
    env.reset(seed, "D0")
    initial = env.get_state()
    tray, cube = env.objects["tray"], env.objects["cube"]
    hand = {a: tray @ at(HANDLE[a]) for a in ARMS}
    right = path(env.eefs["right"], cube @ at((0, 0, 0.02)), 15)
    right += path(right[-1], hand["right"], 10)
    left = [at(START["left"])] * 15 + path(at(START["left"]), hand["left"], 10)
    for track in (right, left):
        track += path(track[-1], track[-1] @ at((0, 0, LIFT)), 10)
    actions = []
    for r, lt in zip(right, left, strict=True):
        parts = [env.arm("right").target_pose_to_action(r, 1.0)]
        parts.append(env.arm("left").target_pose_to_action(lt, 1.0))
        act = np.concatenate(parts).astype(np.float32)
        env.step(act)
        actions.append(act)
    return replay_actions(env, initial, np.stack(actions), OBJECTS, ARMS)


def source_demos(env: ToyTwoArmEnv, seeds: list[int]) -> SourceDemos:
    """Demos from ``seeds``, parsed: each arm's track split by its own signals."""
    demos = [demonstrate(env, s) for s in seeds]
    assert all(ok for _, ok in demos)
    steps = [d for d, _ in demos]
    term = []
    for d in steps:
        signals = {k.split("/", 1)[1]: v for k, v in d.items() if k.startswith("subtask_signals/")}
        term.append(subtask_ends(signals, SPEC))
    cat = {k: np.concatenate([d[k] for d in steps]) for k in steps[0]}
    return SourceDemos(
        target_poses={a: cat[f"target_pose/{a}"] for a in ARMS},
        gripper={a: cat[f"gripper/{a}"].astype(np.float64) for a in ARMS},
        object_poses={o: cat[f"object_poses/{o}"] for o in OBJECTS},
        episode_ends=np.cumsum([len(d["actions"]) for d in steps]),
        term_index=np.asarray(term, np.int64),
    )
