"""What evaluate and evaluate_external say while they roll out, and what they record: the plan
before any rollout, the step counts and time estimate while the workers run, the cameras
rendered for a policy (only those it reads), the epoch recorded for each checkpoint, and the
error naming the train stage when there are no checkpoints. On a fake env, in this process."""

from __future__ import annotations

import functools
import re
import time
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mimicgen_pipe import backends
from mimicgen_pipe.core.cameras import CameraRenderer
from mimicgen_pipe.data.metrics import evaluation_metrics
from mimicgen_pipe.data.params import EvaluateParams
from mimicgen_pipe.formats.external import PolicySpec, lerobot, policy_cameras, robomimic
from mimicgen_pipe.learn.evaluation import (
    Checkpoints,
    EvalJob,
    EvaluateJob,
    evaluate_checkpoints,
    evaluate_policies,
    rollout_plan,
)
from mimicgen_pipe.run import rollout_progress
from mimicgen_pipe.run.executors import Executor
from tests.conftest import REPO, SMALL_PARAMS, cli
from tests.test_external_policy import FakeEnv


class StateEnv(FakeEnv):
    """FakeEnv with a state a renderer can picture."""

    def get_state(self) -> np.ndarray:
        return np.asarray(self.pos, np.float32)


class SlowStill:
    """Holds the arm still (no episode succeeds), ``seconds`` per action."""

    def __init__(self, seconds: float = 0.0) -> None:
        self.seconds = seconds

    def reset(self, seed: int) -> None:
        pass

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        time.sleep(self.seconds)
        return np.zeros(7, np.float32)


def slow_still(seconds: float, name: str) -> SlowStill:
    return SlowStill(seconds)


ESTIMATE = re.compile(
    r"^t: first episode: ([\d.]+) s each \((\d+) steps, ([\d.]+) ms a step\); "
    r"estimated total ([\d.]+) s for (\d+) steps on 1 worker \(at most"
)


def test_progress_counts_steps_and_estimates_the_total_after_the_first_episode(capsys, monkeypatch):
    """12 episodes of 20 steps, 3 ms a step: the bar counts steps (240) and moves inside a
    block of ten episodes, step by step; after the first episode one line estimates the
    total from its time a step, at least the time the steps take and no more than a few
    times the real one."""
    monkeypatch.setattr(rollout_progress, "PROGRESS_SECONDS", 0.05)
    monkeypatch.setattr(rollout_progress, "WRITE_SECONDS", 0.0)
    job = EvalJob(make_env=FakeEnv, load_policy=functools.partial(slow_still, 0.003),
                  variant="D0", horizon=20, objects=())  # fmt: skip
    t0 = time.perf_counter()
    results, _ = evaluate_policies(job, ["still"], list(range(12)), Executor("local", 1), "t")
    wall = time.perf_counter() - t0
    assert [r.steps for r in results["still"]] == [20] * 12
    out, err = capsys.readouterr()
    (line,) = [m for m in map(ESTIMATE.search, out.splitlines()) if m]
    episode, steps, ms, total, slots = map(float, line.groups())
    assert (steps, slots) == (20, 240)
    assert 3.0 <= ms < 500 and episode == pytest.approx(steps * ms / 1000, rel=0.1)
    assert 0.9 * 240 * 0.003 <= total <= 3 * wall + 1
    shown = [int(n) for n in re.findall(r"(\d+)/240 ", err)]
    assert shown[-1] == 240 and "step/s" in err
    assert any(0 < n < 200 and n % 20 for n in shown), shown  # mid-episode, mid-block


def test_the_plan_names_inputs_cameras_and_the_work():
    inputs = {"eef_pos": ([3], "float32"), "agentview_image": ([84, 84, 3], "uint8")}
    lines = rollout_plan("evaluate x", inputs, ("agentview",), (84, 64), 1, 50, 200, 2)
    assert lines == [
        "evaluate x: the policy reads eef_pos (3,) float32, agentview_image (84, 84, 3) uint8",
        "evaluate x: cameras agentview, rendered at 84x64 (HxW) every step",
        "evaluate x: 1 policy x 50 episodes x 200 steps at most = 10000 steps, on 2 workers",
    ]
    low = rollout_plan("e", {"eef_pos": ((3,), "float32")}, (), None, 4, 5, 6, 1, "checkpoint")
    assert low[1] == "e: no cameras (low-dim observations only)"
    assert low[2] == "e: 4 checkpoints x 5 episodes x 6 steps at most = 120 steps, on 1 worker"


class CountingRenderer(CameraRenderer):
    """A renderer stand-in: counts the pictures it takes, per camera."""

    made: list[tuple[tuple[str, ...], int, int]] = []
    pictures: Counter = Counter()

    def __init__(self, backend, task, robot, width, height, cameras) -> None:
        super().__init__(cameras)
        self.size = (height, width)
        CountingRenderer.made.append((tuple(cameras), width, height))

    def _set_scene(self, state: np.ndarray) -> None:
        pass

    def _picture(self, camera: str) -> np.ndarray:
        CountingRenderer.pictures[camera] += 1
        return np.zeros((*self.size, 3), np.uint8)


class Recorder(SlowStill):
    seen: list[dict[str, tuple[int, ...]]] = []

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        Recorder.seen.append({k: v.shape for k, v in obs.items()})
        return super().act(obs)


def test_the_workers_render_only_the_cameras_the_policy_reads(monkeypatch):
    """A policy that reads the wrist camera at 8x6: the cameras it reads, the renderer each
    worker makes (evaluate_external's camera_renderer) and the pictures taken are that
    camera's alone, one a step, and the policy sees it at its size."""
    from mimicgen_pipe.stages.evaluate_external import camera_renderer

    image = {"shape": [8, 6, 3], "dtype": "uint8"}
    hello = {"observations": {"eye_in_hand_image": image,
                              "eef_pos": {"shape": [3], "dtype": "float32"}}}  # fmt: skip
    spec = PolicySpec("robomimic", "/p", "python", ("eef_pos",), "")
    cameras, size = policy_cameras(spec, hello, ("agentview", "eye_in_hand"))
    assert (cameras, size) == (("eye_in_hand",), (8, 6))
    monkeypatch.setattr(backends, "make_renderer", CountingRenderer)
    CountingRenderer.made, CountingRenderer.pictures, Recorder.seen = [], Counter(), []
    params = SimpleNamespace(backend="maniskill", task="stack_cube")
    make_cameras = camera_renderer(params, "panda", cameras, size)
    job = EvalJob(make_env=StateEnv, load_policy=lambda name: Recorder(), variant="D0",
                  horizon=5, objects=(), make_cameras=make_cameras)  # fmt: skip
    results, _ = evaluate_policies(job, ["p"], [1, 2, 3], Executor("local", 1), "t")
    steps = sum(r.steps for r in results["p"])
    assert CountingRenderer.made == [(("eye_in_hand",), 6, 8)]
    assert CountingRenderer.pictures == Counter({"eye_in_hand": steps}) and steps == 15
    assert all(s["eye_in_hand_image"] == (8, 6, 3) and "agentview_image" not in s
               for s in Recorder.seen) and len(Recorder.seen) == steps  # fmt: skip


def test_the_epoch_recorded_is_the_checkpoint_s_own(tmp_path, capsys):
    """robomimic's model_epoch_<N>.pth and LeRobot's checkpoints/<step>/ give their epoch
    (step); a path that says none gives None, recorded as null, never 0."""
    assert robomimic.checkpoint_epoch(Path("run/models/model_epoch_2.pth")) == 2
    assert robomimic.checkpoint_epoch(Path("model_epoch_20_best_validation_0.5.pth")) == 20
    assert robomimic.checkpoint_epoch(Path("model_epoch_7_Lift_success_0.9.pth")) == 7
    for other in ("last.pth", "model_epoch_.pth", "model_epoch_2.pt", "epoch00002.pt"):
        assert robomimic.checkpoint_epoch(Path(other)) is None
    checkpoints = tmp_path / "run/checkpoints"
    model = checkpoints / "000040/pretrained_model"
    model.mkdir(parents=True)
    (checkpoints / "last").symlink_to("000040")
    assert lerobot.checkpoint_epoch(checkpoints / "last/pretrained_model") == 40
    (model.parent / "training_state").mkdir()
    (model.parent / "training_state/training_step.json").write_text('{"step": 41}')
    assert lerobot.checkpoint_epoch(checkpoints / "last/pretrained_model") == 41
    elsewhere = tmp_path / "policy"
    elsewhere.mkdir()
    assert lerobot.checkpoint_epoch(elsewhere) is None
    # evaluate_external records it so
    from mimicgen_pipe.stages.evaluate_external import checkpoint_epoch

    epoch = checkpoint_epoch("robomimic", Path("models/model_epoch_2.pth"), "e")
    assert epoch == (2, "epoch")
    assert evaluation_metrics({0: [(epoch[0], 50.0)]})["seed0_best_epoch"] == 2
    assert checkpoint_epoch("lerobot", checkpoints / "last/pretrained_model", "e") == (41, "step")
    assert checkpoint_epoch("robomimic", Path("last.pth"), "e") == (None, "epoch")
    assert "last.pth does not say its training epoch" in capsys.readouterr().out
    assert evaluation_metrics({0: [(None, 50.0)]})["seed0_best_epoch"] is None


class SucceedsAt:
    """Succeeds at once when its checkpoint's name says so (FakeEnv: 2 m up in one step)."""

    def __init__(self, name: str) -> None:
        self.up = 2.0 if name.endswith("epoch00050.pt") else 0.0

    def reset(self, seed: int) -> None:
        pass

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return np.array([0, 0, self.up, 0, 0, 0, 0], np.float32)


def test_evaluate_records_the_best_checkpoint_s_epoch():
    """Of checkpoints of epochs 25, 50 and 75, the one of epoch 50 alone succeeds: its epoch
    is the run's best."""
    paths = [Path(f"seed0/epoch{e:05d}.pt") for e in (25, 50, 75)]
    checkpoints = Checkpoints({0: paths}, {p: int(p.stem[5:]) for p in paths}, None)
    rollouts = EvalJob(make_env=FakeEnv, load_policy=SucceedsAt, variant="D0", horizon=3,
                       objects=())  # fmt: skip
    job = EvaluateJob(
        task="t", backend="fake", robot="panda", data="D0", variant="D0", policies=Path("seed0"),
        checkpoints=checkpoints, inputs={}, seeds=(1, 2), evaluate=EvaluateParams(),
        executor=Executor("local", 1), rollouts=rollouts, metrics_path=Path("m.json"),
        plot=Path("p.csv"),
    )  # fmt: skip
    per_run, _ = evaluate_checkpoints(job)
    assert per_run == {0: [(25, 0.0), (50, 100.0), (75, 0.0)]}
    assert evaluation_metrics(per_run)["seed0_best_epoch"] == 50


def test_evaluate_without_checkpoints_names_the_train_stage(tmp_path):
    """Before training: one line naming the train command; in the pipeline, its stage."""
    from mimicgen_pipe.stages.evaluate import checkpoints_made_by

    (tmp_path / "params.yaml").write_text(SMALL_PARAMS)
    res = cli("evaluate", "--data", "D1", "--variant", "D1", cwd=tmp_path, check=False)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    (line,) = res.stderr.strip().splitlines()
    assert "data/policies/stack_cube_D1: no checkpoints" in line
    assert "the train stage writes them: run `mimicgen-pipe train --data D1` first" in line
    tracked = checkpoints_made_by("D1", REPO / "data/policies/stack_cube_D1", True)
    assert tracked == "; made by stage train@D1 of dvc.yaml: run `dvc repro train@D1`"
    elsewhere = checkpoints_made_by("D1", tmp_path / "elsewhere", False)
    assert f"`mimicgen-pipe train --data D1 --out {tmp_path / 'elsewhere'}`" in elsewhere
