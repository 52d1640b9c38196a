"""The PyBullet adapter: one headless (DIRECT) env implementing the generator's env protocol."""

from __future__ import annotations

import math

import numpy as np
import pybullet as p
import pybullet_data
from pybullet_utils.bullet_client import BulletClient

from mimicgen_pipe.backends import load_task
from mimicgen_pipe.backends.pybullet.robots import (
    CONTROL,
    HOME_TCP,
    TCP_LINK,
    robot_chain,
    robot_spec,
    robot_urdf_file,
)
from mimicgen_pipe.backends.pybullet.tasks import ROBOT_BASE_XY
from mimicgen_pipe.core import poses
from mimicgen_pipe.core.controller import (
    DeltaPoseController,
    actions_to_target_poses,
    clip_actions,
    target_poses_to_actions,
)
from mimicgen_pipe.core.kinematics import inverse_kinematics
from mimicgen_pipe.core.reset_variants import sample_planar_poses
from mimicgen_pipe.core.urdf import FINGER_JOINTS, FINGER_OPEN

SIM_HZ = 240
CONTROL_HZ = CONTROL[1]
IK_ITERATIONS = 10  # DLS iterations per control step, from the current joint positions
ARM_KP = 0.1  # PyBullet position-motor gain
FINGER_FORCE = 70.0  # [N] per finger, the Franka hand's continuous grasp force
FRICTION = 1.0
# torsional friction of the finger pads: without it a tall object pivots between the
# fingers (about the closing axis) when the arm accelerates
FINGER_SPIN = 0.1
POS_SCALE = 0.05  # [m] per unit translation action (robosuite's OSC scale; see PyBulletEnv)
ROT_SCALE = 0.1  # [rad] per unit rotation action


def _pose(pos, quat_xyzw) -> np.ndarray:
    x, y, z, w = quat_xyzw
    return poses.pose_from_pq(np.asarray(pos, np.float64), np.array([w, x, y, z], np.float64))


class PyBulletEnv:
    """One PyBullet env: physics at 240 Hz, 12 sub-steps per 20 Hz control step.

    Poses are 4x4 in the world frame [m]. Actions are 7-D end-effector delta poses: translation
    0.1 m per unit in the robot base frame (clipped to [-1, 1] per axis), rotation as an
    axis-angle vector of 0.1 rad per unit (norm-clipped to 1) pre-multiplying the TCP
    rotation in the base frame, gripper +1 open / -1 closed (each finger at
    0.04 * (g + 1) / 2 m). Each step sets the target TCP pose to the current one plus the
    delta, solves it with damped-least-squares IK (mimicgen_pipe.core.kinematics) from the current
    joint positions, and drives the arm joints there with position motors.
    """

    backend = "pybullet"
    control_mode, control_freq = CONTROL

    def __init__(
        self,
        task: str = "stack",
        robot: str = "panda",
        base_xy: tuple[float, float] = ROBOT_BASE_XY,
    ) -> None:
        self.task = load_task("pybullet", task)
        self.spec = self.task.spec
        self.robot = robot
        spec = robot_spec(robot)
        self._urdf = robot_urdf_file(spec)
        self.chain = robot_chain(spec)
        root = np.eye(4)
        root[:2, 3] = base_xy
        self.controller = DeltaPoseController(
            pos_scale=POS_SCALE, rot_scale=ROT_SCALE, rot_repr="axis_angle", root_pose=root
        )
        home = inverse_kinematics(
            self.chain, HOME_TCP[None], np.asarray(spec.seed_q), iterations=300, max_step=0.05
        )
        if not home.converged[0]:
            raise RuntimeError(f"robot {robot}: no IK solution for the home pose")
        self.home_q = home.q[0]
        lo, hi = self.chain.lower[-1], self.chain.upper[-1]
        self._ik_restarts = np.repeat(self.home_q[None], 8, axis=0)
        self._ik_restarts[:, -1] = np.linspace(lo + 0.1, hi - 0.1, 8)
        self._sim = BulletClient(connection_mode=p.DIRECT)
        self._sim.setAdditionalSearchPath(pybullet_data.getDataPath())
        self.reset(seed=0, variant="D0")  # builds the scene

    # -- scene ----------------------------------------------------------------------------
    def _build(self) -> None:
        sim = self._sim
        sim.resetSimulation()
        sim.setPhysicsEngineParameter(
            fixedTimeStep=1.0 / SIM_HZ, numSolverIterations=50, deterministicOverlappingPairs=1
        )
        sim.setGravity(0, 0, -9.81)
        sim.loadURDF("plane.urdf")
        base = self.controller.root_pose[:3, 3]
        self._robot = sim.loadURDF(str(self._urdf), base.tolist(), useFixedBase=True)
        index = {}
        for j in range(sim.getNumJoints(self._robot)):
            info = sim.getJointInfo(self._robot, j)
            index[info[1].decode()] = j
            index["link:" + info[12].decode()] = j
        self._arm = [index[n] for n in self.chain.names]
        self._fingers = [index[n] for n in FINGER_JOINTS]
        self._tcp = index["link:" + TCP_LINK]
        self._arm_force = [
            max(50.0, sim.getJointInfo(self._robot, j)[10]) for j in self._arm
        ]  # effort limits, at least 50 N m: gravity alone needs ~40 on the iiwa's shoulder
        for j in self._fingers:
            sim.changeDynamics(
                self._robot, j, lateralFriction=FRICTION, spinningFriction=FINGER_SPIN
            )
        # the Franka hand's fingers move together (a mimic joint); two free fingers squeezing
        # with equal force let a held object slide along the closing axis
        gear = sim.createConstraint(
            self._robot,
            self._fingers[0],
            self._robot,
            self._fingers[1],
            p.JOINT_GEAR,
            [1, 0, 0],
            [0, 0, 0],
            [0, 0, 0],
        )
        sim.changeConstraint(gear, gearRatio=-1, erp=0.1, maxForce=50)
        self._bodies = {}
        for name, shape in self.task.shapes.items():
            col = sim.createCollisionShapeArray(
                [p.GEOM_BOX] * len(shape.boxes),
                halfExtents=[b.half_extents for b in shape.boxes],
                collisionFramePositions=[b.offset for b in shape.boxes],
            )
            vis = sim.createVisualShapeArray(
                [p.GEOM_BOX] * len(shape.boxes),
                halfExtents=[b.half_extents for b in shape.boxes],
                visualFramePositions=[b.offset for b in shape.boxes],
                rgbaColors=[shape.rgba] * len(shape.boxes),
            )
            body = sim.createMultiBody(shape.mass, col, vis)
            sim.changeDynamics(body, -1, lateralFriction=FRICTION, spinningFriction=0.001)
            self._bodies[name] = body
        self._changed()

    def _changed(self) -> None:
        self._eef: np.ndarray | None = None
        self._objects: dict[str, np.ndarray] | None = None
        self._signals: dict[str, bool] | None = None

    # -- protocol -------------------------------------------------------------------------
    def reset(self, seed: int, variant: str) -> None:
        """The home pose, fingers open, objects resting on the table where ``variant`` draws
        them (mimicgen_pipe.core.reset_variants, each object's yaw right after its position) from
        numpy's generator seeded with ``seed``."""
        rng = np.random.default_rng(seed)
        base_xy = tuple(self.controller.root_pose[:2, 3])
        xys, yaws = sample_planar_poses(
            self.spec.reset_variants[variant],
            self.spec.objects,
            base_xy,
            rng.random,
            draw_order="object_by_object",
        )
        fingers = np.full(len(FINGER_JOINTS), FINGER_OPEN)
        state = [self.home_q, fingers, np.zeros(self.chain.dof + len(fingers))]
        for name, xy, yaw in zip(self.spec.objects, xys, yaws, strict=True):
            pose = np.eye(4)
            c, s = math.cos(yaw[0]), math.sin(yaw[0])
            pose[:2, :2] = [[c, -s], [s, c]]
            pose[:2, 3], pose[2, 3] = xy[0], self.task.shapes[name].z
            pq = poses.pose_to_pq(pose)
            state += [pq[:3], pq[[4, 5, 6, 3]], np.zeros(6)]
        # stores keep states in float32: start from float32 values so that a stored initial
        # state is this one exactly
        self.set_state(np.concatenate(state).astype(np.float32))

    def rebuild(self) -> None:
        """Nothing to do: every reset or set_state builds a new scene."""

    def step(self, action: np.ndarray) -> None:
        a = clip_actions(action)
        sim = self._sim
        target = self.controller.root_pose_inv @ actions_to_target_poses(
            self.eef_pose(), a, self.controller
        )
        q = np.array([s[0] for s in sim.getJointStates(self._robot, self._arm)])
        q_target = inverse_kinematics(self.chain, target[None], q, iterations=IK_ITERATIONS).q[0]
        sim.setJointMotorControlArray(
            self._robot,
            self._arm,
            p.POSITION_CONTROL,
            targetPositions=q_target.tolist(),
            forces=self._arm_force,
            positionGains=[ARM_KP] * len(self._arm),
        )
        width = FINGER_OPEN * (float(a[6]) + 1.0) / 2.0
        sim.setJointMotorControlArray(
            self._robot,
            self._fingers,
            p.POSITION_CONTROL,
            targetPositions=[width, width],
            forces=[FINGER_FORCE, FINGER_FORCE],
        )
        for _ in range(SIM_HZ // CONTROL_HZ):
            sim.stepSimulation()
        self._changed()

    def eef_pose(self) -> np.ndarray:
        if self._eef is None:
            state = self._sim.getLinkState(self._robot, self._tcp, computeForwardKinematics=True)
            self._eef = _pose(state[4], state[5])
        return self._eef

    def object_poses(self) -> dict[str, np.ndarray]:
        if self._objects is None:
            self._objects = {
                n: _pose(*self._sim.getBasePositionAndOrientation(b))
                for n, b in self._bodies.items()
            }
        return self._objects

    def gripper_state(self) -> np.ndarray:
        return np.array([s[0] for s in self._sim.getJointStates(self._robot, self._fingers)])

    def grasped(self, name: str) -> bool:
        """Both fingers touch object ``name``."""
        body = self._bodies[name]
        return all(
            self._sim.getContactPoints(self._robot, body, linkIndexA=f) for f in self._fingers
        )

    def subtask_signals(self) -> dict[str, bool]:
        if self._signals is None:
            self._signals = self.task.signals(self)
        return self._signals

    def is_success(self) -> bool:
        return self.task.success(self.subtask_signals())

    def get_state(self) -> np.ndarray:
        """[arm q, finger q, arm and finger velocities, then per object position, quaternion
        (x, y, z, w), linear and angular velocity], world frame."""
        sim = self._sim
        joints = sim.getJointStates(self._robot, self._arm + self._fingers)
        parts = [[s[0] for s in joints], [s[1] for s in joints]]
        for name in self.spec.objects:
            body = self._bodies[name]
            pos, quat = sim.getBasePositionAndOrientation(body)
            lin, ang = sim.getBaseVelocity(body)
            parts += [pos, quat, lin, ang]
        # float32 like the stores (and ManiSkill): restoring a returned state restores the
        # scene every reset() built, bit for bit
        return np.concatenate(parts).astype(np.float32)

    def state_layout(self) -> None:
        """None: PyBullet's poses are float64 and the state float32, so the poses the
        recorder stores are read at every step."""
        return None

    def set_state(self, state: np.ndarray) -> None:
        """Restore ``state`` (get_state()'s layout) in a freshly built scene. Bullet keeps
        contact caches between steps that the state vector does not hold; starting every
        episode from a new scene (~30-60 ms) makes an episode's trajectory depend on its
        initial state and actions only, so replays reproduce generated episodes exactly."""
        self._build()
        sim = self._sim
        state = np.asarray(state, np.float64)
        joints = self._arm + self._fingers
        n = len(joints)
        q, qd = state[:n], state[n : 2 * n]
        for j, qj, vj in zip(joints, q, qd, strict=True):
            sim.resetJointState(self._robot, j, float(qj), float(vj))
        # hold where restored until the first action
        sim.setJointMotorControlArray(
            self._robot,
            self._arm,
            p.POSITION_CONTROL,
            targetPositions=q[: len(self._arm)].tolist(),
            forces=self._arm_force,
            positionGains=[ARM_KP] * len(self._arm),
        )
        sim.setJointMotorControlArray(
            self._robot,
            self._fingers,
            p.POSITION_CONTROL,
            targetPositions=q[len(self._arm) :].tolist(),
            forces=[FINGER_FORCE] * 2,
        )
        k = 2 * n
        for name in self.spec.objects:
            body, s = self._bodies[name], state[k : k + 13]
            sim.resetBasePositionAndOrientation(body, s[:3].tolist(), s[3:7].tolist())
            sim.resetBaseVelocity(body, s[7:10].tolist(), s[10:13].tolist())
            k += 13
        self._changed()

    def target_pose_to_action(self, target: np.ndarray, gripper: float) -> np.ndarray:
        return target_poses_to_actions(self.eef_pose(), target, gripper, self.controller)

    def action_to_target_pose(self, action: np.ndarray) -> np.ndarray:
        return actions_to_target_poses(self.eef_pose(), action, self.controller)

    def reachable(self, targets: np.ndarray) -> np.ndarray:
        """(K,) whether each TCP target pose (K, 4, 4, world) is in the arm's workspace: an
        IK solution within 1 mm / 0.5 deg, solved as one batch from the current joint
        positions, then for the targets not solved yet from the home configuration with the
        wrist (last joint) turned to 8 angles across its range: top-down targets differ
        mostly in yaw, and a start on the wrong side of a wrist limit gets stuck there.
        Whether the arm gets there from where it is is the controller's business: that shows
        up as a task failure."""
        q = np.array([s[0] for s in self._sim.getJointStates(self._robot, self._arm)])
        root = self.controller.root_pose_inv @ np.asarray(targets)
        return inverse_kinematics(
            self.chain, root, q, iterations=200, restarts=self._ik_restarts
        ).converged

    def close(self) -> None:
        self._sim.disconnect()
