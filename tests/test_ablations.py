"""The generation ablations as stages: params.yaml's ``ablations`` section and the ablation
stage, which runs pose_noise -> generate -> coverage on one run's params."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data.params import ablation_params, load_params
from mimicgen_pipe.data.store import read_store

REPO = Path(__file__).resolve().parents[1]

RUNS = """
task: stack_cube
generate: {action_noise: 0.05, workers: 1, seed: 7}
ablations:
  variant: D1
  attempts: 3
  runs:
    default: {what: the base}
    pose_noise_L1: {what: pose noise, changes: {pose_noise: {level: L1}}}
    greedy: {what: selection, changes: {generate: {selection: nearest_neighbor, per_subtask: true}}}
"""


def params_file(tmp_path: Path, text: str = RUNS) -> Path:
    path = tmp_path / "params.yaml"
    path.write_text(text)
    return path


def test_a_run_is_the_pipelines_params_with_its_changes_on_the_shared_variant(tmp_path):
    params = load_params(params_file(tmp_path))
    run = ablation_params(params, "greedy")
    g = run.generate
    assert (g.selection, g.per_subtask, g.action_noise, g.seed) == (
        "nearest_neighbor",
        True,
        0.05,
        7,
    )
    assert (g.variants, g.mode, g.max_attempts) == (["D1"], "fixed_attempts", 3)
    assert run.pose_noise == params.pose_noise and run.train == params.train
    assert ablation_params(params, "pose_noise_L1").pose_noise.level == "L1"
    base = ablation_params(params, "default")
    assert base.generate == g.__class__(**{**vars(g), "selection": "random", "per_subtask": False})


def test_the_repositorys_runs_are_the_papers_ablations():
    """Every run of params.yaml changes what its name says, and no two runs are the same."""
    params = load_params(REPO / "params.yaml")
    runs = {name: ablation_params(params, name) for name in params.ablations.runs}
    base = runs["default"]
    assert runs["action_noise_0"].generate.action_noise == 0.0 != base.generate.action_noise
    assert runs["pose_noise_L2"].pose_noise.level == "L2"
    assert {runs[f"seed_{k}"].generate.seed for k in (1, 2)} == {1, 2}
    seen = [(r.generate, r.pose_noise) for r in runs.values()]
    assert len(set(map(repr, seen))) == len(seen)


@pytest.mark.parametrize(
    "change, needle",
    [
        ("{generate: {selection: bogus}}", "generate.selection: expected one of"),
        ("{generate: {nope: 1}}", "generate.nope: unknown key"),
        ("{train: {epochs: 1}}", "train: an ablation changes only generate and pose_noise"),
        ("{generate: {max_attempts: 9}}", "generate.max_attempts: every run shares it"),
        ("{generate: 3}", "generate: expected a mapping, got 3"),
        ("{pose_noise: {level: L9}}", "pose_noise.level: "),
    ],
)
def test_a_bad_change_names_the_runs_key_when_the_file_is_read(tmp_path, change, needle):
    text = RUNS.replace("{generate: {selection: nearest_neighbor, per_subtask: true}}", change)
    key = "params.yaml: ablations.runs.greedy.changes." + needle
    with pytest.raises(InputError, match=key.replace(".", r"\.")):
        load_params(params_file(tmp_path, text))


def test_an_unknown_run_is_named_with_the_known_ones(tmp_path):
    params = load_params(params_file(tmp_path))
    with pytest.raises(InputError, match="no run 'L3' .runs: default, pose_noise_L1, greedy."):
        ablation_params(params, "L3")


def run_stage(stage, *argv) -> None:
    parser = argparse.ArgumentParser()
    stage.add_arguments(parser)
    stage.run(stage.resolve(parser.parse_args([str(a) for a in argv])))


@pytest.mark.sim
def test_the_ablation_stage_is_the_three_stages_on_the_runs_params(pipeline, tmp_path):
    """One run of the stage writes what pose_noise, generate and coverage write when run by
    hand on a params file holding the run's settings, byte for byte in the stores; its params
    file goes beside its metrics last, with the run's settings and no list of runs."""
    from mimicgen_pipe.stages import ablation, coverage, generate, pose_noise

    parsed = pipeline / "data/parsed/stack_cube.zarr"
    params = params_file(tmp_path)
    work, out = tmp_path / "work", tmp_path / "metrics/ablations/pose_noise_L1"
    run_stage(ablation, "--params", params, "--run", "pose_noise_L1", "--parsed", parsed,
              "--work", work, "--out", out)  # fmt: skip

    by_hand = tmp_path / "by_hand.yaml"
    by_hand.write_text(
        "task: stack_cube\npose_noise: {level: L1}\n"
        "generate: {variants: [D1], mode: fixed_attempts, max_attempts: 3, workers: 1, seed: 7}\n"
    )
    hand = tmp_path / "hand"
    run_stage(pose_noise, "--params", by_hand, "--parsed", parsed, "--out", hand / "noised.zarr")
    run_stage(generate, "--params", by_hand, "--variant", "D1", "--parsed", hand / "noised.zarr",
              "--out", hand / "kept.zarr", "--metrics", hand / "generate.json")  # fmt: skip
    run_stage(coverage, "--params", by_hand, "--variant", "D1", "--generated", hand / "kept.zarr",
              "--metrics", hand / "coverage.json", "--table", hand / "coverage.csv",
              "--heatmap", hand / "coverage.png")  # fmt: skip

    for mine, theirs in (("pose_noise.zarr", "noised.zarr"), ("stack_cube_D1.zarr", "kept.zarr"),
                         ("stack_cube_D1_failed.zarr", "kept_failed.zarr")):  # fmt: skip
        a, b = read_store(work / mine), read_store(hand / theirs)
        assert a.data.keys() == b.data.keys()
        for key in a.data:
            np.testing.assert_array_equal(a.data[key], b.data[key], err_msg=f"{mine} {key}")
    ours = json.loads((out / "generate_stack_cube_D1.json").read_text())
    theirs = json.loads((hand / "generate.json").read_text())
    assert ours["attempts"] == 3 and ours["dgr"] == theirs["dgr"]
    assert ours["run_id"] == theirs["run_id"]  # the same params and inputs: the same run
    cov = json.loads((out / "coverage_stack_cube_D1.json").read_text())
    assert cov["run_id"] == ours["run_id"]
    assert (work / "coverage_stack_cube_D1.png").read_bytes()[:4] == b"\x89PNG"
    saved = load_params(out / "params.yaml")
    assert saved.pose_noise.level == "L1" and saved.generate.max_attempts == 3
    assert saved.ablations.runs == {}
    assert (out / "params.yaml").read_text().startswith("# ablation run pose_noise_L1: pose noise")
