"""Pose-noise injection (paper T), support coverage (paper Q) and the report."""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np
import pytest

from mimicgen_pipe.core import poses
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.taskspec import ObjectBounds, ResetVariant, SubtaskSpec, TaskSpec
from mimicgen_pipe.data.params import load_params
from mimicgen_pipe.data.store import read_store
from mimicgen_pipe.method.coverage import reset_bounds, support_coverage, uniform_coverage
from mimicgen_pipe.method.pose_noise import (
    PoseNoise,
    generation_rng,
    perturb_pose,
    pose_noise_level,
)
from tests.test_cli_errors import run_bad

REPO = Path(__file__).resolve().parents[1]
PAPER = REPO / "reference/paper_results.yaml"


def run_stage(stage, *argv) -> None:
    """Run a stage module in-process with arguments parsed by its own parser."""
    parser = argparse.ArgumentParser()
    stage.add_arguments(parser)
    stage.run(stage.resolve(parser.parse_args([str(a) for a in argv])))


def random_poses(rng, n):
    return poses.pose_from_pq(rng.uniform(-0.5, 0.5, (n, 3)), rng.standard_normal((n, 4)))


# --- pose noise ---------------------------------------------------------------------------


def test_perturbed_poses_are_uniform_within_the_level():
    rng = np.random.default_rng(0)
    clean = random_poses(rng, 4000)
    noise = pose_noise_level("L2")
    assert noise == PoseNoise(0.010, math.radians(10))
    noisy = perturb_pose(clean, noise, np.random.default_rng(1))
    dpos = noisy[:, :3, 3] - clean[:, :3, 3]
    angle = poses.rotation_angle(clean[:, :3, :3], noisy[:, :3, :3])
    assert np.abs(dpos).max() <= 0.010 and np.abs(dpos).max() > 0.0099
    # uniform per axis: mean |d| is half the bound
    np.testing.assert_allclose(np.abs(dpos).mean(axis=0), 0.005, rtol=0.05)
    assert angle.max() <= math.radians(10) + 1e-9 and angle.max() > math.radians(9.9)
    np.testing.assert_allclose(angle.mean(), math.radians(5), rtol=0.05)
    # still rigid transforms, and the same seed gives the same noise
    rot = noisy[:, :3, :3]
    np.testing.assert_allclose(
        rot @ rot.swapaxes(1, 2), np.broadcast_to(np.eye(3), rot.shape), atol=1e-12
    )
    np.testing.assert_array_equal(noisy, perturb_pose(clean, noise, np.random.default_rng(1)))


def test_no_noise_is_the_identity_and_draws_nothing():
    rng = np.random.default_rng(3)
    clean = random_poses(rng, 5)
    state = rng.bit_generator.state
    np.testing.assert_array_equal(perturb_pose(clean, pose_noise_level("none"), rng), clean)
    assert rng.bit_generator.state == state
    assert pose_noise_level([7.5, 3]) == PoseNoise(0.0075, math.radians(3))


@pytest.mark.parametrize(
    "text,needle",
    [
        (
            "pose_noise: {level: L3}",
            "pose_noise.level: expected one of none, L1, L2 or [position_mm, rotation_deg], "
            "got 'L3'",
        ),
        ("pose_noise: {level: [5]}", "pose_noise.level: expected one of none, L1, L2"),
        ("pose_noise: {level: [5, x]}", "pose_noise.level: expected one of none, L1, L2"),
        ("pose_noise: {level: 5}", "pose_noise.level: expected one of none, L1, L2"),
        ("pose_noise: {level: [-1, 5]}", "pose_noise.level: expected position_mm in [0, 1000]"),
        ("coverage: {bins: 0}", "coverage.bins: expected a value in [1, 100], got 0"),
    ],
)
def test_bad_pose_noise_level_or_bins_name_the_key(tmp_path, text, needle):
    (tmp_path / "params.yaml").write_text(text)
    with pytest.raises(InputError) as err:
        load_params(tmp_path / "params.yaml")
    assert needle in str(err.value)


def test_a_bad_level_stops_the_stage_before_any_work(tmp_path):
    msg = run_bad(tmp_path, "pose_noise", params="pose_noise: {level: 5mm}\n")
    assert "params.yaml: pose_noise.level: expected one of none, L1, L2" in msg


# --- coverage -----------------------------------------------------------------------------


def planar(x, y, yaw):
    t = np.eye(4)
    t[:3, :3] = poses.axis_angle_to_matrix(np.array([0.0, 0.0, yaw]))
    t[:2, 3] = x, y
    return t


def test_support_coverage_bins_positions_and_wraps_yaw():
    b = ObjectBounds((0.0, 3.0), (0.0, 3.0), (0.0, 2 * math.pi))
    episodes = np.array(
        [
            [planar(0.5, 0.5, 0.1), planar(2.5, 2.5, 0.1)],
            # yaw -0.1 is 2 pi - 0.1: the last yaw bin; x on the upper bound: the last x bin
            [planar(0.5, 0.5, -0.1), planar(3.0, 1.5, math.pi)],
            [planar(0.5, 0.5, 0.1), planar(2.5, 2.5, 0.1)],  # a repeat: no new bin
            [planar(3.5, 0.5, 0.1), planar(1.5, 1.5, 0.1)],  # outside: edge bin, counted
        ]
    )
    cov = support_coverage(episodes, [b, b], bins=3)
    assert cov.counts.shape == (2, 3, 3, 3) and cov.counts.sum() == 8
    assert cov.counts[0, 0, 0, 0] == 2 and cov.counts[0, 0, 0, 2] == 1
    assert cov.counts[1, 2, 2, 0] == 2 and cov.counts[1, 2, 1, 1] == 1
    assert cov.counts[0, 2, 0, 0] == 1 and cov.outside == 1
    np.testing.assert_allclose(cov.object_coverage, [100 * 3 / 27, 100 * 3 / 27])
    assert (cov.joint_filled, cov.joint_total) == (3, 729)
    assert support_coverage(episodes, [b, b], bins=1).joint_coverage == 100.0


def test_uniform_coverage_is_the_expected_share_of_filled_bins():
    rng = np.random.default_rng(0)
    filled = [len(np.unique(rng.integers(729, size=1000))) / 729 for _ in range(200)]
    assert abs(uniform_coverage(1000, 729) - 100 * np.mean(filled)) < 0.5
    assert uniform_coverage(5, 1) == 100.0 and uniform_coverage(0, 27) == 0.0


def test_reset_bounds_missing_from_the_task_spec_are_one_clear_error():
    b = ObjectBounds((0, 1), (0, 1), (0, 1))
    subtasks = (SubtaskSpec("s", "a", "sig"), SubtaskSpec("e", "b", None))
    spec = TaskSpec("t", ("a", "b"), subtasks, {"D0": ResetVariant({"a": b, "b": b})}, 10)
    assert reset_bounds(spec, "D0") == [b, b]
    with pytest.raises(InputError, match="no reset bounds for variant 'D2'"):
        reset_bounds(spec, "D2")
    with pytest.raises(ValueError, match="variant D1 lacks bounds of"):
        TaskSpec("t", ("a", "b"), subtasks, {"D1": ResetVariant({"a": b})}, 10)


# --- stages on the simulator --------------------------------------------------------------


@pytest.mark.sim
def test_generation_sees_noisy_poses_and_records_true_ones(pipeline, tmp_path):
    """pose_noise perturbs only the object poses of a new store; generate transforms segments
    with the perturbed source pose and a perturbed new-scene pose drawn from the attempt's
    pose-noise stream, and records the simulator's true poses."""
    from mimicgen_pipe.stages import generate, pose_noise

    parsed = pipeline / "data/parsed/stack_cube.zarr"
    before = read_store(parsed)
    params = tmp_path / "params.yaml"
    params.write_text(
        "task: stack_cube\npose_noise: {level: L2, seed: 3}\n"
        "generate: {mode: fixed_attempts, max_attempts: 1, workers: 1, seed: 7}\n"
    )
    noisy_path = tmp_path / "pose_noise.zarr"
    run_stage(pose_noise, "--params", params, "--parsed", parsed, "--out", noisy_path)
    noisy = read_store(noisy_path)
    for key, value in before.data.items():
        same = np.array_equal(noisy.data[key], value)
        assert same != key.startswith("object_poses/"), key
    after = read_store(parsed).data["object_poses/cubeA"]
    np.testing.assert_array_equal(after, before.data["object_poses/cubeA"])  # clean untouched
    dpos = noisy.data["object_poses/cubeA"][:, :3] - before.data["object_poses/cubeA"][:, :3]
    assert 0.005 < np.abs(dpos).max() <= 0.010

    out = tmp_path / "gen.zarr"
    run_stage(
        generate, "--params", params, "--variant", "D1", "--parsed", noisy_path,
        "--out", out, "--metrics", tmp_path / "m.json",
    )  # fmt: skip
    gen = [s for s in (read_store(out), read_store(tmp_path / "gen_failed.zarr")) if s.n_episodes]
    gen = gen[0]
    true_cube = gen.poses("initial_object_poses")[0, 0]
    np.testing.assert_allclose(gen.poses("object_poses/cubeA")[0], true_cube, atol=1e-6)
    pose_rng = generation_rng(int(gen.episodes["seed"][0]))
    seen_cube = perturb_pose(true_cube, pose_noise_level("L2"), pose_rng)
    demo = int(gen.episodes["source_demo"][0, 0])
    s0 = noisy.episode_starts[demo]
    src_rel = poses.pose_inv(noisy.poses("object_poses/cubeA")[s0]) @ noisy.poses("target_pose")[s0]
    target = gen.poses("target_pose")[5]  # after n_interp=5 interpolation poses
    np.testing.assert_allclose(poses.pose_inv(seen_cube) @ target, src_rel, atol=1e-6)
    assert np.abs(poses.pose_inv(true_cube) @ target - src_rel).max() > 1e-3
    assert gen.attrs["params"]["pose_noise"]["level"] == "L2"

    # the same source demos at another level are refused before any work
    params.write_text(params.read_text().replace("L2", "L1"))
    with pytest.raises(InputError, match="source demos carry pose noise 10 mm / 10 deg"):
        run_stage(
            generate, "--params", params, "--variant", "D1", "--parsed", noisy_path,
            "--out", tmp_path / "refused.zarr", "--metrics", tmp_path / "refused.json",
        )  # fmt: skip
    assert not (tmp_path / "refused.zarr").exists()


@pytest.mark.sim
def test_coverage_and_report_stages_on_the_pipeline(pipeline, tmp_path):
    from mimicgen_pipe.stages import coverage, report

    metrics = tmp_path / "metrics"
    metrics.mkdir()
    (metrics / "generate_stack_cube_D1.json").write_bytes(
        (pipeline / "metrics/generate_stack_cube_D1.json").read_bytes()
    )
    plots = tmp_path / "plots"
    run_stage(coverage, "--params", pipeline / "params.yaml", "--variant", "D1",
              "--generated", pipeline / "data/generated/stack_cube_D1.zarr",
              "--metrics", metrics / "coverage_stack_cube_D1.json",
              "--table", plots / "coverage_stack_cube_D1.csv",
              "--heatmap", plots / "coverage_stack_cube_D1.png")  # fmt: skip
    kept = read_store(pipeline / "data/generated/stack_cube_D1.zarr").n_episodes
    failed = read_store(pipeline / "data/generated/stack_cube_D1_failed.zarr").n_episodes
    rows = list(csv.DictReader((plots / "coverage_stack_cube_D1.csv").open()))
    assert len(rows) == 2 * 27
    for obj in ("cubeA", "cubeB"):
        mine = [r for r in rows if r["object"] == obj]
        assert sum(int(r["generated"]) for r in mine) == kept
        assert sum(int(r["attempted"]) for r in mine) == kept + failed
    import json

    m = json.loads((metrics / "coverage_stack_cube_D1.json").read_text())
    filled = sum(int(r["generated"]) > 0 for r in rows if r["object"] == "cubeA")
    assert m["support_coverage_cubeA"] == pytest.approx(100 * filled / 27)
    assert (m["episodes"], m["attempts"], m["outside_bounds"]) == (kept, kept + failed, 0)
    assert (plots / "coverage_stack_cube_D1.png").read_bytes()[:4] == b"\x89PNG"

    out = tmp_path / "report"
    run_stage(report, "--params", pipeline / "params.yaml", "--metrics", metrics, "--plots", plots,
              "--paper", PAPER, "--out", out)  # fmt: skip
    md = (out / "report.md").read_text()
    assert "![initial object positions, stack_cube D1](../plots/coverage_stack_cube_D1.png)" in md
    assert not (out / "coverage_stack_cube_D1.png").exists()  # linked where coverage wrote it
    assert f"| D1 | 3 | {kept} / {kept + failed} | {m['support_coverage_joint']:.1f} |" in md
    assert "data:image/png;base64," in (out / "report.html").read_text()


def test_a_fixed_yaw_counts_as_one_bin():
    """An object whose reset does not vary its yaw (e.g. PullCubeTool's tool in D0) has
    bins**2 object bins, and the joint total shrinks with it."""
    fixed = ObjectBounds((0.0, 1.0), (0.0, 1.0), (0.3, 0.3))
    free = ObjectBounds((0.0, 1.0), (0.0, 1.0), (0.0, 2 * math.pi))
    rng = np.random.default_rng(0)
    poses = np.tile(np.eye(4), (200, 2, 1, 1))
    poses[:, :, :2, 3] = rng.uniform(0, 1, (200, 2, 2))
    c, s = math.cos(0.3), math.sin(0.3)
    poses[:, 0, :2, :2] = [[c, -s], [s, c]]  # the fixed yaw
    yaw = rng.uniform(0, 2 * math.pi, 200)
    poses[:, 1, 0, 0], poses[:, 1, 1, 0] = np.cos(yaw), np.sin(yaw)
    poses[:, 1, 0, 1], poses[:, 1, 1, 1] = -np.sin(yaw), np.cos(yaw)
    cov = support_coverage(poses, [fixed, free], bins=3)
    assert cov.outside == 0 and cov.joint_total == 9 * 27
    assert cov.object_coverage[0] == 100.0  # all 9 (x, y) bins hit by 200 draws
    assert cov.counts[0, :, :, 1:].sum() == 0  # yaw in its single bin
