"""Policy checkpoints are never unpickled beyond tensors and plain values, a bad checkpoint
or training set is one line, and training reads only the arrays and episodes it uses, the
same values as a whole-store read (no simulator)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data import store as store_module
from mimicgen_pipe.data.store import open_store, read_store, write_store
from mimicgen_pipe.learn.policy import BCRNN, PolicyConfig
from mimicgen_pipe.learn.training import (
    SequenceData,
    check_meta,
    load_checkpoint,
    load_training_data,
    save_checkpoint,
    split_episodes,
    subset,
)
from tests.conftest import cli

KEYS = ["eef_pos", "gripper_qpos"]  # observations of stack_cube


class WritesAFile:
    """Unpickling this object opens (creates) ``marker``: code run by a checkpoint."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def forged_checkpoint(path: Path, marker: Path) -> Path:
    """A checkpoint of the right layout whose meta carries WritesAFile(marker)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    model = BCRNN(PolicyConfig(("eef_pos",), (3,), 7, hidden=4, layers=1))
    torch.save(
        {
            "version": 1,
            "config": model.config.as_dict(),
            "state_dict": model.state_dict(),
            "meta": {"task": "stack_cube", "epoch": 1, "x": WritesAFile(marker)},
        },
        path,
    )
    return path


def tiny_model() -> BCRNN:
    torch.manual_seed(0)
    return BCRNN(PolicyConfig(("eef_pos", "gripper_qpos"), (3, 2), 7, hidden=4, layers=1))


def test_a_forged_checkpoint_is_refused_and_runs_nothing(tmp_path):
    # the file is a real threat: an unrestricted unpickler runs it
    probe = forged_checkpoint(tmp_path / "probe.pt", tmp_path / "probe_marker")
    torch.load(probe, weights_only=False)
    assert (tmp_path / "probe_marker").exists()

    marker = tmp_path / "marker"
    bad = forged_checkpoint(tmp_path / "bad.pt", marker)
    with pytest.raises(InputError) as err:
        load_checkpoint(bad)
    msg = str(err.value)
    assert msg.startswith(f"{bad}: not a policy checkpoint") and "\n" not in msg
    assert "never unpickled" in msg and "GLOBAL io.open" in msg
    assert not marker.exists()


def test_checkpoints_of_the_train_stage_load_with_their_meta(tmp_path):
    model = tiny_model()
    meta = {
        "task": "stack_cube",
        "robot": None,
        "data_run_id": "abc",
        "train_params": {"obs_keys": ["eef_pos"], "val_fraction": 0.1, "cpu": {"seeds": [0]}},
        "epoch": 3,
        "step": 300,
    }
    save_checkpoint(tmp_path / "a.pt", model, meta)
    loaded, got = load_checkpoint(tmp_path / "a.pt")
    assert got == meta and loaded.config == model.config
    for (k, v), (k2, v2) in zip(
        model.state_dict().items(), loaded.state_dict().items(), strict=True
    ):
        assert k == k2 and torch.equal(v, v2)


def test_nan_weights_are_named_at_load(tmp_path):
    model = tiny_model()
    with torch.no_grad():
        model.means.bias[2] = float("nan")
    save_checkpoint(tmp_path / "nan.pt", model, {"task": "stack_cube", "epoch": 1})
    with pytest.raises(InputError, match=r"nan.pt: state_dict\['means.bias'\] has NaN or inf"):
        load_checkpoint(tmp_path / "nan.pt")
    with torch.no_grad():
        model.means.bias[2] = 0.0
        model.obs_std[0] = float("inf")
    save_checkpoint(tmp_path / "inf.pt", model, {"task": "stack_cube", "epoch": 1})
    with pytest.raises(InputError, match=r"inf.pt: state_dict\['obs_std'\] has NaN or inf"):
        load_checkpoint(tmp_path / "inf.pt")


def test_a_meta_that_is_not_a_dict_is_one_line(tmp_path):
    model = tiny_model()
    save_checkpoint(tmp_path / "m.pt", model, [1, 2])  # type: ignore[arg-type]
    with pytest.raises(InputError, match="m.pt: meta is a list, expected a dict"):
        load_checkpoint(tmp_path / "m.pt")


def evaluate(work: Path, policies: str) -> tuple[int, str]:
    (work / "params.yaml").write_text(
        "task: stack_cube\nevaluate: {episodes: 2, every_epochs: 1, workers: 1}\n"
    )
    res = cli(
        "evaluate", "--data", "D1", "--variant", "D1", "--policies", policies,
        "--metrics", "m.json", "--plot", "p.csv", cwd=work, check=False,
    )  # fmt: skip
    assert not (work / "m.json").exists() and not (work / "p.csv").exists()
    return res.returncode, res.stderr.strip()


def test_evaluate_refuses_a_forged_checkpoint_without_running_it(tmp_path):
    marker = tmp_path / "marker"
    forged_checkpoint(tmp_path / "pol/seed0/epoch00001.pt", marker)
    code, err = evaluate(tmp_path, "pol")
    assert code == 2 and len(err.splitlines()) == 1, err
    assert "pol/seed0/epoch00001.pt: not a policy checkpoint" in err and "never unpickled" in err
    assert not marker.exists()


def test_evaluate_names_a_checkpoint_without_an_epoch(tmp_path):
    save_checkpoint(tmp_path / "pol/seed0/epoch00001.pt", tiny_model(), {"task": "stack_cube"})
    code, err = evaluate(tmp_path, "pol")
    assert code == 2 and len(err.splitlines()) == 1, err
    assert "pol/seed0/epoch00001.pt: meta has no 'epoch' (expected a positive integer)" in err


def test_checkpoints_of_another_task_version_are_refused_before_a_rollout(tmp_path):
    """A checkpoint records the task version of the data it trained on (nothing at version
    1): evaluating it after the task's file moved on names the checkpoint and the versions."""
    import dataclasses

    from mimicgen_pipe import backends
    from mimicgen_pipe.learn.evaluation import checkpoints_to_evaluate

    spec = backends.task_spec("maniskill", "stack_cube")
    keys = ("eef_pos", "gripper_qpos")
    save_checkpoint(tmp_path / "pol/seed0/epoch00001.pt", tiny_model(),
                    {"task": "stack_cube", "epoch": 1})  # fmt: skip
    assert checkpoints_to_evaluate(tmp_path / "pol", spec, keys, 1).runs
    v2 = dataclasses.replace(spec, version=2)
    with pytest.raises(InputError, match=r"pol/seed0/epoch00001.pt: made with version 1 of task "
                       r"stack_cube, whose file is at version 2"):  # fmt: skip
        checkpoints_to_evaluate(tmp_path / "pol", v2, keys, 1)


def test_evaluate_meta_checks():
    check_meta(Path("c.pt"), {"task": "stack_cube", "epoch": 2})
    with pytest.raises(InputError, match="c.pt: meta has no 'task'"):
        check_meta(Path("c.pt"), {"epoch": 2})
    with pytest.raises(InputError, match="c.pt: meta 'epoch' is '2', expected a positive integer"):
        check_meta(Path("c.pt"), {"task": "stack_cube", "epoch": "2"})
    with pytest.raises(InputError, match="meta 'epoch' is True"):
        check_meta(Path("c.pt"), {"task": "stack_cube", "epoch": True})


# ---- training data ----


def synthetic_store(
    path: Path, success: list[bool], seed: int = 0, nan_at: tuple[int, int] | None = None
) -> Path:
    """A generated store with observations, actions (float64, as some arm's actions are)
    and arrays training does not use, 6-14 steps per episode."""
    rng = np.random.default_rng(seed)
    steps = []
    for _ in success:
        t = int(rng.integers(6, 15))
        steps.append(
            {
                "actions": rng.uniform(-1, 1, (t, 7)),
                "obs/eef_pos": rng.normal(size=(t, 3)).astype(np.float32),
                "obs/gripper_qpos": rng.normal(size=(t, 2)).astype(np.float32),
                "env_state": rng.normal(size=(t, 20)).astype(np.float32),
                "eef_pose": rng.normal(size=(t, 7)),
            }
        )
    if nan_at is not None:
        steps[nan_at[0]]["obs/gripper_qpos"][nan_at[1], 1] = np.nan
    episodes = {"success": np.array(success), "seed": np.arange(len(success))}
    return write_store(path, "generated", steps, episodes, {"task": "stack_cube"})


def whole_store_data(path: Path, num_demos: int | None, val_fraction: float):
    """The training data as assembled from a whole-store read (the reference)."""
    s = read_store(path)
    keep = np.flatnonzero(s.episodes["success"])[:num_demos]
    index = np.concatenate([np.arange(s.episode_starts[i], s.episode_ends[i]) for i in keep])
    obs = np.concatenate([s.data[f"obs/{k}"][index] for k in KEYS], axis=1).astype(np.float32)
    data = SequenceData(
        obs, s.data["actions"][index].astype(np.float32), np.cumsum(s.lengths[keep])
    )
    tr, va = split_episodes(len(keep), val_fraction, np.random.default_rng(0))
    return subset(data, tr), subset(data, va)


@pytest.mark.parametrize("block", [1 << 22, 40])  # 40 bytes: a few rows per decoded block
@pytest.mark.parametrize("num_demos,val_fraction", [(None, 0.1), (7, 0.3), (3, 0.0)])
def test_training_reads_the_values_a_whole_store_read_gives(
    tmp_path, monkeypatch, block, num_demos, val_fraction
):
    success = [True, False, True, True, False, False, True, True, True, False, True, True]
    path = synthetic_store(tmp_path / "s.zarr", success)
    monkeypatch.setattr(store_module, "_BLOCK_BYTES", block)
    got = load_training_data(path, KEYS, num_demos, val_fraction, 0, "stack_cube", "generated")
    want = whole_store_data(path, num_demos, val_fraction)
    assert got.obs_dims == (3, 2) and got.action_dim == 7
    for g, w in zip((got.train, got.val), want, strict=True):
        for a, b in ((g.obs, w.obs), (g.actions, w.actions), (g.episode_ends, w.episode_ends)):
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    if val_fraction == 0:
        assert got.val.n_episodes == 0 and got.val.obs.shape == (0, 5)


def test_training_reads_only_the_arrays_it_uses(tmp_path, monkeypatch):
    path = synthetic_store(tmp_path / "s.zarr", [True] * 6)
    whole = []  # arrays decoded whole
    read_array = store_module._read_array
    monkeypatch.setattr(
        store_module, "_read_array", lambda p, k, m: whole.append(k) or read_array(p, k, m)
    )
    # a damaged array training does not use is not read, so not in the way
    chunk = next(p for p in (path / "data/env_state/c").rglob("*") if p.is_file())
    chunk.write_bytes(b"garbage")
    data = load_training_data(path, KEYS, 2, 0.1, 0)
    assert data.train.n_episodes + data.val.n_episodes == 2
    assert sorted(whole) == ["meta/episode_ends", "meta/episodes/success"]


def test_a_damaged_chunk_is_found_even_past_the_rows_read(tmp_path):
    path = synthetic_store(tmp_path / "s.zarr", [True] * 8)
    chunk = next(p for p in (path / "data/actions/c").rglob("*") if p.is_file())
    raw = bytearray(chunk.read_bytes())
    raw[-8] ^= 0xFF  # in the last episode's compressed bytes, which 2 demos never decode
    chunk.write_bytes(bytes(raw))
    with pytest.raises(InputError, match="s.zarr: data/actions: a chunk cannot be decoded"):
        load_training_data(path, KEYS, 2, 0.1, 0)
    chunk.write_bytes(bytes(raw[:-5]))
    with pytest.raises(InputError, match="data/actions: a chunk cannot be decoded"):
        load_training_data(path, KEYS, 2, 0.1, 0)
    chunk.unlink()
    with pytest.raises(InputError, match="data/actions: 1 of 1 chunk\\(s\\) missing"):
        load_training_data(path, KEYS, 2, 0.1, 0)


def test_nan_in_an_episode_read_is_named_one_unread_is_not_in_the_way(tmp_path):
    path = synthetic_store(tmp_path / "s.zarr", [True] * 5, nan_at=(3, 4))
    data = load_training_data(path, KEYS, 3, 0.1, 0)  # episodes 0-2
    assert np.isfinite(data.train.obs).all()
    with pytest.raises(
        InputError,
        match=r"s.zarr: data/obs/gripper_qpos: NaN or infinite value at episode 3, step 4",
    ):
        load_training_data(path, KEYS, 4, 0.1, 0)


def test_actions_that_overflow_float32_are_named(tmp_path):
    rng = np.random.default_rng(0)
    steps = [
        {"actions": np.full((4, 7), 1e300 if i else 0.5), "obs/eef_pos": rng.normal(size=(4, 3))}
        for i in range(3)
    ]
    path = write_store(tmp_path / "s.zarr", "generated", steps, {}, {"task": "stack_cube"})
    with pytest.raises(InputError, match="data/actions: a value at row 4 does not fit float32"):
        load_training_data(path, ["eef_pos"], None, 0.0, 0)


def test_too_few_episodes_for_a_validation_split_is_one_clear_error(tmp_path):
    path = synthetic_store(tmp_path / "s.zarr", [False, True, False])
    with pytest.raises(InputError) as err:
        load_training_data(path, KEYS, None, 0.1, 0)
    assert str(err.value) == (
        f"{path}: 1 episode to train on (1 successful in the store), but train.val_fraction "
        "0.1 holds out at least one for validation: at least 2 are needed (or set "
        "train.val_fraction: 0 to train without validation)"
    )
    with pytest.raises(InputError, match=r"\(train.num_demos is 1\)"):
        load_training_data(synthetic_store(tmp_path / "t.zarr", [True] * 4), KEYS, 1, 0.1, 0)
    alone = load_training_data(path, KEYS, None, 0.0, 0)
    assert (alone.train.n_episodes, alone.val.n_episodes) == (1, 0)


def test_open_store_checks_what_read_store_checks(tmp_path):
    path = synthetic_store(tmp_path / "s.zarr", [True, True])
    with pytest.raises(InputError, match="a 'generated' store, expected 'source'"):
        open_store(path, kind="source")
    with pytest.raises(InputError, match="attrs.task is 'stack_cube', expected 'lift'"):
        open_store(path, task="lift")
    with pytest.raises(InputError, match=r"missing data keys \['gripper'\]"):
        open_store(path, required=["gripper"])
    with pytest.raises(InputError, match="store not found"):
        open_store(tmp_path / "none.zarr")
    view = open_store(path)
    assert view.shape("env_state")[1:] == (20,) and view.n_episodes == 2


TRAIN = """
task: stack_cube
train:
  num_demos: 1
  obs_keys: [eef_pos, gripper_qpos]
  val_fraction: {val}
  cpu: {{hidden: 8, layers: 1, seq_len: 4, batch_size: 4, lr: 0.001, epochs: 1,
        steps_per_epoch: 2, checkpoint_every: 1, seeds: [0]}}
"""


def test_train_stage_without_validation_and_with_too_few_episodes(tmp_path):
    synthetic_store(tmp_path / "one.zarr", [False, True])
    out = ["--data", "D1", "--store", "one.zarr", "--out", "pol", "--metrics", "m.json",
           "--plot", "p.csv"]  # fmt: skip
    (tmp_path / "params.yaml").write_text(TRAIN.format(val=0.1))
    res = cli("train", *out, cwd=tmp_path, check=False)
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert (
        "one.zarr: 1 episode to train on (train.num_demos is 1)" in res.stderr
        and "at least 2 are needed" in res.stderr
    )
    assert not (tmp_path / "pol").exists() and not (tmp_path / "m.json").exists()

    (tmp_path / "params.yaml").write_text(TRAIN.format(val=0))
    cli("train", *out, cwd=tmp_path)
    m = json.loads((tmp_path / "m.json").read_text())
    assert (m["train_episodes"], m["val_episodes"], m["final_val_loss"]) == (1, 0, None)
    assert np.isfinite(m["final_loss"])
    _, meta = load_checkpoint(tmp_path / "pol/seed0/epoch00001.pt")
    assert (meta["epoch"], meta["val_episodes"]) == (1, 0)
