"""Bad input: one clear error naming what is wrong, exit status 2, nothing written; raised by
the stage's ``resolve``, before any output is claimed."""

from __future__ import annotations

import argparse
import importlib
import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from mimicgen_pipe.core.errors import InputError, one_line
from mimicgen_pipe.data.store import write_store
from tests.conftest import REPO, cli


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


def make_trajectory_file(folder, control_mode="pd_ee_delta_pose", drop=None, episodes=1):
    folder.mkdir(parents=True, exist_ok=True)
    h5 = folder / "demo.h5"
    with h5py.File(h5, "w") as f:
        for i in range(episodes):
            g = f.create_group(f"traj_{i}")
            if drop != "actions":
                g["actions"] = np.zeros((5, 7), np.float32)
            g["env_states/actors/cubeA"] = np.zeros((6, 13), np.float32)
            g["env_states/articulations/panda"] = np.zeros((6, 31), np.float32)
    meta = {
        "env_info": {"env_id": "StackCube-v1", "env_kwargs": {"control_mode": control_mode}},
        "episodes": [{"episode_id": i, "episode_seed": i} for i in range(episodes)],
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


def _truncate(h5):
    data = h5.read_bytes()
    h5.write_bytes(data[: len(data) // 2])


@pytest.mark.parametrize(
    ("damage", "expected"),
    [
        (_truncate, "demo.h5: not a readable HDF5 trajectory file (Unable to synchronously "
                    "open file (truncated file: eof = "),
        (lambda h5: h5.write_text("not HDF5\n"), "demo.h5: not a readable HDF5 trajectory "
                                                  "file (Unable to synchronously open file "
                                                  "(file signature not found))"),
        (lambda h5: h5.with_suffix(".json").write_text("{,}"),
         "demo.json: not valid JSON (line 1, column 2: Expecting property name"),
    ],
)  # fmt: skip
def test_a_broken_source_file_is_one_error(tmp_path, damage, expected):
    """(tests/test_user_files.py has the other broken files, without a process each)"""
    h5 = make_trajectory_file(tmp_path / "input")
    damage(h5)
    msg = run_bad(tmp_path, "source", params=f"source: {{from_file: {h5}}}\n")
    assert f"mimicgen-pipe source: error: {h5.parent / expected}" in msg


def test_a_source_file_shorter_than_num_demos_is_one_error(tmp_path):
    """source.num_demos: 20 with a 10-episode file used to say 20 demos and write 10."""
    h5 = make_trajectory_file(tmp_path / "input", episodes=10)
    msg = run_bad(tmp_path, "source", params=f"source: {{num_demos: 20, from_file: {h5}}}\n")
    assert msg.endswith(
        f"{h5}: 10 episodes, fewer than source.num_demos = 20 in params.yaml; ask for 10 or "
        "fewer, or give a file with more"
    )


def test_params_that_are_not_utf8_are_one_error(tmp_path):
    (tmp_path / "params.yaml").write_bytes(b"task: stack_cube  # caf\xe9\nsource: {}\n")
    res = cli("source", cwd=tmp_path, check=False)
    assert res.returncode == 2 and outputs(tmp_path) == []
    assert res.stderr == (
        "mimicgen-pipe source: error: params.yaml: not UTF-8 text (byte 0xe9 at offset 23); "
        "expected a params file\n"
    )


def stack_cube_steps(t: int = 30) -> list[dict[str, np.ndarray]]:
    """One still episode of ``t`` steps of stack_cube as a source store holds it (identity
    poses, world frame), without term signals."""
    eye = np.broadcast_to(np.eye(4), (t, 4, 4)).copy()
    return [{"actions": np.zeros((t, 7), np.float32), "gripper": np.zeros(t, np.float32),
             "eef_pose": eye, "target_pose": eye, "object_poses/cubeA": eye,
             "object_poses/cubeB": eye}]  # fmt: skip


@pytest.mark.parametrize(
    ("name", "content", "expected"),
    [
        ("b.yaml", "0: [12]\n0: [20]\n",
         "b.yaml: not valid YAML: key 0 appears twice in one mapping (lines 1 and 2)"),
        ("b.yaml", "0: [true]\n",
         "b.yaml: demo 0: subtask 'grasp_cubeA' ends at True, expected a step in 1..29"),
        ("b.csv", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR",
         "b.csv: not UTF-8 text (byte 0x89 at offset 0); expected a boundaries file (CSV)"),
    ],
)  # fmt: skip
def test_a_bad_boundaries_file_is_one_error(tmp_path, name, content, expected):
    """bool is an int to Python: ``0: [true]`` used to be read as step 1."""
    write_store(tmp_path / "input" / "src.zarr", "source", stack_cube_steps(), {},
                {"task": "stack_cube"})  # fmt: skip
    path = tmp_path / "input" / name
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    msg = run_bad(tmp_path, "parse", "--source", "input/src.zarr", "--boundaries", str(path))
    assert f"error: {path.parent / expected}" in msg


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
        (MINIMAL + "generate: {variants: [D0, D0]}\n", "generate.variants: expected distinct"),
        (
            MINIMAL + "evaluate: {executor: dask}\n",
            "evaluate.executor: expected one of 'local', 'ray', got 'dask'",
        ),
        (MINIMAL + "ray: {adress: auto}\n", "ray.adress: unknown key (known: address)"),
        (MINIMAL + "generate: {seed: -1}\n", "params.yaml: generate.seed: expected a value in"),
        (
            MINIMAL + "task: stack_cube\n",
            "params.yaml: not valid YAML: key 'task' appears twice in one mapping (lines 1 "
            "and 3); give each key once",
        ),
    ],
)
def test_params_gaps_are_one_clear_error_at_load(tmp_path, params, expected):
    """Every stage loads params the same way; source stops before recording anything."""
    msg = run_bad(tmp_path, "source", params=params)
    assert expected in msg


def test_a_pipelines_own_section_is_checked_by_its_check_stage_only(tmp_path):
    """Robot transfer's lists are refused by its check stage, the first of its pipeline,
    before the stamp every other stage depends on is written (not by every stage)."""
    params = MINIMAL + "transfer: {variants: [D0, D2]}\n"
    msg = run_bad(tmp_path, "check", "--stamp", "params.checked", params=params)
    assert "transfer.variants: 'D2' is not a reset variant of stack on pybullet" in msg
    assert not (tmp_path / "params.checked").exists()


def test_source_stops_with_one_error_when_the_demonstrator_falls_short(tmp_path, monkeypatch):
    """A demonstrator that gives fewer demos than source.num_demos within its seed budget is
    an error naming the count, not a silently smaller source store."""
    import argparse

    from mimicgen_pipe import backends
    from mimicgen_pipe.core.errors import InputError
    from mimicgen_pipe.stages import source

    real, seeds = backends.source_episodes, []

    def first_demo_only(backend, env, num_demos, seed, from_file, work_dir):
        seeds.append(seed)
        if len(seeds) == 1:
            return real(backend, env, 1, seed, from_file, work_dir)
        return [], 1, 1  # every later seed's plan fails

    monkeypatch.setattr(backends, "source_episodes", first_demo_only)
    params = "task: stack\nbackend: pybullet\nsource: {num_demos: 2}\n"
    (tmp_path / "params.yaml").write_text(params)
    parser = argparse.ArgumentParser()
    source.add_arguments(parser)
    args = parser.parse_args(["--params", str(tmp_path / "params.yaml"),
                              "--out", str(tmp_path / "s.zarr"),
                              "--metrics", str(tmp_path / "s.json")])  # fmt: skip
    with pytest.raises(InputError, match="gave 1 of source.num_demos = 2 demos .* in 40 seeds"):
        source.run(source.resolve(args))
    assert seeds[-1] == 39 and not (tmp_path / "s.zarr").exists()
    assert not (tmp_path / "s.json").exists()


@pytest.mark.parametrize(
    "args, expected",
    [
        (["train", "--data", "D9"], "--data 'D9': expected \"source\" or a reset variant of"),
        (["evaluate", "--data", "../x", "--variant", "D0"], "--data '../x': expected letters"),
        (["evaluate", "--data", "a/b", "--variant", "D0", "--policies", "p"],
         "--data 'a/b': expected letters, digits, _ and - only"),
        (["evaluate_external", "--policy", "robomimic:input/m.pth", "--data", "D9",
          "--variant", "D0"],
         "--data 'D9': expected \"source\" or a reset variant of stack_cube (D0, D1)"),
    ],
)  # fmt: skip
def test_data_is_training_data_the_task_has(tmp_path, args, expected):
    """--data goes into output file names: "source" or a reset variant, or with the store or
    policies given by path a plain name; anything else is refused before any work."""
    (tmp_path / "input").mkdir()
    (tmp_path / "input/m.pth").write_bytes(b"")
    assert expected in run_bad(tmp_path, *args)


def test_a_params_typo_stops_before_the_stages_libraries_load(tmp_path, monkeypatch):
    """The params file is checked before the stage's module (and zarr, torch, the
    simulators) is imported: a typo's error comes in well under a second."""
    (tmp_path / "params.yaml").write_text(MINIMAL + "generate: {action_nois: 0.02}\n")
    probe = (
        "import sys; from mimicgen_pipe import cli\n"
        "rc = cli.main(['generate', '--variant', 'D0'])\n"
        "heavy = ('mimicgen_pipe.stages.generate', 'zarr', 'torch', 'sapien', 'mani_skill',"
        " 'pybullet')\n"
        "print(rc, [m for m in heavy if m in sys.modules])\n"
    )
    res = subprocess.run(
        [sys.executable, "-c", probe], cwd=tmp_path, capture_output=True, text=True,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
    )  # fmt: skip
    assert res.stdout.split(None, 1) == ["2", "[]\n"], res.stdout + res.stderr
    assert "params.yaml: generate.action_nois: unknown key" in res.stderr
    assert outputs(tmp_path) == []


@pytest.mark.parametrize(
    "params_file",
    ["params.yaml", "quickstart/params.yaml", "suite/params.yaml", "transit/params.yaml",
     "transfer/params.yaml"],
)  # fmt: skip
def test_check_passes_every_pipelines_params(params_file):
    res = cli("check", "--params", params_file, cwd=REPO)
    assert res.stdout.strip() == f"check: {params_file}: valid"


@pytest.mark.parametrize(
    "source,expected",
    [
        ("{from_file: input}", "source.from_file: input: cannot read the file (it is a folder"),
        (
            "{from_file: input/fifo.h5}",
            "source.from_file: input/fifo.h5: cannot read the file (it is a FIFO, not a regular",
        ),
        ("{from_file: input/none.h5}", "source.from_file: input/none.h5: file not found"),
        ("{num_demoz: 3}", "source.num_demoz: unknown key"),
    ],
)
def test_check_refuses_a_bad_params_file_or_a_file_it_names(tmp_path, source, expected):
    (tmp_path / "input").mkdir()
    os.mkfifo(tmp_path / "input/fifo.h5")  # a reader would block on it for ever
    msg = run_bad(tmp_path, "check", params=f"task: stack_cube\nsource: {source}\n")
    assert f"mimicgen-pipe check: error: params.yaml: {expected}" in msg


PIPELINE_FOLDERS = ("", "quickstart", "suite", "transit", "transfer", "images")


def pipelines_copy(work, params_file, from_file):
    """``work`` as a repository of the six pipelines (their real dvc.yaml and params
    files), source.from_file set to ``from_file`` in ``params_file``, and a demo file in
    each inputs folder and elsewhere."""
    (work / ".dvc").mkdir()
    for folder in PIPELINE_FOLDERS:
        (work / folder).mkdir(exist_ok=True)
        for name in ("dvc.yaml", "params.yaml"):
            text = (REPO / folder / name).read_text()
            if f"{folder}/{name}".lstrip("/") == params_file:
                text = text.replace("from_file: null", f"from_file: {from_file}")
            (work / folder / name).write_text(text)
    for folder in ("inputs", "quickstart/inputs", "elsewhere"):
        (work / folder).mkdir()
        (work / folder / "demo.h5").write_bytes(b"demos")


@pytest.mark.parametrize(
    ("params_file", "from_file", "expected"),
    [
        (
            "quickstart/params.yaml",
            "elsewhere/demo.h5",
            "expected a file in quickstart/inputs/, the folder that the source stage of "
            "quickstart/dvc.yaml tracks (so that editing the file re-runs the stage)",
        ),
        (
            "params.yaml",
            "inputs/../elsewhere/demo.h5",
            "expected a file in inputs/, the folder that the source stage of dvc.yaml tracks",
        ),
        (
            "suite/params.yaml",
            "quickstart/inputs/demo.h5",
            "the pipeline of suite/dvc.yaml makes its own source demos; brought-in demos go "
            "in inputs/ (dvc.yaml) or quickstart/inputs/ (quickstart/dvc.yaml), named by "
            "source.from_file in that pipeline's params file",
        ),
        ("transit/params.yaml", "elsewhere/demo.h5", "transit/dvc.yaml makes its own source"),
        ("transfer/params.yaml", "inputs/demo.h5", "transfer/dvc.yaml makes its own source"),
        ("images/params.yaml", "inputs/demo.h5", "images/dvc.yaml makes its own source"),
    ],
)
def test_check_refuses_a_source_file_its_pipeline_does_not_track(
    tmp_path, params_file, from_file, expected
):
    """A pipeline's source stage re-runs on an edit of the files in its inputs folder only
    (a DVC dep); a file elsewhere would be edited without DVC seeing it."""
    pipelines_copy(tmp_path, params_file, from_file)
    res = cli("check", "--params", params_file, cwd=tmp_path, check=False)
    assert res.returncode == 2, res.stderr
    assert res.stderr.startswith(
        f"mimicgen-pipe check: error: {params_file}: source.from_file: {from_file}: "
    )
    assert expected in res.stderr and res.stderr.count("\n") == 1


@pytest.mark.parametrize(
    ("params_file", "from_file"),
    [("quickstart/params.yaml", "quickstart/inputs/demo.h5"), ("params.yaml", "inputs/demo.h5")],
)
def test_check_passes_a_source_file_in_its_pipelines_inputs_folder(
    tmp_path, params_file, from_file
):
    pipelines_copy(tmp_path, params_file, from_file)
    res = cli("check", "--params", params_file, cwd=tmp_path)
    assert res.stdout.strip() == f"check: {params_file}: valid"


# -- refused by resolve: nothing claimed, nothing written -----------------------------------


def tree(work: Path) -> list[str]:
    return sorted(p.relative_to(work).as_posix() for p in work.rglob("*"))


def refused_by_resolve(stage: str, work: Path, *argv: str | Path) -> str:
    """The one line of the InputError that ``stage``'s resolve raises for the command line
    ``argv`` (the params file ``work``/params.yaml), after checking that it left ``work`` as
    it was: no output, no folder, no lock file. A stage that claimed its outputs before the
    check would leave its locks (held until the process ends) and their folders."""
    module = importlib.import_module(f"mimicgen_pipe.stages.{stage}")
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    args = parser.parse_args(["--params", str(work / "params.yaml"), *map(str, argv)])
    before = tree(work)
    with pytest.raises(InputError) as exc:
        module.resolve(args)
    assert tree(work) == before
    return one_line(str(exc.value))


def test_parse_refuses_a_subtask_end_past_its_demo_before_claiming(tmp_path):
    (tmp_path / "params.yaml").write_text(MINIMAL)
    source = tmp_path / "input" / "src.zarr"
    write_store(source, "source", stack_cube_steps(), {}, {"task": "stack_cube"})
    boundaries = tmp_path / "input" / "b.yaml"
    boundaries.write_text("0: [30]\n")  # the demo's 30 steps end at 29
    out = tmp_path / "out" / "parsed.zarr"
    msg = refused_by_resolve("parse", tmp_path, "--source", source, "--boundaries", boundaries,
                             "--out", out)  # fmt: skip
    expected = "demo 0: subtask 'grasp_cubeA' ends at 30, expected a step in 1..29 (an integer"
    assert msg.startswith(f"{boundaries}: {expected}")
    assert not out.parent.exists()


def test_pose_noise_refuses_a_store_with_pose_noise_before_claiming(tmp_path):
    (tmp_path / "params.yaml").write_text(MINIMAL + "pose_noise: {level: L1}\n")
    parsed = tmp_path / "input" / "noisy.zarr"
    episodes = {"subtask_term_index": np.array([[10]], np.int64)}
    write_store(parsed, "parsed", stack_cube_steps(), episodes,
                {"task": "stack_cube", "pose_noise": {"level": "L1"}})  # fmt: skip
    out = tmp_path / "out" / "noised.zarr"
    msg = refused_by_resolve("pose_noise", tmp_path, "--parsed", parsed, "--out", out)
    assert msg == f"{parsed}: already carries pose noise; give the clean parsed store"
    assert not out.parent.exists()


def test_train_refuses_a_store_of_another_kind_before_claiming(tmp_path):
    (tmp_path / "params.yaml").write_text(MINIMAL)
    store = tmp_path / "input" / "parsed.zarr"
    write_store(store, "parsed", stack_cube_steps(), {}, {"task": "stack_cube"})
    out = tmp_path / "out"
    msg = refused_by_resolve("train", tmp_path, "--data", "source", "--store", store,
                             "--out", out / "policy", "--metrics", out / "m.json",
                             "--plot", out / "p.csv")  # fmt: skip
    assert msg == f"{store}: a 'parsed' store, expected 'source'"
    assert not out.exists()


def test_evaluate_refuses_a_broken_checkpoint_before_claiming(tmp_path):
    """The checkpoints are loaded and checked by resolve (evaluate used to claim its
    outputs first)."""
    (tmp_path / "params.yaml").write_text(MINIMAL)
    checkpoint = tmp_path / "policy" / "seed0" / "epoch00001.pt"
    checkpoint.parent.mkdir(parents=True)
    checkpoint.write_bytes(b"not a checkpoint")
    out = tmp_path / "out"
    msg = refused_by_resolve("evaluate", tmp_path, "--data", "D1", "--variant", "D1",
                             "--policies", tmp_path / "policy", "--metrics", out / "m.json",
                             "--plot", out / "p.csv")  # fmt: skip
    assert msg.startswith(f"{checkpoint}: ")
    assert not out.exists()
