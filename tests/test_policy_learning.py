"""BC-RNN, sequence sampling, checkpoints, observations and evaluation bookkeeping (no
simulator)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mimicgen_pipe.core import poses
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.observations import low_dim_observation, observation_dims, observation_keys
from mimicgen_pipe.data.metrics import evaluation_metrics
from mimicgen_pipe.data.params import load_params
from mimicgen_pipe.data.store import write_store
from mimicgen_pipe.learn.evaluation import EVAL_SEED_BASE, evaluated_checkpoints, evaluation_seed
from mimicgen_pipe.learn.policy import BCRNN, PolicyConfig, RolloutPolicy
from mimicgen_pipe.learn.training import (
    SequenceData,
    TrainConfig,
    load_checkpoint,
    load_training_data,
    save_checkpoint,
    split_episodes,
    subset,
    train_policy,
    window_index,
)
from mimicgen_pipe.run.runner import attempt_seed

torch.set_num_threads(1)  # tiny models: a second thread only adds synchronisation


def toy_data(n_episodes: int = 12, length: int = 30, seed: int = 0) -> SequenceData:
    """Episodes whose action is a fixed function of the observation, with an episode id in
    obs[:, 0] so that window tests can see which episode a step came from."""
    rng = np.random.default_rng(seed)
    obs, act = [], []
    for e in range(n_episodes):
        x = rng.uniform(-1, 1, (length, 3))
        obs.append(np.column_stack([np.full(length, e), x]))
        act.append(np.column_stack([np.tanh(2 * x[:, :2]), np.sign(x[:, 2:])]))
    return SequenceData(
        np.concatenate(obs).astype(np.float32),
        np.concatenate(act).astype(np.float32),
        np.arange(1, n_episodes + 1) * length,
    )


def test_windows_stay_inside_their_episode_and_pad_with_the_last_step():
    data = SequenceData(np.arange(10.0)[:, None], np.zeros((10, 1)), np.array([4, 10]))
    idx = window_index(data, np.array([0, 2, 3, 8]), 4)
    np.testing.assert_array_equal(idx, [[0, 1, 2, 3], [2, 3, 3, 3], [3, 3, 3, 3], [8, 9, 9, 9]])
    data = toy_data()
    starts = np.random.default_rng(0).integers(0, len(data.obs), 256)
    obs = data.obs[window_index(data, starts, 10)]
    assert (obs[:, :, 0] == obs[:, :1, 0]).all()  # one episode id per window


def test_split_is_by_episode_and_complete():
    train, val = split_episodes(10, 0.1, np.random.default_rng(0))
    assert len(val) == 1 and sorted(np.concatenate([train, val])) == list(range(10))
    data = toy_data()
    part = subset(data, val)
    assert set(np.unique(part.obs[:, 0])) == {float(v) for v in val}
    assert split_episodes(10, 0.0, np.random.default_rng(0))[1].size == 0


def train_toy(seed: int, epochs: int = 30) -> tuple[BCRNN, list[dict]]:
    data = toy_data()
    policy = PolicyConfig(("x",), (4,), 3, hidden=32, layers=1, seq_len=5)
    cfg = TrainConfig(
        policy, batch_size=32, lr=3e-3, epochs=epochs, steps_per_epoch=20, checkpoint_every=epochs
    )
    saved = []
    tr, va = split_episodes(data.n_episodes, 0.2, np.random.default_rng(0))
    hist = train_policy(subset(data, tr), subset(data, va), cfg, seed, lambda e, m: saved.append(m))
    return saved[-1], hist


def test_bc_rnn_learns_a_mapping_and_is_deterministic():
    model, hist = train_toy(seed=3)
    assert hist[-1]["loss"] < hist[0]["loss"] - 2.0
    assert np.isfinite(hist[-1]["val_loss"])
    data = toy_data(n_episodes=2, seed=9)  # unseen episodes
    policy = RolloutPolicy(model)
    policy.reset(0)
    err = [
        np.abs(policy.act({"x": o}) - a)[:2].max()
        for o, a in zip(data.obs, data.actions, strict=False)
    ]
    assert np.median(err) < 0.15
    again, _ = train_toy(seed=3)
    for p, q in zip(model.parameters(), again.parameters(), strict=False):
        assert torch.equal(p, q)
    other, _ = train_toy(seed=4, epochs=1)
    assert not torch.equal(next(iter(model.parameters())), next(iter(other.parameters())))


def test_rollout_policy_acts_on_a_drawn_or_the_most_likely_component():
    torch.manual_seed(0)
    model = BCRNN(PolicyConfig(("x",), (4,), 3, hidden=8, layers=1, seq_len=50, modes=5))
    obs = np.random.default_rng(0).normal(size=(40, 4)).astype(np.float32)
    with torch.no_grad():
        means, _, logits, _ = model(torch.from_numpy(obs)[None])
    best = means[0, torch.arange(40), logits[0].argmax(-1)].numpy()
    acted = {}
    for component in ("drawn", "most_likely"):
        policy = RolloutPolicy(model, component)
        policy.reset(0)
        acted[component] = np.stack([policy.act({"x": o}) for o in obs])
    np.testing.assert_allclose(acted["most_likely"], best, atol=1e-3)
    # a drawn component is another one at some steps (5 components of similar weight)
    assert np.abs(acted["drawn"] - best).max(axis=1).max() > 1e-2
    with pytest.raises(ValueError, match="component: expected one of"):
        RolloutPolicy(model, "mode")


def test_rollout_policy_restarts_its_context_every_seq_len_steps():
    torch.manual_seed(0)
    model = BCRNN(PolicyConfig(("x",), (4,), 3, hidden=8, layers=1, seq_len=3, modes=1))
    obs = np.random.default_rng(0).normal(size=(7, 4)).astype(np.float32)
    policy = RolloutPolicy(model)
    policy.reset(0)
    acted = np.stack([policy.act({"x": o}) for o in obs])
    with torch.no_grad():
        windows = [model(torch.from_numpy(obs[s : s + 3])[None])[0][0, :, 0] for s in (0, 3, 6)]
    np.testing.assert_allclose(acted, torch.cat(windows).numpy(), atol=1e-3)


def test_checkpoint_round_trip_and_bad_file(tmp_path):
    model, _ = train_toy(seed=0, epochs=1)
    save_checkpoint(tmp_path / "a.pt", model, {"epoch": 1})
    loaded, meta = load_checkpoint(tmp_path / "a.pt")
    assert meta == {"epoch": 1} and loaded.config == model.config
    x = torch.randn(2, 5, 4)
    torch.testing.assert_close(loaded(x)[0], model(x)[0])
    (tmp_path / "b.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="b.pt: not a policy checkpoint"):
        load_checkpoint(tmp_path / "b.pt")


def store_with_obs(tmp_path, success):
    steps = [
        {"actions": np.zeros((5, 7), np.float32), "obs/eef_pos": np.ones((5, 3), np.float32)}
        for _ in success
    ]
    return write_store(
        tmp_path / "s.zarr", "generated", steps, {"success": np.array(success)}, {"task": "t"}
    )


def test_dataset_errors_name_the_store_and_the_problem(tmp_path):
    store = store_with_obs(tmp_path, [True, False, True])
    data = load_training_data(store, ["eef_pos"], None, 0.0, 0)
    assert (data.train.n_episodes, data.val.n_episodes, data.obs_dims) == (2, 0, (3,))
    with pytest.raises(InputError, match=r"s.zarr: observation keys \['cube_pos'\] not in"):
        load_training_data(store, ["eef_pos", "cube_pos"], None, 0.1, 0)
    with pytest.raises(InputError, match="2 successful episodes, 5 wanted"):
        load_training_data(store, ["eef_pos"], 5, 0.1, 0)
    with pytest.raises(InputError, match="s.zarr: no successful episodes"):
        load_training_data(store_with_obs(tmp_path, [False, False]), ["eef_pos"], None, 0.1, 0)


def test_evaluation_seeds_never_meet_generation_seeds():
    gen = {attempt_seed(s, v, i) for s in (0, 1) for v in ("D0", "D1") for i in range(2000)}
    ev = {evaluation_seed(s, v, i) for s in (0, 1) for v in ("D0", "D1") for i in range(2000)}
    assert max(gen) < EVAL_SEED_BASE <= min(ev) and max(ev) < 2**31
    assert len(ev) > 7990  # distinct per (seed, variant, episode)


def test_evaluation_metrics_max_last_mean_std():
    m = evaluation_metrics(
        {0: [(10, 40.0), (20, 80.0), (30, 60.0)], 1: [(10, 20.0), (20, 100.0), (30, 100.0)]}
    )
    assert m["success_rate_max"] == 90.0 and m["success_rate_max_std"] == 10.0
    assert m["success_rate_last"] == 80.0 and m["success_rate_last_std"] == 20.0
    assert m["seed0_best_epoch"] == 20 and m["checkpoints"] == 3


def test_evaluated_checkpoints_every_nth_epoch_and_the_last():
    every25 = list(range(25, 201, 25))
    assert evaluated_checkpoints(every25, 50) == [1, 3, 5, 7]  # epochs 50, 100, 150, 200
    assert evaluated_checkpoints(every25, 25) == list(range(8))
    assert evaluated_checkpoints([25, 50, 60], 50) == [1, 2]  # the last, off the grid
    assert evaluated_checkpoints([25, 50], 100) == [1]  # only the last
    with pytest.raises(InputError, match="no checkpoint of epoch 50 .*epochs \\[25, 75, 100\\]"):
        evaluated_checkpoints([25, 75, 100], 50)


def test_observation_quaternions_do_not_flip_sign():
    """A top-down gripper yawing through ±90° and a cube yawing through 0: the quaternions
    a simulator may report as q or -q become one continuous curve."""
    objects = ("cube",)
    keys = observation_keys(objects)
    rows = []
    for yaw in np.linspace(-1.6, 1.6, 41):
        eef = np.eye(4)
        eef[:3, :3] = poses.axis_angle_to_matrix(np.array([0, 0, yaw])) @ np.diag([1, -1, -1.0])
        eef[:3, 3] = [0.1, 0.0, 0.3]
        cube = np.eye(4)
        cube[:3, :3] = poses.axis_angle_to_matrix(np.array([0, 0, yaw]))
        cube[:3, 3] = [0.2, 0.1, 0.02]
        obs = low_dim_observation(eef, np.full(2, 0.04), {"cube": cube}, objects)
        assert tuple(obs) == keys
        rows.append(obs)
    for key in ("eef_quat", "cube_quat"):
        q = np.stack([r[key] for r in rows])
        assert np.abs(np.diff(q, axis=0)).max() < 0.1, key
    np.testing.assert_allclose(rows[0]["eef_to_cube_pos"], [0.1, 0.1, -0.28], atol=1e-6)
    assert observation_dims(objects) == {k: v.size for k, v in rows[0].items()}


@pytest.mark.parametrize(
    "text,needle",
    [
        ("train: {cpu: {hidden: 0}}", "train.cpu.hidden: expected a value in"),
        ("train: {paper: {lr: -1.0}}", "train.paper.lr: expected a value in"),
        ("train: {profile: gpu}", "train.profile: expected one of"),
        ("train: {obs_keys: eef_pos}", "train.obs_keys: expected a list of a string"),
        ("evaluate: {episodes: 0}", "evaluate.episodes: expected a value in"),
    ],
)
def test_bad_train_params_name_the_key(tmp_path, text, needle):
    (tmp_path / "params.yaml").write_text(text)
    with pytest.raises(InputError, match=needle):
        load_params(tmp_path / "params.yaml")
