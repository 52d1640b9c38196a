"""ManiSkill's batched simulation as the batched form of the env protocol
(mimicgen_pipe.core.contracts.BatchEnv): one ManiSkill env holding ``num_envs`` scenes, stepped
together by ManiSkill's own ``env.step`` and reset one scene at a time by its partial reset.

On ``physx_cuda`` the scenes live on the GPU, thousands in one process. On ``physx_cpu``
ManiSkill holds one scene per env, and this form is ManiSkill's stock step under the batch
protocol: the same attempts, bit for bit, as the one-at-a-time env with
``maniskill.lean_step: false`` (tests/test_maniskill_batch.py), which is what checks this
form without a GPU.

Reads are made once per step for all scenes (one transfer from the device per array) and
each slot takes its row: the generator reads every scene every step.
"""

from __future__ import annotations

import os

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from mimicgen_pipe.backends import load_task  # noqa: E402
from mimicgen_pipe.backends.maniskill.env import ManiSkillEnv, make_gym_env  # noqa: E402
from mimicgen_pipe.backends.maniskill.tasks import ManiSkillTask  # noqa: E402
from mimicgen_pipe.core import poses  # noqa: E402
from mimicgen_pipe.core.contracts import check_batch_size  # noqa: E402
from mimicgen_pipe.core.controller import (  # noqa: E402
    DeltaPoseController,
    actions_to_target_poses,
    target_poses_to_actions,
)
from mimicgen_pipe.core.errors import InputError  # noqa: E402

SIM_BACKENDS = ("physx_cpu", "physx_cuda")


def check_batched(task: ManiSkillTask, sim_backend: str, num_envs: int) -> None:
    """InputError, before any work, for a batch this back end cannot run: an unknown
    simulation back end, physx_cuda without a CUDA device, more than one scene on the CPU,
    or a task without a batched form (``batched`` in its task file)."""
    check_batch_size(num_envs)
    if sim_backend not in SIM_BACKENDS:
        raise InputError(
            f"maniskill.sim_backend {sim_backend!r}: unknown (known: {', '.join(SIM_BACKENDS)})"
        )
    if sim_backend == "physx_cuda" and not torch.cuda.is_available():
        raise InputError(
            "maniskill.sim_backend physx_cuda: no CUDA device here (torch.cuda.is_available() "
            "is False); use physx_cpu, which runs generate.workers processes of one scene each"
        )
    if sim_backend == "physx_cpu" and num_envs > 1:
        raise InputError(
            f"generate.num_envs {num_envs} on maniskill.sim_backend physx_cpu: ManiSkill's CPU "
            "simulation holds one scene per env; use generate.workers for more processes, or "
            "physx_cuda"
        )
    if not task.batched:
        raise InputError(
            f"task {task.spec.name}: no batched form (its task file does not set batched=True: "
            "its reset, signals or success read one scene); generate it with "
            "generate.num_envs 1 on physx_cpu"
        )


class ManiSkillBatch:
    """``num_envs`` scenes of ``task`` in one ManiSkill env on ``sim_backend``, with
    pd_ee_delta_pose and ManiSkill's own step, reset and evaluation. Poses are 4x4 in each
    scene's world frame [m] (ManiSkill reports every scene in its own frame)."""

    def __init__(
        self,
        task: str,
        num_envs: int,
        sim_backend: str = "physx_cuda",
        robot: str = "panda",
    ) -> None:
        if robot != "panda":
            raise InputError(f"robot {robot!r}: the batched ManiSkill form has the Panda only")
        self.task = load_task("maniskill", task)
        check_batched(self.task, sim_backend, num_envs)
        self.spec = self.task.spec
        self.robot = robot
        self.num_envs = num_envs
        self._env = make_gym_env(
            ManiSkillEnv.env_id_for(self.task),
            self.task,
            sim_backend,
            num_envs=num_envs,
            robot_uids=self.task.panda_uid,
        )
        self._u = self._env.unwrapped
        arm = self._u.agent.controller.controllers["arm"].config
        self.control_freq = int(self._u.control_freq)
        root = self._u.agent.robot.pose.raw_pose[0].cpu().numpy().astype(np.float64)
        self.controller = DeltaPoseController(
            pos_scale=float(arm.pos_upper),
            rot_scale=float(arm.rot_lower),
            rot_repr="euler_xyz",
            root_pose=poses.pose_from_pq(root[:3], root[3:]),
        )
        robot_ = self._u.agent.robot
        self._finger_index = [
            robot_.active_joints.index(j) for j in robot_.active_joints if "finger" in j.name
        ]
        self._slots = tuple(_Slot(self, k) for k in range(num_envs))
        self._info: dict | None = None
        self._reads: dict[str, np.ndarray] = {}
        self.rebuild()

    # -- the batch --------------------------------------------------------------------------
    def slot(self, k: int) -> _Slot:
        return self._slots[k]

    def step(self, actions: np.ndarray, active: np.ndarray) -> None:
        """Every scene steps (a GPU batch steps all at once); an idle one gets a zero arm
        action and keeps its gripper command, and is reset before its next attempt."""
        actions = np.array(actions, dtype=np.float32, copy=True)
        actions[~np.asarray(active, bool), :6] = 0.0
        self._changed(self._u.step(torch.as_tensor(actions, device=self._u.device))[4])

    def rebuild(self) -> None:
        self._u.reset(seed=self.task.rebuild_seed, options={"variant": "D0", "reconfigure": True})
        self._changed()

    def close(self) -> None:
        self._env.close()

    # -- what the slots read, once per step ------------------------------------------------
    def _changed(self, info: dict | None = None) -> None:
        self._info, self._reads = info, {}

    def _reset_slot(self, k: int, seed: int, variant: str) -> None:
        scene = self.task.variant_scene_seeds.get(variant)
        if scene is not None:
            raise InputError(
                f"variant {variant} of task {self.spec.name} has a scene of its own; the "
                "batched form has the task's one scene (generate it with generate.num_envs 1)"
            )
        idx = torch.tensor([k], device=self._u.device)
        options = {"variant": variant, "env_idx": idx}
        self._changed(self._u.reset(seed=[int(seed)], options=options)[1])

    def _read(self, name: str) -> np.ndarray:
        """All scenes' ``name`` as numpy, read once until the next step or reset."""
        if name not in self._reads:
            u = self._u
            if name == "tcp":
                value = u.agent.tcp.pose.raw_pose
            elif name == "qpos":
                value = u.agent.robot.get_qpos()
            elif name == "state":
                value = u.get_state()
            else:  # an object of the task
                value = getattr(u, self.task.objects[name]).pose.raw_pose
            self._reads[name] = value.cpu().numpy()
        return self._reads[name]

    def _evaluation(self) -> dict:
        if self._info is None:
            self._info = self._u.evaluate()
        return self._info


def _pose(raw: np.ndarray) -> np.ndarray:
    pq = raw.astype(np.float64)
    return poses.pose_from_pq(pq[:3], pq[3:])


def _row(value, k: int) -> bool:
    """Scene k's entry of a signal: a (num_envs,) tensor, or one bool of a one-scene task."""
    return bool(value[k]) if isinstance(value, torch.Tensor) and value.ndim else bool(value)


class _Slot:
    """Scene k of a ManiSkillBatch as an env of the env protocol; its ``step`` is the batch's
    (mimicgen_pipe.method.batched steps the batch, never a slot)."""

    def __init__(self, batch: ManiSkillBatch, k: int) -> None:
        self.batch, self.k = batch, k
        self.spec = batch.spec
        self.robot = batch.robot
        self.control_mode = ManiSkillEnv.control_mode
        self.control_freq = batch.control_freq

    def reset(self, seed: int, variant: str) -> None:
        self.batch._reset_slot(self.k, seed, variant)

    def rebuild(self) -> None:
        self.batch.rebuild()

    def eef_pose(self) -> np.ndarray:
        return _pose(self.batch._read("tcp")[self.k])

    def object_poses(self) -> dict[str, np.ndarray]:
        return {o: _pose(self.batch._read(o)[self.k]) for o in self.spec.objects}

    def gripper_state(self) -> np.ndarray:
        return self.batch._read("qpos")[self.k, self.batch._finger_index].astype(np.float64)

    def step(self, action: np.ndarray) -> None:
        raise RuntimeError("a slot of a batch is stepped by its batch (ManiSkillBatch.step)")

    def subtask_signals(self) -> dict[str, bool]:
        b = self.batch
        signals = b.task.signals(b._u, b._evaluation())
        return {name: _row(value, self.k) for name, value in signals.items()}

    def is_success(self) -> bool:
        return _row(self.batch._evaluation()["success"], self.k)

    def get_state(self) -> np.ndarray:
        return self.batch._read("state")[self.k].astype(np.float32)

    def state_layout(self) -> None:
        """None: a slot reads its poses and fingers from the batch's own buffers, which no
        layout of its state is checked against; the recorder reads them at every step."""
        return None

    def set_state(self, state: np.ndarray) -> None:
        b = self.batch
        idx = torch.tensor([self.k], device=b._u.device)
        s = torch.as_tensor(np.asarray(state, np.float32)[None], device=b._u.device)
        b._u.set_state(s, idx)
        if b.task.restore:  # what the task derives from poses outside the state (a goal)
            b.task.restore(b._u)
        b._changed()

    def target_pose_to_action(self, target: np.ndarray, gripper: float) -> np.ndarray:
        return target_poses_to_actions(self.eef_pose(), target, gripper, self.batch.controller)

    def action_to_target_pose(self, action: np.ndarray) -> np.ndarray:
        return actions_to_target_poses(self.eef_pose(), action, self.batch.controller)

    def reachable(self, targets: np.ndarray) -> np.ndarray:
        """All True, as the one-scene env: ManiSkill's controller solves its own IK."""
        return np.ones(len(targets), bool)

    def close(self) -> None:
        self.batch.close()
