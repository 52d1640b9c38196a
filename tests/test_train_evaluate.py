"""The train and evaluate stages on the small session pipeline, and the evaluator itself
(needs SAPIEN; marked ``sim``)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from mimicgen_pipe.data.store import read_store, write_store
from mimicgen_pipe.learn.evaluation import evaluation_seed, rollout
from mimicgen_pipe.learn.policy import BCRNN, PolicyConfig
from mimicgen_pipe.learn.training import save_checkpoint
from tests.conftest import cli

pytestmark = pytest.mark.sim

TINY = """
task: stack_cube
source: {num_demos: 3, seed: 0}
generate: {num_demos: 4, max_attempts: 12, workers: 1, seed: 7}
train:
  num_demos: 4
  cpu: {hidden: 16, layers: 1, seq_len: 10, batch_size: 8, lr: 0.001, epochs: 2,
        steps_per_epoch: 5, checkpoint_every: 1, seeds: [0, 1], threads: 1}
evaluate: {episodes: 2, every_epochs: 1, workers: 1}
"""


@pytest.fixture(scope="module")
def env():
    from mimicgen_pipe.backends import make_env

    e = make_env("maniskill", "stack_cube")
    yield e
    e.close()


class ReplayPolicy:
    """Plays one stored episode's actions, recording the observations it is shown."""

    def __init__(self, actions: np.ndarray) -> None:
        self.actions, self.seen = actions, []

    def reset(self, seed: int) -> None:
        self.t, self.seen = 0, []

    def act(self, obs):
        self.seen.append(obs)
        self.t += 1
        return self.actions[min(self.t, len(self.actions)) - 1]


class ZeroPolicy:
    def reset(self, seed: int) -> None:
        pass

    def act(self, obs):
        return np.zeros(7, np.float32)


def test_evaluator_scores_replayed_demos_100_and_a_still_arm_0(pipeline, env):
    gen = read_store(pipeline / "data/generated/stack_cube_D1.zarr")
    spec = env.spec
    for ep in range(gen.n_episodes):
        steps = gen.episode(ep)
        policy = ReplayPolicy(steps["actions"])
        grasp = spec.subtasks[0].term_signal
        r = rollout(env, policy, int(gen.episodes["seed"][ep]), "D1", spec.horizon, spec.objects,
                    term_signals=[grasp])  # fmt: skip
        assert r.success and r.steps <= len(steps["actions"]), ep
        # the step after which the grasp first held: the generator's own record, in which
        # step k holds the signal before action k
        recorded = int(np.argmax(steps[f"subtask_signals/{grasp}"]))
        assert recorded > 0 and abs(r.subtask_ends[0] - recorded) <= 2, (ep, r.subtask_ends)
        # the evaluator shows the policy the observations the generator recorded
        for key in ("eef_pos", "cubeA_pos", "gripper_qpos", "eef_to_cubeB_pos"):
            seen = np.stack([o[key] for o in policy.seen])
            np.testing.assert_allclose(seen, steps[f"obs/{key}"][: len(seen)], atol=5e-3)
    for i in range(3):
        seed = evaluation_seed(0, "D1", i)
        assert not rollout(env, ZeroPolicy(), seed, "D1", spec.horizon, spec.objects).success


def test_train_and_evaluate_stages(pipeline):
    (pipeline / "tiny.yaml").write_text(TINY)
    cli("train", "--params", "tiny.yaml", "--data", "D1", cwd=pipeline)
    cli("train", "--params", "tiny.yaml", "--data", "source", cwd=pipeline)
    for seed in (0, 1):
        ckpts = sorted(
            p.name for p in (pipeline / f"data/policies/stack_cube_D1/seed{seed}").iterdir()
        )
        assert ckpts == ["epoch00001.pt", "epoch00002.pt"]
    train = json.loads((pipeline / "metrics/train_stack_cube_D1.json").read_text())
    assert (train["train_episodes"], train["val_episodes"], train["gradient_steps"]) == (3, 1, 20)
    curve = list(csv.DictReader((pipeline / "plots/train_stack_cube_D1.csv").open()))
    assert [(r["seed"], r["epoch"]) for r in curve] == [
        ("0", "1"),
        ("0", "2"),
        ("1", "1"),
        ("1", "2"),
    ]
    # no wall-clock column in the tracked curve: the times are in the timings file
    assert list(curve[0]) == ["seed", "epoch", "step", "loss", "val_loss"]
    timed = json.loads((pipeline / "timings/train_stack_cube_D1.json").read_text())
    assert [e[:2] for e in timed["epoch_seconds"]] == [[0, 1], [0, 2], [1, 1], [1, 2]]
    assert all(e[2] > 0 for e in timed["epoch_seconds"]) and "epoch_seconds" not in train
    source = json.loads((pipeline / "metrics/train_stack_cube_source.json").read_text())
    assert source["train_episodes"] + source["val_episodes"] == 3

    cli("evaluate", "--params", "tiny.yaml", "--data", "D1", "--variant", "D1", cwd=pipeline)
    m = json.loads((pipeline / "metrics/evaluate_stack_cube_D1_on_D1.json").read_text())
    assert (m["seeds"], m["checkpoints"], m["episodes"], m["horizon"]) == (2, 2, 2, 200)
    rows = list(csv.DictReader((pipeline / "plots/evaluate_stack_cube_D1_on_D1.csv").open()))
    assert len(rows) == 4
    rates = {(r["seed"], r["epoch"]): float(r["success_rate"]) for r in rows}
    assert all(v in (0.0, 50.0, 100.0) for v in rates.values())  # 2 episodes per checkpoint
    best = [max(rates[(s, "1")], rates[(s, "2")]) for s in ("0", "1")]
    assert m["success_rate_max"] == pytest.approx(np.mean(best))
    assert m["success_rate_last"] == pytest.approx(np.mean([rates[("0", "2")], rates[("1", "2")]]))

    # every 2nd epoch: only epoch 2 of each run is rolled out, from the same scenes
    (pipeline / "every2.yaml").write_text(TINY.replace("every_epochs: 1", "every_epochs: 2"))
    cli("evaluate", "--params", "every2.yaml", "--data", "D1", "--variant", "D1",
        "--metrics", "metrics/every2.json", "--plot", "plots/every2.csv", cwd=pipeline)  # fmt: skip
    rows2 = list(csv.DictReader((pipeline / "plots/every2.csv").open()))
    assert [(r["seed"], r["epoch"]) for r in rows2] == [("0", "2"), ("1", "2")]
    assert all(float(r["success_rate"]) == rates[(r["seed"], "2")] for r in rows2)
    m2 = json.loads((pipeline / "metrics/every2.json").read_text())
    assert (m2["checkpoints"], m2["every_epochs"]) == (1, 2)


def test_train_and_evaluate_refuse_bad_input_before_work(pipeline):
    (pipeline / "tiny.yaml").write_text(TINY)
    gen = read_store(pipeline / "data/generated/stack_cube_D1.zarr")
    failed = "data/none_succeeded.zarr"
    write_store(
        pipeline / failed,
        "generated",
        [gen.episode(i) for i in range(gen.n_episodes)],
        {**gen.episodes, "success": np.zeros(gen.n_episodes, bool)},
        gen.attrs,
    )
    res = cli(
        "train",
        "--params",
        "tiny.yaml",
        "--data",
        "D1",
        "--store",
        failed,
        "--out",
        "data/x",
        cwd=pipeline,
        check=False,
    )
    assert res.returncode == 2 and "no successful episodes" in res.stderr
    assert not (pipeline / "data/x").exists()

    (pipeline / "keys.yaml").write_text(
        TINY.replace("num_demos: 4\n", "num_demos: 4\n  obs_keys: [eef_pos, cube_pose]\n")
    )
    res = cli("train", "--params", "keys.yaml", "--data", "D1", cwd=pipeline, check=False)
    assert res.returncode == 2, res.stderr
    assert "train.obs_keys: 'cube_pose' not an observation of task stack_cube (known:" in res.stderr

    other = pipeline / "data/other/seed0/epoch00001.pt"
    model = BCRNN(PolicyConfig(("eef_pos", "cubeA_pos"), (3, 4), 7, hidden=4, layers=1))
    save_checkpoint(other, model, {"task": "stack_cube", "epoch": 1})
    res = cli(
        "evaluate",
        "--params",
        "tiny.yaml",
        "--data",
        "D1",
        "--variant",
        "D1",
        "--policies",
        "data/other",
        "--metrics",
        "m.json",
        cwd=pipeline,
        check=False,
    )
    assert res.returncode == 2 and "observation layout" in res.stderr and "cubeA_pos" in res.stderr
    assert not (pipeline / "m.json").exists()

    # the same evaluation as Ray tasks on a local Ray: the same success per checkpoint
    (pipeline / "tiny_ray.yaml").write_text(
        TINY.replace(
            "evaluate: {episodes: 2, every_epochs: 1, workers: 1}",
            "evaluate: {episodes: 2, every_epochs: 1, workers: 2, executor: ray}",
        )
    )
    cli("evaluate", "--params", "tiny_ray.yaml", "--data", "D1", "--variant", "D1",
        "--metrics", "metrics/ray.json", "--plot", "plots/ray.csv", cwd=pipeline)  # fmt: skip
    assert (pipeline / "plots/ray.csv").read_text() == (
        pipeline / "plots/evaluate_stack_cube_D1_on_D1.csv"
    ).read_text()


def test_trainings_side_by_side_write_what_trainings_one_by_one_write(pipeline):
    """Two policies x two seeds trained by one command on two processes give the bytes that
    training each policy alone, in this process, gives."""
    (pipeline / "tiny.yaml").write_text(TINY)
    (pipeline / "side.yaml").write_text(
        TINY.replace("num_demos: 4\n  cpu", "num_demos: 4\n  workers: 2\n  cpu")
    )
    cli("train", "--params", "side.yaml", "--data", "source", "D1", cwd=pipeline)
    for data in ("source", "D1"):
        alone = [f"--out=alone/{data}", f"--metrics=alone/{data}.json", f"--plot=alone/{data}.csv"]
        cli("train", "--params", "tiny.yaml", "--data", data, *alone, cwd=pipeline)
        side = pipeline / f"data/policies/stack_cube_{data}"
        files = sorted(p.relative_to(side) for p in side.rglob("*.pt"))
        assert len(files) == 4  # 2 seeds x 2 epochs
        for f in files:
            assert (side / f).read_bytes() == (pipeline / "alone" / data / f).read_bytes(), f
        m = json.loads((pipeline / f"metrics/train_stack_cube_{data}.json").read_text())
        assert m["trainings_side_by_side"] == 2
        assert (
            json.loads((pipeline / f"alone/{data}.json").read_text())["trainings_side_by_side"] == 1
        )


@pytest.mark.parametrize(
    "args, message",
    [
        (["--data", "D1", "D1"], "--data D1 D1: each dataset at most once"),
        (["--data", "source", "D1", "--store", "a.zarr"], "--store: expected one path per --data"),
        (["--data", "source", "D1", "--out", "x"], "--out: expected one path per --data (2)"),
        (["--data", "source", "D1", "--metrics", "m.json"], "--metrics: expected one path"),
        (["--data", "source", "D7"], "D7"),
    ],
)  # fmt: skip
def test_train_refuses_a_bad_list_of_datasets_before_work(pipeline, args, message):
    (pipeline / "tiny.yaml").write_text(TINY)
    before = sorted(p for p in (pipeline / "data").rglob("*") if "policies" in p.parts)
    res = cli("train", "--params", "tiny.yaml", *args, cwd=pipeline, check=False)
    assert res.returncode == 2 and message in res.stderr, res.stderr
    assert sorted(p for p in (pipeline / "data").rglob("*") if "policies" in p.parts) == before
    assert not (pipeline / "x").exists()
