"""Every task file of every back end: its spec is consistent with what its env provides
(signals, objects, observation keys), its reset variants sample inside the bounds that
coverage bins, and its docstring reads as ManiSkill's task docstrings do. Task files are
found by name, as the stages find them."""

from __future__ import annotations

import importlib
import inspect
import itertools
import math
import re

import numpy as np
import pytest

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.observations import observation_keys
from mimicgen_pipe.core.registry import choices

TASKS = [(b, t) for b in choices("mimicgen_pipe.backends") for t in backends.task_names(b)]
IDS = [f"{b}-{t}" for b, t in TASKS]


@pytest.mark.parametrize(("backend", "task"), TASKS, ids=IDS)
def test_spec_is_consistent(backend, task):
    spec = backends.task_spec(backend, task)
    assert spec.name == task and spec.paper_task, "a task says which paper task it stands for"
    assert "D0" in spec.variants
    assert set(spec.default_obs_keys) <= set(spec.provided_obs_keys)
    if len(spec.arms) == 1:
        assert spec.provided_obs_keys == observation_keys(spec.objects)
    for sub in spec.subtasks:
        assert sub.reference_object in spec.objects
    for name, variant in spec.reset_variants.items():
        for o in spec.objects:
            b = variant.bounds[o]
            assert b.x[0] < b.x[1] and b.y[0] < b.y[1] and b.yaw[0] <= b.yaw[1], (name, o)


# ManiSkill's task docstring headings (e.g. StackCube-v1's), then the spec's subtasks
HEADINGS = ("Task Description", "Randomizations", "Success Conditions", "Subtasks")


def _sections(doc: str) -> dict[str, str]:
    """The text under each ``**Heading:**`` line of ``doc``, by heading, in order."""
    parts = re.split(r"^\*\*(.+?):\*\*$", doc, flags=re.M)
    return dict(zip(parts[1::2], parts[2::2], strict=True))


def _bullets(section: str) -> list[str]:
    """The ``- `` items of a section, each with its continuation lines."""
    return [b.strip() for b in re.split(r"^- ", section, flags=re.M)[1:]]


@pytest.mark.parametrize(("backend", "task"), TASKS, ids=IDS)
def test_task_docstring_has_maniskills_headings_and_the_specs_subtasks(backend, task):
    """The task file's docstring has ManiSkill's headings and Subtasks, in this order; a
    bullet per reset variant under Randomizations, and one per subtask, in the spec's order,
    opening with its name and naming its reference object, its term signal (or that the demo
    ends it) and, with two arms, its arm."""
    spec = backends.task_spec(backend, task)
    module = importlib.import_module(f"mimicgen_pipe.tasks.{backend}.{task}")
    sections = _sections(inspect.cleandoc(module.__doc__ or ""))
    assert tuple(sections) == HEADINGS, module.__file__
    variants = {b.split(maxsplit=1)[0].rstrip(":") for b in _bullets(sections["Randomizations"])}
    assert set(spec.variants) <= variants, module.__file__
    bullets = _bullets(sections["Subtasks"])
    assert len(bullets) == len(spec.subtasks), module.__file__
    for sub, bullet in zip(spec.subtasks, bullets, strict=True):
        assert bullet.startswith(f"``{sub.name}``"), (module.__file__, sub.name)
        assert f"reference ``{sub.reference_object}``" in bullet, (module.__file__, sub.name)
        signal = f"ends when ``{sub.term_signal}``"
        ends = "ends with the demo" if sub.term_signal is None else signal
        assert ends in " ".join(bullet.split()), (module.__file__, sub.name)
        if spec.several_arms:
            assert f"arm ``{sub.arm}``" in bullet, (module.__file__, sub.name)


def test_lookups_name_the_valid_choices():
    with pytest.raises(
        InputError, match=r"backend 'mujoco': unknown \(known: maniskill, pybullet\)"
    ):
        backends.task_spec("mujoco", "stack")
    with pytest.raises(InputError, match=r"task 'stack_sphere': unknown .*known: .*stack_cube"):
        backends.task_spec("maniskill", "stack_sphere")
    spec = backends.task_spec("maniskill", "stack_cube")
    with pytest.raises(InputError, match=r"variant 'D7': unknown for task stack_cube \(known: D0"):
        backends.check_variant(spec, "D7")
    with pytest.raises(InputError, match=r"'peg_pos' not an observation of task stack_cube"):
        backends.check_obs_keys(spec, ["eef_pos", "peg_pos"], "train.obs_keys")


def _yaw(pose: np.ndarray) -> float:
    return math.atan2(pose[1, 0], pose[0, 0])


@pytest.mark.sim
@pytest.mark.parametrize(("backend", "task"), TASKS, ids=IDS)
def test_env_provides_the_spec_and_samples_inside_its_variants(backend, task):
    env = backends.make_env(backend, task)
    try:
        spec = env.spec
        assert set(spec.signals) <= set(env.subtask_signals()), "every term signal is provided"
        for name, variant in spec.reset_variants.items():
            for seed in range(12):
                env.reset(seed=seed, variant=name)
                poses = env.object_poses()
                assert set(poses) == set(spec.objects)
                for o, pose in poses.items():
                    b = variant.bounds[o]
                    assert b.x[0] - 1e-6 <= pose[0, 3] <= b.x[1] + 1e-6, (name, o, seed)
                    assert b.y[0] - 1e-6 <= pose[1, 3] <= b.y[1] + 1e-6, (name, o, seed)
                    yaw = (_yaw(pose) - b.yaw[0] + 1e-4) % (2 * math.pi) + b.yaw[0] - 1e-4
                    assert yaw <= b.yaw[1] + 1e-4 or b.yaw[1] - b.yaw[0] >= 2 * math.pi - 1e-6
                if not variant.native:
                    xy = [p[:2, 3] for p in poses.values()]
                    gaps = [np.linalg.norm(a - c) for i, a in enumerate(xy) for c in xy[i + 1 :]]
                    assert min(gaps, default=1.0) >= variant.min_distance - 1e-6
                    if variant.max_reach is not None:
                        base = env.controller.root_pose[:2, 3]  # the robot's base, world
                        reach = max(np.linalg.norm(p - base) for p in xy)
                        assert reach <= variant.max_reach + 1e-6
    finally:
        env.close()


@pytest.mark.sim
def test_a_task_frame_carries_the_source_scenes_hole_into_another_scene():
    """peg_insertion's box is reported in its hole's frame (ManiSkillTask.frames): in the
    source demos' scene its pose is the actor's, bit for bit; in O1's scene, where ManiSkill
    put the hole 2-4 cm elsewhere in the box, the reported pose puts the source scene's hole
    offset exactly onto O1's hole, so an insertion carried in the box's frame follows it."""
    from mimicgen_pipe.backends.maniskill.peg_in_hole import hole_frame
    from mimicgen_pipe.core.poses import pose_from_pq

    env = backends.make_env("maniskill", "peg_insertion")
    try:
        u = env.unwrapped
        source_hole = hole_frame(u)

        def actor() -> np.ndarray:
            p, q = u.box.pose.p.numpy()[0], u.box.pose.q.numpy()[0]
            return pose_from_pq(p.astype(np.float64), q.astype(np.float64))

        env.reset(seed=3, variant="D0")
        assert np.array_equal(env.object_poses()["box"], actor())
        env.reset(seed=3, variant="O1")
        o1_hole = hole_frame(u)
        assert np.abs(o1_hole[:3, 3] - source_hole[:3, 3]).max() > 0.02  # another hole
        reported = env.object_poses()["box"]
        np.testing.assert_allclose(reported @ source_hole, actor() @ o1_hole, atol=1e-9)
        env.reset(seed=3, variant="D0")  # back in the source scene: as read again
        assert np.array_equal(env.object_poses()["box"], actor())
    finally:
        env.close()


@pytest.mark.sim
def test_a_restored_state_brings_back_what_the_task_derived_at_reset():
    """PlugCharger keeps its goal pose outside the simulator's state (ManiSkill derives it
    from the receptacle at reset); a restored state gets the goal of its own scene, not the
    last reset's, so a stored episode is judged against the right goal."""
    env = backends.make_env("maniskill", "plug_charger")
    try:
        env.reset(seed=1, variant="D0")
        state, goal = env.get_state(), env.unwrapped.goal_pose.raw_pose.numpy().copy()
        env.reset(seed=2, variant="D0")
        assert np.abs(env.unwrapped.goal_pose.raw_pose.numpy() - goal).max() > 0.01
        env.set_state(state)
        np.testing.assert_allclose(env.unwrapped.goal_pose.raw_pose.numpy(), goal, atol=1e-7)
    finally:
        env.close()


def test_a_task_caps_the_action_noise_its_tolerances_take():
    import dataclasses

    plug = backends.task_spec("maniskill", "plug_charger")
    assert plug.action_noise(0.025) == 0.0
    assert backends.task_spec("maniskill", "peg_insertion").action_noise(0.025) == 0.025
    capped = dataclasses.replace(plug, max_action_noise=0.01)
    assert capped.action_noise(0.025) == 0.01 and capped.action_noise(0.005) == 0.005
    with pytest.raises(ValueError, match="max_action_noise"):
        dataclasses.replace(plug, max_action_noise=-0.01)


@pytest.mark.sim
def test_a_task_with_geometry_of_its_own_has_its_own_env_and_leaves_its_base_as_it_was():
    """peg_insertion_square sets PegInsertionSide's hole clearance to Square's 6.75 mm
    (ManiSkillTask.env_attributes) on an env class of its own; peg_insertion, built in the
    same process, keeps ManiSkill's 3 mm, and the square task's demonstrator records in the
    square task's env."""
    from mimicgen_pipe.backends.maniskill.source import demo_env_id
    from mimicgen_pipe.tasks.maniskill.peg_insertion_square import SQUARE_CLEARANCE

    square, stock = (
        backends.make_env("maniskill", t) for t in ("peg_insertion_square", "peg_insertion")
    )
    try:
        clearance = {
            name: float(e.unwrapped.box_hole_radii[0] - e.unwrapped.peg_half_sizes[0, 1])
            for name, e in (("square", square), ("stock", stock))
        }
        assert clearance["square"] == pytest.approx(SQUARE_CLEARANCE, abs=1e-6)
        assert clearance["stock"] == pytest.approx(0.003, abs=1e-6)
        ids = {e.task.env_id for e in (square, stock)}
        assert ids == {"MimicGenpeg_insertion_square-PegInsertionSide-v1",
                       "MimicGenPegInsertionSide-v1"}  # fmt: skip
        assert demo_env_id(square.task) == square.task.env_id
        assert demo_env_id(stock.task) == "PegInsertionSide-v1"
    finally:
        square.close()
        stock.close()


def test_stack_tower_counts_a_cube_on_another_only_at_one_cube_height():
    """stack_tower's "on" test (StackCube-v1's): centres within the half diagonal + 5 mm in
    xy and 4 cm ± 5 mm apart in z; A beside B (the pyramid's first step) is not on it."""
    from mimicgen_pipe.tasks.maniskill.stack_tower import HALF, _signals, on

    b = np.array([0.05, -0.02, HALF], np.float32)
    up = np.array([0.0, 0.0, 2 * HALF], np.float32)
    assert on(b + up, b) and on(b + up + [0.03, 0.0, 0.004], b)
    assert not on(b + up + [0.035, 0.0, 0.0], b)  # past the half diagonal + 5 mm
    assert not on(b + [2 * HALF + 0.003, 0.0, 0.0], b)  # beside, on the table
    assert not on(b + 2 * up, b) and not on(b, b + up)  # one cube too high; below it
    p = {"cubeA": b + up, "cubeB": b, "cubeC": b + 2 * up}
    free = {"cubeA": False, "cubeC": False}
    assert _signals(p, free)["cubeA_on_cubeB"]
    assert not _signals(p, free | {"cubeA": True})["cubeA_on_cubeB"]  # still held


@pytest.mark.sim
def test_stack_tower_reports_its_own_success_in_the_pyramids_scene():
    """stack_tower (own_success) has an env of its own beside stack_pyramid's in the same
    process, its demonstrator records there, and that env's success is the tower's: cubes
    set by hand as a pyramid (A beside B, C on both) fail it and pass stack_pyramid's test,
    which stack_pyramid keeps; as a tower they pass it."""
    from mani_skill.utils.structs.pose import Pose

    from mimicgen_pipe.backends.maniskill.source import demo_env_id
    from mimicgen_pipe.tasks.maniskill.stack_tower import HALF

    up, aside = np.array([0, 0, 2 * HALF], np.float32), np.array([2 * HALF + 0.003, 0, 0])
    arrangements = {"tower": (up, 2 * up), "pyramid": (aside, aside / 2 + up)}
    tower, pyramid = (backends.make_env("maniskill", t) for t in ("stack_tower", "stack_pyramid"))
    try:
        assert tower.task.env_id == "MimicGenstack_tower-StackPyramid-v1"
        assert pyramid.task.env_id == "MimicGenStackPyramid-v1"
        assert demo_env_id(tower.task) == tower.task.env_id
        results = {}
        for (name, e), (shape, (a, c)) in itertools.product(
            (("tower", tower), ("pyramid", pyramid)), arrangements.items()
        ):
            e.reset(seed=3, variant="D0")
            u = e.unwrapped
            b = u.cubeB.pose.p[0].numpy()
            q = np.array([1, 0, 0, 0], np.float32)[None]
            u.cubeB.set_pose(Pose.create_from_pq(p=b[None], q=q))
            for cube, offset in ((u.cubeA, a), (u.cubeC, c)):
                cube.set_pose(Pose.create_from_pq(p=(b + offset)[None].astype(np.float32), q=q))
            results[name, shape] = (bool(u.evaluate()["success"][0]), e.task.evaluate(u)["success"])
        assert results[("tower", "tower")] == (True, True)
        assert results[("tower", "pyramid")] == (False, False)
        assert results[("pyramid", "pyramid")] == (True, True)
    finally:
        tower.close()
        pyramid.close()


def test_a_task_version_is_recorded_from_two_on_and_data_of_another_is_refused(tmp_path):
    """Every task is at version 1, which stores record by saying nothing (their bytes as
    before versions); a task file raised to version 2 writes it into its generated stores'
    attributes, and the check that generate and train run on their input stores refuses
    data of version 1, naming the store."""
    import dataclasses

    from mimicgen_pipe.core.taskspec import check_task_version, version_record
    from mimicgen_pipe.data.params import Params
    from mimicgen_pipe.stages.generate import generated_attrs

    for backend in choices("mimicgen_pipe.backends"):
        for task in choices(f"mimicgen_pipe.tasks.{backend}"):
            spec = backends.task_spec(backend, task)
            assert spec.version == 1 and version_record(spec) == {}, task
    spec = backends.task_spec("maniskill", "stack_cube")
    v2 = dataclasses.replace(spec, version=2)
    source = {"robot": "panda", "control_mode": "pd_ee_delta_pose", "control_freq": 20}
    assert "task_version" not in generated_attrs("r", Params(), "D0", spec, source)
    assert generated_attrs("r", Params(), "D0", v2, source)["task_version"] == 2
    check_task_version({}, spec, "x.zarr")  # no record: version 1
    check_task_version({"task_version": 2}, v2, "x.zarr")
    with pytest.raises(InputError, match="data/parsed/stack_cube.zarr: made with version 1 of "
                       "task stack_cube, whose file is at version 2; re-run"):  # fmt: skip
        check_task_version({}, v2, "data/parsed/stack_cube.zarr")
