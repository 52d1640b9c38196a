"""drawer_cleanup: ManiSkill's StackPyramid-v1 three cubes and a cabinet with a drawer; no
paper task: it stands for the paper's long tasks with a drawer, Coffee Preparation and Mug
Cleanup.

**Task Description:**
Open the drawer, grasp the red cube A, put it in the drawer, close the drawer, grasp the
green cube B, stack it on the blue cube C. Six subtasks, each relative to one object; the
three drawer subtasks to the drawer.

The cabinet is an articulation built here from boxes: a fixed body 16 cm wide, 15 cm deep
and 8 cm tall, and a drawer that slides out of its front along a prismatic joint (0 to 12 cm;
damped, so that it stays where it is let go). The drawer is a tray 12 cm square inside with a
bar handle on its front. The task object ``drawer`` is the drawer's link: its frame is the
cabinet's at the joint's zero (the front face's centre at table level, x into the cabinet),
and moves out along its -x as the drawer opens.

**Randomizations:**
World frame: the table centre is the origin, the Panda base at x = -0.615 m; positions in
metres, yaw about world z in radians. The drawer is closed, the cabinet's front faces the
robot, turned by the drawer's yaw (yaw 0: opening towards -x); the cubes lie right of the
cabinet (y < 0), their yaw uniform over a full turn. In every variant the object centres
are at least 0.08 m apart and at most 0.76 m horizontally from the Panda's base (its
top-down reach; D0's boxes lie within it).
- D0 (the source demos'): the cabinet at x in [0.0, 0.05], y in [0.18, 0.22], yaw in
  [-0.1, 0.1]; each cube in x in [-0.12, 0.08], y in [-0.25, -0.02].
- D1: the cabinet at x in [-0.05, 0.1], y in [0.16, 0.26], yaw in [-0.3, 0.3]; each cube in
  x in [-0.2, 0.15], y in [-0.3, -0.02].
- D2: the cabinet at x in [-0.1, 0.15], y in [0.15, 0.3], yaw in [-0.5, 0.5]; each cube in
  x in [-0.3, 0.2], y in [-0.35, -0.02].

**Success Conditions:**
The task's own (its env reports it):
- the drawer is shut (open by at most 1 cm) and not grasped;
- cube A is inside the drawer's tray and not grasped;
- cube B is on cube C (centres within the cubes' half diagonal + 5 mm, 3.3 cm, in xy and
  4 cm +- 5 mm apart in z), static (below 1 cm/s and 0.5 rad/s) and not grasped.

**Subtasks:**
A drawer signal also needs the handle let go and the TCP at least 5 cm from its centre.
- ``open_drawer``, reference ``drawer``: ends when ``drawer_open`` turns true: the drawer
  open by 8 cm or more.
- ``grasp_cubeA``, reference ``cubeA``: ends when ``grasp_cubeA`` (the agent's
  ``is_grasping``) turns true.
- ``place_in_drawer``, reference ``drawer``: ends when ``cubeA_in_drawer`` turns true: A's
  centre inside the tray, A released.
- ``close_drawer``, reference ``drawer``: ends when ``drawer_closed`` turns true: the drawer
  open by at most 1 cm.
- ``grasp_cubeB``, reference ``cubeB``: ends when ``grasp_cubeB`` turns true.
- ``place_on_cubeC``, reference ``cubeC``: ends with the demo.
"""

from __future__ import annotations

import numpy as np

from mimicgen_pipe.backends.maniskill.tasks import FULL_YAW, PANDA_REACH, ManiSkillTask
from mimicgen_pipe.core.taskspec import ObjectBounds, ResetVariant, SubtaskSpec, TaskSpec

OBJECTS = ("drawer", "cubeA", "cubeB", "cubeC")
HALF = 0.02  # [m] the cubes' half size
F32 = np.float32
TRAVEL = 0.12  # [m] the drawer's joint range
PULL = 0.11  # [m] how far the demonstrator opens the drawer
OPEN = 0.08  # [m] open enough for a cube (the "drawer_open" signal)
CLOSED = 0.01  # [m] shut (the "drawer_closed" signal and success)
LIFT = 0.1  # [m] the hand rises after each grasp and each release
ABOVE = 0.15  # [m] a held cube comes down onto its spot from this high: over the handle
# the drawer's link, in its own frame [m] (x into the cabinet, z up from the table)
TRAY_INSIDE = ((0.0, 0.12), (-0.055, 0.055), (0.012, 0.06))  # x, y, z of the space inside
# the bar's centre; the bar runs along y, above the front, so that the hand grasping it from
# above stays clear of the cabinet's top
HANDLE = np.array([-0.005, 0.0, 0.115])
STACKED = np.linalg.norm(np.full(2, HALF, F32)) + F32(0.005)  # ManiSkill's "on" test, xy
# [m] the hand counts as gone from the drawer this far from the handle's centre: a drawer
# subtask ends only then, so that the transit to the next subtask's first pose, a straight
# line, starts clear of the handle instead of dragging the drawer with the open fingers
CLEAR = 0.05


def _box(link, centre, half, colour, name: str) -> None:
    import sapien

    pose = sapien.Pose(p=list(centre))
    link.add_box_collision(pose=pose, half_size=list(half))
    link.add_box_visual(
        pose=pose,
        half_size=list(half),
        material=sapien.render.RenderMaterial(base_color=colour),
        name=name,
    )


def load_scene(env) -> None:
    """Add the cabinet (an articulation: the fixed body and the drawer on a prismatic joint)
    to StackPyramid-v1's scene, as ``env.cabinet`` and its drawer link ``env.drawer``."""
    import sapien

    wood, tray, metal = [0.6, 0.45, 0.3, 1.0], [0.8, 0.7, 0.55, 1.0], [0.3, 0.3, 0.32, 1.0]
    builder = env.scene.create_articulation_builder()
    body = builder.create_link_builder()
    body.set_name("body")
    _box(body, (0.075, 0.0, 0.074), (0.075, 0.08, 0.006), wood, "top")
    for side in (1, -1):
        _box(body, (0.075, side * 0.074, 0.04), (0.075, 0.006, 0.04), wood, f"side{side}")
    _box(body, (0.144, 0.0, 0.04), (0.006, 0.068, 0.04), wood, "back")
    drawer = builder.create_link_builder(body)
    drawer.set_name("drawer")
    # the joint's x axis turned half round: the drawer's q moves it along the body's -x
    turn = sapien.Pose(q=[0.0, 0.0, 0.0, 1.0])
    drawer.set_joint_properties(
        "prismatic", limits=[[0.0, TRAVEL]], pose_in_parent=turn, pose_in_child=turn, damping=20.0
    )
    drawer.set_joint_name("drawer_slide")
    _box(drawer, (0.06, 0.0, 0.007), (0.065, 0.064, 0.005), tray, "bottom")
    for side in (1, -1):
        _box(drawer, (0.065, side * 0.06, 0.035), (0.06, 0.004, 0.023), tray, f"wall{side}")
    _box(drawer, (0.121, 0.0, 0.035), (0.004, 0.056, 0.023), tray, "rear")
    _box(drawer, (-0.005, 0.0, 0.04), (0.005, 0.08, 0.038), wood, "front")
    for side in (1, -1):  # the bar's two posts, up from the front's top
        post = (HANDLE[0], side * 0.045, (HANDLE[2] + 0.078) / 2)
        _box(drawer, post, (0.005, 0.005, (HANDLE[2] - 0.078) / 2), metal, f"post{side}")
    _box(drawer, HANDLE, (0.0075, 0.05, 0.0075), metal, "handle")
    builder.initial_pose = sapien.Pose(p=[0.3, 0.4, 0.0])
    env.cabinet = builder.build(name="cabinet", fix_root_link=True)
    env.drawer = env.cabinet.links_map["drawer"]


def initialize(env, env_idx, variant: ResetVariant) -> None:
    import torch

    from mimicgen_pipe.backends.maniskill.env import draw_planar, set_planar_poses

    env.table_scene.initialize(env_idx)
    xy, yaw = draw_planar(variant, OBJECTS, len(env_idx), TASK.robot_base_xy)
    # the drawer's pose is the cabinet's while it is shut
    actors = [env.cabinet, env.cubeA, env.cubeB, env.cubeC]
    set_planar_poses(actors, xy, yaw, [0.0, HALF, HALF, HALF])
    env.cabinet.set_qpos(torch.zeros(len(env_idx), 1))
    env.cabinet.set_qvel(torch.zeros(len(env_idx), 1))


def _in_drawer(cube: np.ndarray, drawer: tuple[np.ndarray, np.ndarray]) -> bool:
    """A cube's centre ``cube`` (world) inside the drawer's tray, the drawer's pose (p, q)."""
    from mimicgen_pipe.backends.maniskill import lean

    local = lean.quat_apply(lean.quat_invert(drawer[1]), (cube - drawer[0]).astype(F32))
    return all(lo <= v <= hi for v, (lo, hi) in zip(local, TRAY_INSIDE, strict=True))


def _hand_clear(tcp: np.ndarray, drawer: tuple[np.ndarray, np.ndarray]) -> bool:
    """Whether the TCP ``tcp`` (world) is CLEAR or farther from the handle's centre, the
    drawer's pose (p, q)."""
    from mimicgen_pipe.backends.maniskill import lean

    handle = drawer[0] + lean.quat_apply(drawer[1], HANDLE.astype(F32))
    return bool(np.linalg.norm(tcp - handle) >= CLEAR)


def _signals(opening: float, p: dict, grasped: dict[str, bool]) -> dict[str, bool]:
    """The subtask signals from the drawer's opening [m], world poses ``p`` (cubes' centres,
    the drawer's (p, q), the TCP's position) and which objects the hand grasps. The drawer
    signals need the hand let go of the handle and gone from it (CLEAR)."""
    free = not grasped["drawer"] and _hand_clear(p["tcp"], p["drawer"])
    return {
        "drawer_open": opening >= OPEN and free,
        "grasp_cubeA": grasped["cubeA"],
        "cubeA_in_drawer": _in_drawer(p["cubeA"], p["drawer"]) and not grasped["cubeA"],
        "drawer_closed": opening <= CLOSED and free,
        "grasp_cubeB": grasped["cubeB"],
    }


def _opening(env) -> float:
    return float(env.cabinet._objs[0].qpos[0])


def signals(env, info: dict) -> dict[str, bool]:
    p = {o: getattr(env, o).pose.p.numpy()[0] for o in ("cubeA", "cubeB", "cubeC")}
    p["drawer"] = (env.drawer.pose.p.numpy()[0], env.drawer.pose.q.numpy()[0])
    p["tcp"] = env.agent.tcp.pose.p.numpy()[0]
    grasped = {
        o: bool(env.agent.is_grasping(getattr(env, o))) for o in ("drawer", "cubeA", "cubeB")
    }
    return _signals(_opening(env), p, grasped)


def evaluate(env) -> dict[str, bool]:
    from mimicgen_pipe.backends.maniskill import lean

    p = {o: lean.pose(getattr(env, o))[0] for o in ("cubeA", "cubeB", "cubeC")}
    p["drawer"] = lean.pose(env.drawer)
    p["tcp"] = lean.pose(env.agent.tcp)[0]
    grasped = {o: lean.is_grasping(env, getattr(env, o)) for o in ("drawer", "cubeA", "cubeB")}
    opening = _opening(env)
    out = _signals(opening, p, grasped)
    offset = p["cubeB"] - p["cubeC"]
    on = bool(np.linalg.norm(offset[:2]) <= STACKED and abs(offset[2] - 2 * HALF) <= F32(0.005))
    b_free = lean.is_static(env.cubeB, lin_thresh=1e-2, ang_thresh=0.5) and not grasped["cubeB"]
    a_kept = _in_drawer(p["cubeA"], p["drawer"]) and not grasped["cubeA"]
    out["success"] = bool(opening <= CLOSED and not grasped["drawer"] and a_kept and on and b_free)
    return out


def solve(env, seed: int | None = None):
    """The source demonstrator: one planned demo on ManiSkill's ``pd_joint_pos`` env from
    reset ``seed``; ManiSkill's solution convention (the last step's result, or -1 where a
    motion cannot be planned or a grasp slips)."""
    import sapien
    from mani_skill.examples.motionplanning.base_motionplanner.utils import (
        compute_grasp_info_by_obb,
        get_actor_obb,
    )
    from mani_skill.examples.motionplanning.panda.motionplanner import (
        PandaArmMotionPlanningSolver,
    )
    from transforms3d.euler import euler2quat

    env.reset(seed=seed)
    u = env.unwrapped
    planner = PandaArmMotionPlanningSolver(
        env,
        vis=False,
        base_pose=u.agent.robot.pose,
        visualize_target_grasp_pose=False,
        print_env_info=False,
    )
    down = np.array([0.0, 0.0, -1.0])

    last: list = [-1]  # the last step's result

    def moves(*targets) -> bool:
        for target in targets:
            last[0] = planner.move_to_pose_with_screw(target)
            if last[0] == -1:  # no straight screw motion: a planned one
                last[0] = planner.move_to_pose_with_RRTConnect(target)
            if last[0] == -1:
                return False
        return True

    def lift() -> bool:
        return moves(sapien.Pose([0, 0, LIFT]) * u.agent.tcp.pose.sp)

    def grasp(actor) -> bool:
        closing = u.agent.tcp.pose.to_transformation_matrix()[0, :3, 1].cpu().numpy()
        info = compute_grasp_info_by_obb(
            get_actor_obb(actor), approaching=down, target_closing=closing, depth=0.025
        )
        pose = u.agent.build_grasp_pose(down, info["closing"], info["center"])
        if not moves(pose * sapien.Pose([0, 0, -0.05]), pose):
            return False
        planner.close_gripper()
        return bool(u.agent.is_grasping(actor).item()) and lift()

    def slide(distance: float) -> bool:
        """Grasp the handle, move the drawer ``distance`` out (negative: in), let go, rise."""
        drawer = u.drawer.pose.sp
        axis = drawer.to_transformation_matrix()[:3, 0]  # the drawer's x: into the cabinet
        closing = (
            axis
            if float(axis @ u.agent.tcp.pose.sp.to_transformation_matrix()[:3, 1]) >= 0
            else -axis
        )
        pose = u.agent.build_grasp_pose(down, closing, (drawer * sapien.Pose(HANDLE)).p)
        if not moves(pose * sapien.Pose([0, 0, -0.06]), pose):
            return False
        planner.close_gripper()
        if not u.agent.is_grasping(u.drawer).item():
            return False
        if not moves(sapien.Pose(pose.p - distance * axis, pose.q)):
            return False
        planner.open_gripper()
        return lift()

    def place(actor, p: np.ndarray, q: np.ndarray, turns: tuple[int, ...]) -> bool:
        """The held ``actor`` put down with its centre at ``p`` and the yaw of ``q`` turned by
        one of ``turns`` quarter turns (the one nearest the hand's present orientation), let
        go, and the hand risen."""
        tcp = u.agent.tcp.pose.sp
        to_tcp = actor.pose.sp.inv() * tcp
        goals = [
            sapien.Pose(p, q) * sapien.Pose(q=euler2quat(0, 0, k * np.pi / 2)) * to_tcp
            for k in turns
        ]
        goal = max(goals, key=lambda g: abs(float(np.dot(g.q, tcp.q))))
        above = sapien.Pose(goal.p + [0, 0, ABOVE], goal.q)
        if not moves(above, sapien.Pose(goal.p + [0, 0, 0.004], goal.q)):
            return False
        planner.open_gripper()
        return lift()

    ok = slide(PULL) and grasp(u.cubeA)
    if ok:
        drawer = u.drawer.pose.sp
        spot = drawer * sapien.Pose([PULL / 2, 0.0, TRAY_INSIDE[2][0] + HALF])
        # the fingers close across the tray's width (along the drawer's y): two yaws
        ok = place(
            u.cubeA,
            spot.p,
            drawer.q,
            (0, 2) if _fingers_along_y(u.agent.tcp.pose.sp, u.cubeA.pose.sp) else (1, 3),
        )
    # pushed in a little past its travel back: shut against the joint's stop
    ok = ok and slide(-float(u.cabinet.qpos[0, 0]) - 0.005) and grasp(u.cubeB)
    if ok:
        c = u.cubeC.pose.sp
        ok = place(u.cubeB, c.p + [0, 0, 2 * HALF], c.q, (0, 1, 2, 3))
    planner.close()
    return last[0] if ok else -1


def _fingers_along_y(tcp, cube) -> bool:
    """Whether the fingers close along the held cube's own y axis."""
    closing = tcp.to_transformation_matrix()[:3, 1]
    return abs(float(closing @ cube.to_transformation_matrix()[:3, 1])) > 0.7


def _variant(cabinet: ObjectBounds, x: tuple[float, float], y: tuple[float, float]) -> ResetVariant:
    cube = ObjectBounds(x, y, FULL_YAW)
    return ResetVariant(
        {"drawer": cabinet, "cubeA": cube, "cubeB": cube, "cubeC": cube},
        min_distance=0.08,
        max_reach=PANDA_REACH,
    )


TASK = ManiSkillTask(
    spec=TaskSpec(
        name="drawer_cleanup",
        objects=OBJECTS,
        subtasks=(
            SubtaskSpec("open_drawer", "drawer", "drawer_open", (10, 15)),
            SubtaskSpec("grasp_cubeA", "cubeA", "grasp_cubeA", (20, 25)),
            SubtaskSpec("place_in_drawer", "drawer", "cubeA_in_drawer", (10, 15)),
            SubtaskSpec("close_drawer", "drawer", "drawer_closed", (10, 15)),
            SubtaskSpec("grasp_cubeB", "cubeB", "grasp_cubeB", (20, 25)),
            SubtaskSpec("place_on_cubeC", "cubeC", None),
        ),
        reset_variants={
            "D0": _variant(
                ObjectBounds((0.0, 0.05), (0.18, 0.22), (-0.1, 0.1)), (-0.12, 0.08), (-0.25, -0.02)
            ),
            "D1": _variant(
                ObjectBounds((-0.05, 0.1), (0.16, 0.26), (-0.3, 0.3)), (-0.2, 0.15), (-0.3, -0.02)
            ),
            "D2": _variant(
                ObjectBounds((-0.1, 0.15), (0.15, 0.3), (-0.5, 0.5)), (-0.3, 0.2), (-0.35, -0.02)
            ),
        },
        horizon=1000,
        paper_task="Coffee Preparation",  # the paper's long task with a drawer
    ),
    base_env_id="StackPyramid-v1",
    objects={o: o for o in OBJECTS},
    signals=signals,
    evaluate=evaluate,
    initialize=initialize,
    planner=solve,
    load_scene=load_scene,
)
