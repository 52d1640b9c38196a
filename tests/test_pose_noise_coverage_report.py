"""Pose-noise injection (paper T), support coverage (paper Q) and the report."""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np
import pytest

import envs
from mimicgen_pipe import poses
from mimicgen_pipe.coverage import reset_bounds, support_coverage, uniform_coverage
from mimicgen_pipe.errors import InputError
from mimicgen_pipe.params import Params, load_params
from mimicgen_pipe.pose_noise import (
    PoseNoise,
    generation_rng,
    perturb_pose,
    pose_noise_level,
)
from mimicgen_pipe.report import (
    Heading,
    Image,
    Run,
    Table,
    build_report,
    load_paper_results,
    render_html,
    render_markdown,
)
from mimicgen_pipe.store import read_store
from mimicgen_pipe.taskspec import ObjectBounds, ResetVariant, SubtaskSpec, TaskSpec
from tests.test_cli_errors import run_bad

REPO = Path(__file__).resolve().parents[1]
PAPER = REPO / "reference/paper_results.yaml"


def run_stage(stage, *argv) -> None:
    """Run a stage module in-process with arguments parsed by its own parser."""
    parser = argparse.ArgumentParser()
    stage.add_arguments(parser)
    stage.run(parser.parse_args([str(a) for a in argv]))


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


# --- report -------------------------------------------------------------------------------


def with_settings(**generate) -> Params:
    from dataclasses import replace

    p = Params()
    level = generate.pop("level", None)
    if level:
        p = replace(p, pose_noise=replace(p.pose_noise, level=level))
    return replace(p, generate=replace(p.generate, **generate))


def gen_metrics(dgr, attempts=200):
    return {"attempts": attempts, "successes": round(dgr * attempts / 100), "dgr": dgr}


def test_paper_entries_are_unambiguous_for_matching():
    paper = load_paper_results(PAPER)
    assert envs.task_spec("maniskill", "stack_cube").paper_task == "Stack"
    groups = {}
    for e in paper.entries:
        assert e.table and e.value >= 0
        if e.settings:
            groups.setdefault((e.table, e.task, e.variant, e.metric, e.data), []).append(e)
    for entries in groups.values():
        assert len({tuple(sorted(e.settings)) for e in entries}) == 1  # same keys varied
        assert len({tuple(sorted(e.settings.items())) for e in entries}) == len(entries)


def test_report_shows_missing_metrics_and_never_invents_rows():
    paper = load_paper_results(PAPER)
    run = Run("this run", Params(), {"generate_stack_cube_D1": gen_metrics(93.0, 1075)})
    md = render_markdown(build_report("stack_cube", "Stack", ["D0", "D1"], run, [], paper, {}))
    lines = md.splitlines()
    d0 = next(ln for ln in lines if ln.startswith("| D0 | "))
    d1 = next(ln for ln in lines if ln.startswith("| D1 | "))
    assert d0.startswith("| D0 | missing | missing | missing | 94.3 (Table O.1, Stack D0)")
    assert "| 93.0 | 90.0 (Table O.1, Stack D1)" in d1
    assert "63.3 (Table M.2, Stack D1) [no NN + no per-subtask]" in d1  # our settings' row
    sr = [ln for ln in lines if ln.startswith(("| source demos", "| generated "))]
    assert len(sr) == 3 and all(ln.count("missing") == 3 for ln in sr)
    assert "38.7 ± 4.1 (Table P.1, Stack D0)" in sr[0]
    assert "Heat maps for D0: missing." in md and "No saved ablation runs" in md

    run.metrics["evaluate_stack_cube_D1_on_D1"] = {
        "success_rate_max": 96.0,
        "success_rate_max_std": 1.5,
        "success_rate_last": 90.0,
        "success_rate_last_std": 2.0,
        "episodes": 50,
        "seeds": 3,
    }
    md = render_markdown(build_report("stack_cube", "Stack", ["D0", "D1"], run, [], paper, {}))
    row = next(ln for ln in md.splitlines() if ln.startswith("| generated D1"))
    assert row == (
        "| generated D1 | D1 | 96.0 ± 1.5 | 90.0 ± 2.0 | 50 × 3 "
        "| 100.0 ± 0.0 (Table P.1, Stack D1) |"
    )


def test_report_ablations_show_deltas_against_the_base_and_the_papers_direction():
    paper = load_paper_results(PAPER)
    stem = "generate_stack_cube_D1"
    runs = [
        Run("default", with_settings(), {stem: gen_metrics(90.0)}),
        Run("action_noise_0", with_settings(action_noise=0.0), {stem: gen_metrics(95.0)}),
        Run(
            "nn_per_subtask",
            with_settings(selection="nearest_neighbor", per_subtask=True),
            {stem: gen_metrics(92.5)},
        ),
        Run("pose_L2", with_settings(level="L2"), {}),  # its metrics were not produced
        Run("seed_1", with_settings(seed=1), {stem: gen_metrics(91.0)}),
        Run("seed_2", with_settings(seed=2), {stem: gen_metrics(89.0)}),
    ]
    this = Run("this run", Params(), {})
    blocks = build_report("stack_cube", "Stack", ["D1"], this, runs, paper, {})
    tables = [b for b in blocks if isinstance(b, Table)]
    ablation = next(t for t in tables if t.columns[0] == "run")
    rows = {r[0]: r for r in ablation.rows}
    assert set(rows) == {"default", "action_noise_0", "nn_per_subtask", "seed_1", "seed_2"}
    assert rows["action_noise_0"][1] == "action_noise=0.0" and rows["action_noise_0"][5] == "+5.0"
    assert "Square DGR 48.9 → 50.7 (+1.8, Table M.1)" in rows["action_noise_0"][8]
    assert rows["nn_per_subtask"][5] == "+2.5"
    assert rows["nn_per_subtask"][8].startswith("Stack DGR 63.3 → 90.0 (+26.7, Table M.2)")
    assert rows["default"][1] == "(base)" and rows["default"][5] == ""
    seeds = next(t for t in tables if t.columns[0] == "variant" and "seeds" in t.columns)
    assert seeds.rows[0][1:5] == ("0, 1, 2", "90.0, 91.0, 89.0", "90.0 ± 1.0", "2.0")
    assert "69.3 ± 0.4 (Table S.1, Stack Three D1)" in seeds.rows[0][5]


def test_suite_ablations_compare_with_their_own_default_run():
    """A suite task's ablations have a base of their own (here action noise 0.025, not
    params.yaml's 0.05): deltas are against the run named default, and a folder without it
    says so instead of comparing with the wrong base."""
    from mimicgen_pipe.report import suite_ablation_blocks

    paper = load_paper_results(PAPER)
    spec = envs.task_spec("maniskill", "pull_cube_tool")
    stem = "generate_pull_cube_tool_D1"
    base, l2 = with_settings(action_noise=0.025), with_settings(action_noise=0.025, level="L2")
    runs = [
        Run("default", base, {stem: gen_metrics(43.5)}),
        Run("action_noise_0", with_settings(action_noise=0.0), {stem: gen_metrics(62.0)}),
        Run("pose_noise_L2", l2, {stem: gen_metrics(29.5)}),
    ]
    blocks = suite_ablation_blocks(spec, runs, paper)
    assert blocks[0] == Heading(2, "Ablations on pull_cube_tool (Hammer Cleanup)")
    rows = {r[0]: r for r in blocks[-1].rows}
    assert rows["default"][1] == "(base)"
    assert rows["action_noise_0"][1:6] == ("action_noise=0.0", "D1", "200", "62.0 ± 3.4", "+18.5")
    assert rows["pose_noise_L2"][1] == "pose_noise.level=L2" and rows["pose_noise_L2"][5] == "-14.0"
    lone = suite_ablation_blocks(spec, runs[1:], paper)
    assert "missing" in lone[-1].text and "action_noise_0, pose_noise_L2" in lone[-1].text


def test_the_suite_table_states_the_action_noise_each_task_ran_with():
    """plug_charger caps the noise (its 0.5 mm clearance); the others run at the suite's."""
    from mimicgen_pipe.report import suite_blocks

    paper = load_paper_results(PAPER)
    specs = [envs.task_spec("maniskill", t) for t in ("pull_cube_tool", "plug_charger")]
    timing = {"seconds_per_attempt_mean": 0.3, "steps": 40000}
    metrics = {
        "generate_pull_cube_tool_D0": gen_metrics(64.0) | timing,
        "generate_plug_charger_D0": gen_metrics(60.0) | timing,
    }
    table = suite_blocks(specs, ["D0"], metrics, paper, 0.025)[-1]
    rows = {r[0]: dict(zip(table.columns, r, strict=True)) for r in table.rows}
    assert rows["pull_cube_tool (D0)"]["σ"] == "0.025"
    assert rows["plug_charger (D0)"]["σ"] == "0"
    assert "78.2" in rows["plug_charger (D0)"]["paper DGR"]


def test_html_holds_the_same_tables_and_embeds_images():
    blocks = [Table(("a", "b"), (("1 < 2", "`x`"),)), Image("h.png", "heat map")]
    page = render_html(blocks, {"h.png": b"\x89PNG fake"}, "t")
    assert "<td>1 &lt; 2</td><td><code>x</code></td>" in page
    assert 'src="data:image/png;base64,iVBORyBmYWtl"' in page
    assert "![heat map](h.png)" in render_markdown(blocks)


def test_a_malformed_paper_file_is_one_clear_error(tmp_path):
    bad = tmp_path / "paper.yaml"
    bad.write_text("entries:\n  - {table: O.1, task: Stack, variant: D0, value: 1}\n")
    with pytest.raises(InputError, match=r"paper.yaml: entries\[0\]: 'metric' missing"):
        load_paper_results(bad)


# --- stages on the simulator --------------------------------------------------------------


@pytest.mark.sim
def test_generation_sees_noisy_poses_and_records_true_ones(pipeline, tmp_path):
    """pose_noise perturbs only the object poses of a new store; generate transforms segments
    with the perturbed source pose and a perturbed new-scene pose drawn from the attempt's
    pose-noise stream, and records the simulator's true poses."""
    from stages import generate, pose_noise

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
    from stages import coverage, report

    metrics = tmp_path / "metrics"
    metrics.mkdir()
    (metrics / "generate_stack_cube_D1.json").write_bytes(
        (pipeline / "metrics/generate_stack_cube_D1.json").read_bytes()
    )
    plots = tmp_path / "plots"
    coverage.run(
        argparse.Namespace(
            params=str(pipeline / "params.yaml"),
            variant="D1",
            generated=str(pipeline / "data/generated/stack_cube_D1.zarr"),
            metrics=str(metrics / "coverage_stack_cube_D1.json"),
            table=str(plots / "coverage_stack_cube_D1.csv"),
            heatmap=str(plots / "coverage_stack_cube_D1.png"),
        )
    )
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
    report.run(
        argparse.Namespace(
            params=str(pipeline / "params.yaml"),
            metrics=str(metrics),
            ablations=None,
            plots=str(plots),
            paper=str(PAPER),
            out=str(out),
        )
    )
    md = (out / "report.md").read_text()
    assert "![initial object positions, stack_cube D1](coverage_stack_cube_D1.png)" in md
    assert (out / "coverage_stack_cube_D1.png").exists()
    assert f"| D1 | 3 | {kept} / {kept + failed} | {m['support_coverage_joint']:.1f} |" in md
    assert "data:image/png;base64," in (out / "report.html").read_text()


def test_transfer_table_reads_each_arms_metrics():
    from mimicgen_pipe.report import transfer_table

    metrics = {
        "generate_stack_D0_panda": {"dgr": 95.0, "attempts": 200, "ik_failures": 7},
        "generate_stack_D0_iiwa": {"dgr": 78.5, "attempts": 200, "ik_failures": 42},
        "generate_stack_cube_D0": {"dgr": 96.2, "attempts": 1039},  # a main run, no IK check
    }
    table = transfer_table(["stack"], ["D0"], ["panda", "iiwa", "xarm6"], metrics)
    assert table.rows == (("stack (D0)", "95.0 (7/200 IK)", "78.5 (42/200 IK)", "missing"),)
    main = transfer_table(["stack_cube"], ["D0"], ["panda", "xarm6"], metrics)
    assert main.rows == (("stack_cube (D0)", "96.2 (0/1039 IK)", "missing"),)


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


def test_suite_policy_table_sets_source_beside_generated_and_the_paper():
    from mimicgen_pipe.report import suite_policy_blocks

    paper = load_paper_results(PAPER)
    spec = envs.task_spec("maniskill", "place_sphere")  # stands for Pick Place
    protocol = {"episodes": 50, "every_epochs": 50, "checkpoints": 4}
    metrics = {
        "evaluate_place_sphere_source_on_D0": {"success_rate_max": 6.0, "success_rate_last": 2.0},
        "evaluate_place_sphere_D0_on_D0": {"success_rate_max": 84.0, "success_rate_last": 80.0},
        "evaluate_place_sphere_source_on_D1": {"success_rate_max": 0.0, "success_rate_last": 0.0},
    }
    metrics = {k: {**m, **protocol} for k, m in metrics.items()}
    blocks = suite_policy_blocks([spec], metrics, paper)
    assert "50 episodes on each of 4 checkpoints per policy (every 50th epoch" in blocks[1].text
    metrics["evaluate_place_sphere_source_on_D1"]["episodes"] = 20
    assert "as in each evaluate metric" in suite_policy_blocks([spec], metrics, paper)[1].text
    table = blocks[-1]
    d0, d1 = table.rows  # D2: no metric, no row
    assert d0 == (
        "place_sphere (D0)", "Pick Place", "6.0 / 2.0", "84.0 / 80.0", "+78.0",
        "source: 0.0 ± 0.0 (Table P.1, Pick Place D0); D0: 58.7 ± 7.5 (Table P.1, Pick Place D0)",
    )  # fmt: skip
    assert d1 == (
        "place_sphere (D1)", "Pick Place", "0.0 / 0.0", "missing", "missing",
        "– (none in the paper)",
    )  # fmt: skip
