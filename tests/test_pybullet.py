"""The PyBullet back end and robot transfer: kinematics, controller, demonstrators,
determinism, replay, a small end-to-end run through the CLI, and bad input."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from mimicgen_pipe.core import poses
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.kinematics import forward_kinematics, inverse_kinematics
from tests.conftest import PYBULLET_STACK, cli, replay_first_episodes, stages_copied_to

pytest.importorskip("pybullet")

from mimicgen_pipe.backends.pybullet.robots import (  # noqa: E402
    HOME_TCP,
    ROBOTS,
    robot_chain,
    robot_spec,
    robot_urdf_text,
)

ARMS = list(ROBOTS)


@pytest.fixture(scope="module")
def chains():
    return {name: robot_chain(spec) for name, spec in ROBOTS.items()}


@pytest.mark.parametrize("arm", ARMS)
def test_forward_kinematics_matches_pytorch_kinematics(arm, chains):
    import pytorch_kinematics as pk
    import torch
    from pytorch_kinematics.urdf_parser_py.xml_reflection import core

    core.on_error = lambda message: None
    serial = pk.build_serial_chain_from_urdf(robot_urdf_text(ROBOTS[arm]), "panda_grasptarget")
    chain = chains[arm]
    q = np.random.default_rng(0).uniform(chain.lower, chain.upper, (16, chain.dof))
    ours, _ = forward_kinematics(chain, q)
    theirs = serial.to(dtype=torch.float64).forward_kinematics(torch.as_tensor(q)).get_matrix()
    np.testing.assert_allclose(ours, theirs.numpy(), atol=1e-9)


@pytest.mark.parametrize("arm", ARMS)
def test_ik_accuracy_on_random_reachable_poses(arm, chains):
    """Targets from random configurations around the home pose (the tabletop workspace),
    solved as one batch from the home configuration: < 1 mm and < 0.5 deg, every one."""
    chain = chains[arm]
    seed_q = np.asarray(robot_spec(arm).seed_q)
    home = inverse_kinematics(chain, HOME_TCP[None], seed_q, iterations=300, max_step=0.05).q[0]
    rng = np.random.default_rng(1)
    q_true = np.clip(home + rng.uniform(-0.6, 0.6, (200, chain.dof)), chain.lower, chain.upper)
    targets, _ = forward_kinematics(chain, q_true)
    restarts = np.repeat(home[None], 8, axis=0)
    restarts[:, -1] = np.linspace(chain.lower[-1] + 0.1, chain.upper[-1] - 0.1, 8)
    res = inverse_kinematics(chain, targets, home, iterations=200, restarts=restarts)
    assert res.converged.all(), f"{(~res.converged).sum()} of 200 not solved"
    achieved, _ = forward_kinematics(chain, res.q)
    pos_err = np.linalg.norm(achieved[:, :3, 3] - targets[:, :3, 3], axis=1)
    rot_err = poses.rotation_angle(achieved[:, :3, :3], targets[:, :3, :3])
    assert pos_err.max() < 1e-3
    assert np.rad2deg(rot_err.max()) < 0.5
    assert (res.q >= chain.lower - 1e-12).all() and (res.q <= chain.upper + 1e-12).all()


def test_ik_reports_unreachable_targets(chains):
    chain = chains["xarm6"]
    far = HOME_TCP.copy()
    far[0, 3] = 1.5  # beyond the xArm6's ~0.7 m reach
    res = inverse_kinematics(chain, np.stack([HOME_TCP, far]), np.zeros(chain.dof))
    assert res.converged.tolist() == [True, False]
    assert res.position_error[1] > 0.5


def test_missing_urdf_and_unknown_robot_are_input_errors():
    bad = dataclasses.replace(ROBOTS["iiwa"], urdf="kuka_iiwa/no_such_model.urdf")
    with pytest.raises(InputError, match="no_such_model.urdf: no such file"):
        robot_urdf_text(bad)
    with pytest.raises(InputError, match="robot 'ur5e': unknown for pybullet"):
        robot_spec("ur5e")


# -- simulator ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def stack_envs():
    from mimicgen_pipe.backends.pybullet.env import PyBulletEnv

    envs = {arm: PyBulletEnv("stack", arm) for arm in ARMS}
    yield envs
    for env in envs.values():
        env.close()


@pytest.mark.sim
@pytest.mark.parametrize("arm", ARMS)
def test_tcp_pose_matches_the_simulator(arm, stack_envs):
    env = stack_envs[arm]
    env.reset(seed=3, variant="D0")
    q = np.array([s[0] for s in env._sim.getJointStates(env._robot, env._arm)])
    tcp, _ = forward_kinematics(env.chain, q[None])
    np.testing.assert_allclose(env.controller.root_pose @ tcp[0], env.eef_pose(), atol=1e-5)


@pytest.mark.sim
@pytest.mark.parametrize("arm", ARMS)
def test_controller_round_trip_converges(arm, stack_envs):
    """target pose -> action -> achieved pose: a target 6 cm and 30 deg of yaw away is
    reached to < 2 mm and < 1 deg within 20 control steps."""
    env = stack_envs[arm]
    env.reset(seed=0, variant="D0")
    target = env.eef_pose().copy()
    target[:3, 3] += [0.04, -0.03, -0.03]
    yaw = np.deg2rad(30.0)
    rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    target[:3, :3] = rz @ target[:3, :3]
    for _ in range(20):
        env.step(env.target_pose_to_action(target, 1.0))
    eef = env.eef_pose()
    assert np.linalg.norm(eef[:3, 3] - target[:3, 3]) < 2e-3
    assert np.rad2deg(poses.rotation_angle(eef[:3, :3], target[:3, :3])) < 1.0
    # and the action a target implies is the one that leads back to it
    action = env.target_pose_to_action(target, 1.0)
    np.testing.assert_allclose(env.action_to_target_pose(action), target, atol=1e-9)


@pytest.mark.sim
@pytest.mark.parametrize("task", ["stack", "stack_three", "square_peg"])
def test_demonstrator_succeeds_and_is_deterministic(task):
    from mimicgen_pipe.backends.pybullet.demos import demonstrate
    from mimicgen_pipe.backends.pybullet.env import PyBulletEnv

    env = PyBulletEnv(task, "panda")
    demos = [demonstrate(env, seed) for seed in range(3)]
    assert sum(d.success for d in demos) >= 2
    again = demonstrate(env, 0)
    np.testing.assert_array_equal(again.actions, demos[0].actions)
    # human-like variation: demos differ in length, not only in where the objects are
    assert len({len(d.actions) for d in demos}) > 1
    env.close()


@pytest.fixture(scope="module")
def transfer_run(tmp_path_factory, pybullet_stack) -> Path:
    """Source demos on the Panda (PyBullet stack), parsed, then generated with the iiwa."""
    work = stages_copied_to(tmp_path_factory.mktemp("transfer"), pybullet_stack)
    (work / "params.yaml").write_text(PYBULLET_STACK + "generate: {workers: 1, seed: 3}\n")
    for robot in ("iiwa", "panda"):
        cli(
            "generate", "--robot", robot, "--variant", "D0", "--attempts", "8",
            "--parsed", "data/parsed/stack.zarr",
            "--out", f"data/generated/stack_D0_{robot}.zarr",
            "--metrics", f"metrics/generate_stack_D0_{robot}.json",
            cwd=work,
        )  # fmt: skip
    return work


@pytest.mark.sim
def test_transfer_end_to_end(transfer_run):
    from mimicgen_pipe.data.store import read_store

    for robot in ("iiwa", "panda"):
        m = json.loads((transfer_run / f"metrics/generate_stack_D0_{robot}.json").read_text())
        assert m["attempts"] == 8
        failures = m["ik_failures"] + m["failures_grasp_cubeA"] + m["failures_place_on_cubeB"]
        assert m["successes"] + failures == 8
        assert m["successes"] >= 3, m
        store = read_store(transfer_run / f"data/generated/stack_D0_{robot}.zarr", ["actions"])
        assert store.attrs["robot"] == robot and store.attrs["source_robot"] == "panda"
        assert store.attrs["backend"] == "pybullet"
        assert len(store.episode_ends) == m["successes"]


@pytest.mark.sim
def test_generated_episodes_succeed_when_replayed(transfer_run):
    from mimicgen_pipe.backends import make_env
    from mimicgen_pipe.data.store import read_store

    store = read_store(transfer_run / "data/generated/stack_D0_iiwa.zarr", ["actions"])
    # through make_env, which puts numpy's BLAS on one thread as the generating workers
    # had it; a PyBulletEnv made directly replays with the machine's thread count
    env = make_env("pybullet", "stack", "iiwa")
    for k, success in enumerate(replay_first_episodes(store, env, 3)):
        assert success, f"episode {k} failed on replay"
    env.close()


@pytest.mark.sim
def test_generation_is_deterministic(transfer_run):
    """The same seed gives the same dataset: generate again into another store."""
    from mimicgen_pipe.data.store import read_store

    cli(
        "generate", "--robot", "iiwa", "--variant", "D0", "--attempts", "8",
        "--parsed", "data/parsed/stack.zarr", "--out", "data/again/stack_D0_iiwa.zarr",
        "--metrics", "metrics/again.json", cwd=transfer_run,
    )  # fmt: skip
    a = read_store(transfer_run / "data/generated/stack_D0_iiwa.zarr", ["actions"])
    b = read_store(transfer_run / "data/again/stack_D0_iiwa.zarr", ["actions"])
    np.testing.assert_array_equal(np.asarray(a.data["actions"]), np.asarray(b.data["actions"]))
    np.testing.assert_array_equal(a.episode_ends, b.episode_ends)


@pytest.mark.sim
def test_unknown_robot_is_one_clear_error(transfer_run):
    res = cli(
        "generate", "--robot", "ur5e", "--variant", "D0", "--attempts", "2",
        "--parsed", "data/parsed/stack.zarr", "--out", "data/x.zarr", "--metrics", "m.json",
        cwd=transfer_run, check=False,
    )  # fmt: skip
    assert res.returncode == 2
    assert "robot 'ur5e': unknown for pybullet (known: panda, iiwa, xarm6)" in res.stderr
    assert not (transfer_run / "data/x.zarr").exists()


@pytest.mark.sim
def test_unreachable_workspace_is_one_clear_error(transfer_run, monkeypatch, capsys):
    """An arm whose base stands 3 m from the table: the workspace check stops generation
    before any attempt, naming the robot and the variant."""
    from mimicgen_pipe import backends
    from mimicgen_pipe.backends.pybullet.env import PyBulletEnv
    from mimicgen_pipe.cli import main

    monkeypatch.setattr(
        backends, "make_env", lambda backend, task, robot, *_: PyBulletEnv(task, robot, (-3.0, 0.0))
    )
    monkeypatch.chdir(transfer_run)
    code = main(
        ["generate", "--robot", "xarm6", "--variant", "D0", "--attempts", "4",
         "--parsed", "data/parsed/stack.zarr", "--out", "data/far.zarr", "--metrics", "far.json"]
    )  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    assert "robot 'xarm6' cannot reach the D0 workspace of stack" in err
    assert not (transfer_run / "data/far.zarr").exists()
