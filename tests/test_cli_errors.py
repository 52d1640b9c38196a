"""Bad input: one clear error naming what is wrong, exit status 2, nothing written."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from mimicgen_pipe.store import write_store
from tests.conftest import cli


def outputs(work):
    return sorted(
        str(p.relative_to(work))
        for p in work.rglob("*")
        if p.is_file() and p.name != "params.yaml" and "input" not in p.parts
    )


MINIMAL = "task: stack_cube\nsource: {num_demos: 1}\n"


def run_bad(work, *args, params=MINIMAL):
    (work / "params.yaml").write_text(params)
    res = cli(*args, cwd=work, check=False)
    assert res.returncode == 2, res.stderr
    assert outputs(work) == []
    lines = [ln for ln in res.stderr.splitlines() if "error:" in ln]
    assert len(lines) == 1, res.stderr
    return lines[0]


def test_unknown_task(tmp_path):
    msg = run_bad(tmp_path, "source", params=MINIMAL.replace("stack_cube", "stack_sphere"))
    assert "task 'stack_sphere': unknown" in msg and "stack_cube" in msg


def test_unknown_variant(tmp_path):
    msg = run_bad(tmp_path, "generate", "--variant", "D7")
    assert "variant 'D7': unknown" in msg and "D0, D1" in msg


def test_params_value_of_wrong_type(tmp_path):
    msg = run_bad(
        tmp_path, "generate", "--variant", "D0", params="generate: {action_noise: lots}\n"
    )
    assert "params.yaml: generate.action_noise: expected a number, got 'lots'" in msg


def make_trajectory_file(folder, control_mode="pd_ee_delta_pose", drop=None):
    folder.mkdir(parents=True, exist_ok=True)
    h5 = folder / "demo.h5"
    with h5py.File(h5, "w") as f:
        g = f.create_group("traj_0")
        if drop != "actions":
            g["actions"] = np.zeros((5, 7), np.float32)
        g["env_states/actors/cubeA"] = np.zeros((6, 13), np.float32)
        g["env_states/articulations/panda"] = np.zeros((6, 31), np.float32)
    meta = {
        "env_info": {"env_id": "StackCube-v1", "env_kwargs": {"control_mode": control_mode}},
        "episodes": [{"episode_id": 0, "episode_seed": 0}],
    }
    h5.with_suffix(".json").write_text(json.dumps(meta))
    return h5


def test_source_file_with_wrong_control_mode(tmp_path):
    h5 = make_trajectory_file(tmp_path / "input", control_mode="pd_joint_pos")
    msg = run_bad(tmp_path, "source", params=f"source: {{from_file: {h5}}}\n")
    assert "control_mode is 'pd_joint_pos', expected 'pd_ee_delta_pose'" in msg


def test_source_file_with_missing_key(tmp_path):
    h5 = make_trajectory_file(tmp_path / "input", drop="actions")
    msg = run_bad(tmp_path, "source", params=f"source: {{from_file: {h5}}}\n")
    assert "traj_0/actions missing" in msg


def test_parse_rejects_a_nan_pose(tmp_path):
    t = 30
    eye = np.broadcast_to(np.eye(4), (t, 4, 4)).copy()
    bad = eye.copy()
    bad[7, 0, 3] = np.nan
    grasp = np.arange(t) > 10
    steps = [
        {
            "actions": np.zeros((t, 7), np.float32),
            "gripper": np.zeros(t, np.float32),
            "eef_pose": eye,
            "target_pose": eye,
            "object_poses/cubeA": bad,
            "object_poses/cubeB": eye,
            "subtask_signals/grasp_cubeA": grasp,
        }
    ]
    write_store(tmp_path / "input" / "src.zarr", "source", steps, {}, {"task": "stack_cube"})
    msg = run_bad(tmp_path, "parse", "--source", "input/src.zarr")
    assert "data/object_poses/cubeA: NaN or infinite value at episode 0, step 7" in msg


@pytest.mark.parametrize("stage", ["source", "parse", "generate"])
def test_every_stage_has_help(tmp_path, stage):
    res = cli(stage, "--help", cwd=tmp_path)
    assert "--params" in res.stdout


@pytest.mark.parametrize(
    "params,expected",
    [
        ("", "params.yaml: empty; expected the pipeline's params"),
        ("# nothing but a comment\n", "params.yaml: empty"),
        ("task: stack_cube\nbackend: maniskill\n", "params.yaml: no stage sections"),
        (MINIMAL + "train: {obs_keys: []}\n", "train.obs_keys: expected at least one entry"),
        (
            MINIMAL + "train: {obs_keys: [eef_pos, peg_pos]}\n",
            "params.yaml: train.obs_keys: 'peg_pos' not an observation of task stack_cube "
            "(known: eef_pos, eef_quat, gripper_qpos, cubeA_pos,",
        ),
        (
            MINIMAL + "generate: {variants: [D0, D7]}\n",
            "generate.variants: 'D7' is not a reset variant of stack_cube on maniskill "
            "(known: D0, D1)",
        ),
        (
            MINIMAL + "transfer: {variants: [D0, D2]}\n",
            "transfer.variants: 'D2' is not a reset variant of stack on pybullet",
        ),
        (MINIMAL + "generate: {variants: [D0, D0]}\n", "generate.variants: expected distinct"),
        (
            MINIMAL + "evaluate: {executor: dask}\n",
            "evaluate.executor: expected one of 'local', 'ray', got 'dask'",
        ),
        (MINIMAL + "ray: {adress: auto}\n", "ray.adress: unknown key (known: address)"),
    ],
)
def test_params_gaps_are_one_clear_error_at_load(tmp_path, params, expected):
    """Every stage loads params the same way; source stops before recording anything."""
    msg = run_bad(tmp_path, "source", params=params)
    assert expected in msg


def test_source_stops_with_one_error_when_the_demonstrator_falls_short(tmp_path, monkeypatch):
    """A demonstrator that gives fewer demos than source.num_demos within its seed budget is
    an error naming the count, not a silently smaller source store."""
    import argparse

    import envs
    from mimicgen_pipe.errors import InputError
    from stages import source

    real, seeds = envs.source_episodes, []

    def first_demo_only(backend, env, num_demos, seed, from_file, work_dir):
        seeds.append(seed)
        if len(seeds) == 1:
            return real(backend, env, 1, seed, from_file, work_dir)
        return [], 1, 1  # every later seed's plan fails

    monkeypatch.setattr(envs, "source_episodes", first_demo_only)
    params = "task: stack\nbackend: pybullet\nsource: {num_demos: 2}\n"
    (tmp_path / "params.yaml").write_text(params)
    parser = argparse.ArgumentParser()
    source.add_arguments(parser)
    args = parser.parse_args(["--params", str(tmp_path / "params.yaml"),
                              "--out", str(tmp_path / "s.zarr"),
                              "--metrics", str(tmp_path / "s.json")])  # fmt: skip
    with pytest.raises(InputError, match="gave 1 of source.num_demos = 2 demos .* in 40 seeds"):
        source.run(args)
    assert seeds[-1] == 39 and not (tmp_path / "s.zarr").exists()
    assert not (tmp_path / "s.json").exists()
