"""Planned transit on ManiSkill: a collision-free joint-space path for the arm from where it
is to a TCP target, among the scene's actors as they are now, with a grasped object carried
along (mimicgen_pipe.core.transit says when the generator asks for one).

The collision model is mplib's (the arm's convex collision meshes from ManiSkill's URDF and
SRDF, FCL for the checks); the search is our own RRT-Connect in joint space with shortcuts,
drawn from the attempt's generator so that the same seed gives the same path (mplib's own
planner draws from OMPL's and pinocchio's unseeded generators). All poses are 4x4 in the
world frame [m]; joint positions in rad.
"""

from __future__ import annotations

import numpy as np

from mimicgen_pipe.core import poses
from mimicgen_pipe.core.transit import PlannerSettings, joint_path

MOVE_GROUP = "panda_hand_tcp"
ARM_JOINTS = 7
GROUND = "ground"  # ManiSkill's ground plane lies under the table: the arm cannot reach it
IK_TOLERANCE = 1e-3  # [m + rad] mplib's 6-D distance between the IK's pose and the target
BASE_LINK = "panda_link0"  # stands on the table and never moves: its contacts are no news
# [rad] contacts the arm makes where it starts (a grasped cube resting on the table, a finger
# touching a wall beside the cube) are allowed this close to the start, and nowhere else
ESCAPE = 0.1


def _geometry(shape, fcl, margin: float):
    """The FCL geometry of a SAPIEN collision shape grown by ``margin`` [m] on every side
    (a convex mesh: each vertex moved ``margin`` away from the mean vertex), or None for a
    plane."""
    import sapien.physx as physx

    if isinstance(shape, physx.PhysxCollisionShapeBox):
        return fcl.Box(*(2 * (np.asarray(shape.half_size, np.float64) + margin)))
    if isinstance(shape, physx.PhysxCollisionShapeSphere):
        return fcl.Sphere(float(shape.radius) + margin)
    if isinstance(shape, physx.PhysxCollisionShapeCapsule):
        # SAPIEN's capsule lies along x, FCL's along z: the caller turns it
        return fcl.Capsule(float(shape.radius) + margin, 2 * float(shape.half_length))
    if isinstance(shape, physx.PhysxCollisionShapeCylinder):
        return fcl.Cylinder(float(shape.radius) + margin, 2 * (float(shape.half_length) + margin))
    if isinstance(shape, physx.PhysxCollisionShapeConvexMesh):
        vertices = np.asarray(shape.vertices, np.float64) * np.asarray(shape.scale)
        out = vertices - vertices.mean(axis=0)
        norms = np.linalg.norm(out, axis=1, keepdims=True)
        vertices = vertices + margin * out / np.maximum(norms, 1e-9)
        faces = np.asarray(shape.triangles, np.int32)
        return fcl.Convex(vertices, faces, False)
    if isinstance(shape, physx.PhysxCollisionShapePlane):
        return None
    raise ValueError(f"no collision model for a {type(shape).__name__}")


_ALONG_Z = poses.pose_from_pq(np.zeros(3), np.array([np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0]))


def actor_shapes(actor, margin: float = 0.0) -> list[tuple[object, np.ndarray]]:
    """(FCL geometry grown by ``margin`` [m], 4x4 world pose) for each collision shape of a
    ManiSkill actor or articulation link."""
    import sapien.physx as physx
    from mplib.pymp.collision_detection import fcl

    entity = actor._objs[0]
    if isinstance(entity, physx.PhysxArticulationLinkComponent):
        entity = entity.entity
    body = entity.find_component_by_type(physx.PhysxRigidBaseComponent)
    if body is None:
        return []
    world = poses.pose_from_pq(np.asarray(entity.pose.p, np.float64),
                               np.asarray(entity.pose.q, np.float64))  # fmt: skip
    out = []
    for shape in body.collision_shapes:
        geometry = _geometry(shape, fcl, margin)
        if geometry is None:
            continue
        local = poses.pose_from_pq(np.asarray(shape.local_pose.p, np.float64),
                                   np.asarray(shape.local_pose.q, np.float64))  # fmt: skip
        if isinstance(shape, (physx.PhysxCollisionShapeCapsule,
                              physx.PhysxCollisionShapeCylinder)):  # fmt: skip
            local = local @ _ALONG_Z
        out.append((geometry, world @ local))
    return out


class TransitPlanner:
    """Plans transits for a ManiSkill Panda env (``u``: the unwrapped env)."""

    def __init__(self, u) -> None:
        import mplib

        agent = u.agent
        robot = agent.robot
        self._robot = robot
        self.planner = mplib.Planner(
            urdf=agent.urdf_path,
            srdf=agent.urdf_path.replace(".urdf", ".srdf"),
            user_link_names=[link.get_name() for link in robot.get_links()],
            user_joint_names=[j.get_name() for j in robot.get_active_joints()],
            move_group=MOVE_GROUP,
        )
        self.base = poses.pose_from_pq(
            robot.pose.p[0].numpy().astype(np.float64), robot.pose.q[0].numpy().astype(np.float64)
        )
        self.planner.set_base_pose(poses.pose_to_pq(self.base))
        self._model = self.planner.pinocchio_model
        self._world = self.planner.planning_world
        self._tcp = self.planner.link_name_2_idx[MOVE_GROUP]
        self._arm = np.asarray(self.planner.move_group_joint_indices)
        limits = np.asarray(self._model.get_joint_limits(), dtype=object)
        lo_hi = np.concatenate([np.asarray(x, np.float64).reshape(-1, 2) for x in limits])
        self.lower, self.upper = lo_hi[self._arm, 0], lo_hi[self._arm, 1]
        self._names: list[str] = []
        self._start = np.zeros(len(self._arm))
        self._start_contacts: set[tuple[str, str]] = set()
        self._full = np.zeros(len(lo_hi))

    # -- the scene ----------------------------------------------------------------------------
    def sync(
        self,
        actors: dict[str, object],
        held: dict[str, object],
        worked: set[str],
        clearance: float,
    ) -> None:
        """Put ``actors`` (name -> ManiSkill actor) into the planner's world as they are now,
        each grown by ``clearance`` [m] but those in ``worked`` (what the arm works on and
        with: the table, the objects subtasks refer to), and attach the ``held`` ones (at
        most one) to the TCP where they are relative to it."""
        from mplib.pymp.collision_detection import fcl

        for name in self._names:
            self._world.remove_normal_object(name)
        self._names = []
        for name, actor in actors.items():
            if name == GROUND or name in held:
                continue
            margin = 0.0 if name in worked else clearance
            for k, (geometry, pose) in enumerate(actor_shapes(actor, margin)):
                pq = poses.pose_to_pq(pose)
                self._world.set_normal_object(
                    f"{name}#{k}", fcl.CollisionObject(geometry, pq[:3], pq[3:])
                )
                self._names.append(f"{name}#{k}")
        self._world.remove_attach()
        self._world.set_use_attach(False)
        qpos = self._robot.get_qpos()[0].numpy().astype(np.float64)
        tcp = self.tcp_pose(qpos[self._arm])
        for actor in held.values():
            for geometry, pose in actor_shapes(actor)[:1]:
                in_tcp = poses.pose_to_pq(poses.pose_inv(tcp) @ pose)
                self.planner.update_attached_tool(geometry, in_tcp)
                self._world.set_use_attach(True)

    # -- kinematics -----------------------------------------------------------------------------
    def _set(self, arm_q: np.ndarray) -> None:
        self._full[self._arm] = arm_q
        self._world.set_qpos_all(arm_q)

    def tcp_pose(self, arm_q: np.ndarray) -> np.ndarray:
        """The TCP's world pose at arm joint positions ``arm_q`` (7,)."""
        full = self._full.copy()
        full[self._arm] = arm_q
        self._model.compute_forward_kinematics(full)
        pq = np.asarray(self._model.get_link_pose(self._tcp), np.float64)
        return self.base @ poses.pose_from_pq(pq[:3], pq[3:])

    def collisions(self, arm_q: np.ndarray) -> set[tuple[str, str]]:
        """The pairs (robot link or held object, other) in collision at ``arm_q``, the base
        link's left out."""
        self._set(arm_q)
        out = set()
        for c in self._world.collide_full():
            a = c.link_name1 or c.object_name1
            b = c.link_name2 or c.object_name2
            if BASE_LINK not in (a, b):
                out.add((a, b))
        return out

    def free(self, arm_q: np.ndarray) -> bool:
        """No contact at ``arm_q`` but, within ESCAPE of the start, those made there."""
        hits = self.collisions(arm_q)
        if hits and np.abs(arm_q - self._start).max() <= ESCAPE:
            hits -= self._start_contacts
        return not hits

    def ik(self, target: np.ndarray, start: np.ndarray, rng: np.random.Generator,
           tries: int) -> np.ndarray | None:  # fmt: skip
        """Collision-free arm joint positions putting the TCP at ``target`` (world), the one
        nearest ``start`` among the solutions from ``start`` and ``tries`` - 1 random seeds."""
        goal = poses.pose_to_pq(poses.pose_inv(self.base) @ target)
        best, best_d = None, np.inf
        for k in range(tries):
            q0 = self._full.copy()
            q0[self._arm] = start if k == 0 else rng.uniform(self.lower, self.upper)
            q = np.asarray(self._model.compute_IK_CLIK(self._tcp, goal, q0, [])[0])[self._arm]
            if np.any(q < self.lower) or np.any(q > self.upper):
                continue
            reached = self.tcp_pose(q)
            err = (
                np.linalg.norm(reached[:3, 3] - target[:3, 3])
                + poses.rotation_angle(reached[None, :3, :3], target[:3, :3])[0]
            )
            if err > IK_TOLERANCE or not self.free(q):
                continue
            d = float(np.abs(q - start).max())
            if d < best_d:
                best, best_d = q, d
        return best

    # -- planning ---------------------------------------------------------------------------------
    def plan(self, target: np.ndarray, settings: PlannerSettings,
             rng: np.random.Generator) -> tuple[np.ndarray | None, str]:  # fmt: skip
        """TCP world poses (K, 4, 4), one per control step, from the TCP's pose now to
        ``target``, and "" or why there is none ("ik", "start in collision", "no path").
        Contacts the arm makes where it starts are allowed within ESCAPE of the start; no
        other contact is."""
        start = self._robot.get_qpos()[0].numpy().astype(np.float64)[self._arm]
        self._start, self._start_contacts = start, self.collisions(start)
        goal = self.ik(target, start, rng, settings.ik_tries)
        if goal is None:
            return None, "ik"
        path = joint_path(start, goal, self.free, settings, rng, self.lower, self.upper)
        if path is None:
            return None, "no path"
        return np.stack([self.tcp_pose(q) for q in path]), ""
