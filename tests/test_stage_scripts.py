"""Stage scripts stay thin (parse arguments, call the library, write outputs), every class
has a name of its own, and what a stage turns its params into is built in one place: the
training config from train params, the generate options and the task's noise cap (no
simulator)."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from mimicgen_pipe import backends
from mimicgen_pipe.cli import STAGES
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data.params import Params, TrainParams, TrainProfile
from mimicgen_pipe.learn.policy import PolicyConfig
from mimicgen_pipe.learn.training import (
    SequenceData,
    TrainConfig,
    TrainingData,
    default_device,
    train_config,
)
from mimicgen_pipe.stages.generate import capped_action_noise, with_generate_options

REPO = Path(__file__).resolve().parents[1]
MAX_RUN_LINES = 60


def test_every_stage_run_is_at_most_60_lines():
    lengths = {}
    for path in sorted((REPO / "mimicgen_pipe/stages").glob("*.py")):
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.FunctionDef) and node.name == "run":
                lengths[path.stem] = node.end_lineno - node.lineno + 1
    assert set(STAGES) <= set(lengths), "a stage without a run function"
    too_long = {stage: n for stage, n in lengths.items() if n > MAX_RUN_LINES}
    assert not too_long, (
        f"run longer than {MAX_RUN_LINES} lines: {too_long}; "
        "move logic into a layer (mimicgen_pipe/<layer>/)"
    )


def job_type(stage: str) -> str:
    """The name of a stage's job type: train_robomimic -> TrainRobomimicJob."""
    return "".join(word.title() for word in stage.split("_")) + "Job"


def stage_shape(path: Path) -> tuple[bool, str | None, list[str], str | None, bool]:
    """What a stage module is made of: whether it has add_arguments, resolve's return
    annotation, run's parameters' annotations, the module its job type is imported from
    (None: not imported), and whether it defines a class."""
    tree = ast.parse(path.read_text())
    functions = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}
    imports = {
        alias.name: node.module
        for node in tree.body
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
    }
    resolve, run = functions.get("resolve"), functions.get("run")
    return (
        "add_arguments" in functions,
        ast.unparse(resolve.returns) if resolve and resolve.returns else None,
        [ast.unparse(a.annotation) if a.annotation else "" for a in run.args.args] if run else [],
        imports.get(job_type(path.stem)),
        any(isinstance(n, ast.ClassDef) for n in ast.walk(tree)),
    )


def test_every_stage_has_one_shape():
    """add_arguments(p), resolve(args) -> <Stage>Job and run(job: <Stage>Job), the job type
    imported from the layer of the function that does the stage's work, never defined among
    the stages (the command line calls run(resolve(args)))."""
    for stage in STAGES:
        has_arguments, returns, takes, home, classes = stage_shape(
            REPO / f"mimicgen_pipe/stages/{stage}.py"
        )
        job = job_type(stage)
        assert (has_arguments, returns, takes, classes) == (True, job, [job], False), stage
        assert home is not None and home.split(".")[:2] != ["mimicgen_pipe", "stages"], stage


def test_no_two_classes_share_a_name():
    where: dict[str, list[str]] = {}
    # the library and the stages; each back end has its own Renderer, Env, ... (the contracts')
    for path in sorted((REPO / "mimicgen_pipe").rglob("*.py")):
        if "backends" not in path.relative_to(REPO).parts:
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ClassDef):
                    where.setdefault(node.name, []).append(
                        f"{path.relative_to(REPO)}:{node.lineno}"
                    )
    assert {name: at for name, at in where.items() if len(at) > 1} == {}


def training_data(obs_dims: tuple[int, ...], action_dim: int) -> TrainingData:
    empty = SequenceData(np.zeros((0, sum(obs_dims)), np.float32), np.zeros((0, 7)), np.zeros(0))
    return TrainingData(empty, empty, obs_dims, action_dim, {})


def test_the_training_config_is_the_active_profile_and_the_data_layout():
    paper = TrainProfile(hidden=64, layers=3, seq_len=7, batch_size=9, lr=0.01,
                         lr_schedule="cosine", epochs=4, steps_per_epoch=5, checkpoint_every=2,
                         device="auto")  # fmt: skip
    train = TrainParams(profile="paper", obs_keys=["eef_pos", "cubeA_pos"], paper=paper)
    config = train_config(train, training_data((3, 4), 7))
    assert config == TrainConfig(
        PolicyConfig(("eef_pos", "cubeA_pos"), (3, 4), 7, hidden=64, layers=3, seq_len=7),
        batch_size=9,
        lr=0.01,
        epochs=4,
        steps_per_epoch=5,
        checkpoint_every=2,
        lr_schedule="cosine",
        device=default_device(),
    )
    cpu = train_config(dataclasses.replace(train, profile="cpu"), training_data((3, 4), 7))
    assert (cpu.policy.hidden, cpu.epochs, cpu.device) == (100, 200, "cpu")
    # the architecture lives in the policy config only
    names = {f.name for f in dataclasses.fields(TrainConfig)}
    assert not names & {f.name for f in dataclasses.fields(PolicyConfig)}


def test_generate_options_stand_in_for_their_keys():
    params = Params()
    assert with_generate_options(params, None, None) == params
    g = with_generate_options(params, 12, 0.02).generate
    assert (g.mode, g.max_attempts, g.action_noise) == ("fixed_attempts", 12, 0.02)
    with pytest.raises(InputError, match=r"^--attempts 0: expected a value in \[1, "):
        with_generate_options(params, 0, None)


def test_a_task_caps_the_generate_action_noise_and_says_so():
    params = dataclasses.replace(Params(), task="plug_charger")
    capped, note = capped_action_noise(params, backends.task_spec("maniskill", "plug_charger"))
    assert capped.generate.action_noise == 0.0
    assert (
        note == "action noise sigma 0.0, not 0.05: plug_charger's max_action_noise (its task file)"
    )
    spec = backends.task_spec("maniskill", "stack_cube")
    assert capped_action_noise(Params(), spec) == (Params(), None)


def test_obs_keys_are_checked_against_the_task_the_command_line_names(tmp_path):
    """The suite runs every task with one params.yaml and --task: train.obs_keys are the
    named task's, not params.yaml's task's."""
    import argparse

    from mimicgen_pipe.stages import stage_params

    keys = ["eef_pos", "peg_pos", "box_pos"]  # peg_insertion's, not stack_cube's
    (tmp_path / "params.yaml").write_text(
        f"task: stack_cube\nbackend: maniskill\ntrain: {{obs_keys: [{', '.join(keys)}]}}\n"
    )
    named = argparse.Namespace(params=str(tmp_path / "params.yaml"), task="peg_insertion")
    assert stage_params(named).train.obs_keys == keys
    unnamed = argparse.Namespace(params=str(tmp_path / "params.yaml"))
    with pytest.raises(
        InputError, match="'peg_pos', 'box_pos' not an observation of task stack_cube"
    ):
        stage_params(unnamed)
