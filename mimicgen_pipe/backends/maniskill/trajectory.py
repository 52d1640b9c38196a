"""Replaying stored episodes in ManiSkill for its trajectory format
(mimicgen_pipe.formats.exporters.maniskill): the state after every step, the task's success, and
the same motion as ``pd_joint_pos`` actions.

A ``pd_ee_delta_pose`` step solves IK for the arm and sets the result as the joints' PD drive
targets; ManiSkill's Panda ``pd_joint_pos`` controller drives the same joints with the same
stiffness, damping and force limit, and shares the gripper controller. So the pd_joint_pos
action of a step is the arm's drive targets after it plus the same gripper action, and it
moves the robot exactly as the delta-pose action did.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mimicgen_pipe.core.contracts import Replayed
from mimicgen_pipe.core.observations import low_dim_observation


@dataclass(frozen=True)
class ReplayJob:
    task: str
    robot: str
    lean_step: bool = True


_ENV = None


def init_worker(job: ReplayJob) -> None:
    global _ENV
    from mimicgen_pipe import backends

    _ENV = backends.make_env("maniskill", job.task, job.robot, job.lean_step)


def replay(env, initial_state: np.ndarray, actions: np.ndarray) -> Replayed:
    """Restore ``initial_state``, execute ``actions`` (T, 7) with ``env.step`` and record the
    flat state before and after every step (T + 1, S), success after each step (T,), the
    equivalent pd_joint_pos actions (T, 8): arm drive targets [rad], gripper action, and the
    low-dim observation after the last step."""
    env.set_state(initial_state)
    # the arm's drive targets as SAPIEN holds them (the lean step sets them there directly)
    arm = [j._objs[0] for j in env.unwrapped.agent.controller.controllers["arm"].joints]
    # the first state as stored: set and read back, the robot's root moves by ~1e-8
    states, success, joint = [np.asarray(initial_state, np.float32)], [], []
    for action in np.asarray(actions, np.float32):
        env.step(action)
        states.append(env.get_state())
        success.append(env.is_success())
        targets = np.concatenate([j.drive_target for j in arm]).astype(np.float32)
        joint.append(np.concatenate([targets, action[-1:]]))
    last = low_dim_observation(
        env.eef_pose(), env.gripper_state(), env.object_poses(), env.spec.objects
    )
    return Replayed(np.stack(states), np.asarray(success, bool), np.stack(joint), last)


def replay_block(block: list[tuple[np.ndarray, np.ndarray]]) -> list[Replayed]:
    assert _ENV is not None
    _ENV.rebuild()
    return [replay(_ENV, state, actions) for state, actions in block]


def state_layout(env) -> list[tuple[str, str, int]]:
    """(kind, name, width) of every part of the env's flat state, in its order: kind is
    "actors" or "articulations", as in ManiSkill's state dict and trajectory files."""
    state = env.unwrapped.get_state_dict()
    return [(kind, name, int(v.shape[-1])) for kind in ("actors", "articulations")
            for name, v in state[kind].items()]  # fmt: skip


def env_info(env, max_episode_steps: int) -> dict:
    """The trajectory file's env_info: ManiSkill's own env id (the scene is the same; our
    reset variants only set where objects start, and replays start from the stored state)."""
    return {
        "env_id": env.task.base_env_id,
        "max_episode_steps": int(max_episode_steps),
        "env_kwargs": {
            "obs_mode": "none",
            "control_mode": env.control_mode,
            "sim_backend": "physx_cpu",
            "robot_uids": env.agent_uid,
        },
    }
