"""Several BC-RNNs trained as one stacked network (mimicgen_pipe.learn.stacked_training): each
slice computes what its own BCRNN computes, and trains as train_policy trains it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.learn.policy import BCRNN, PolicyConfig, RolloutPolicy, nll_loss
from mimicgen_pipe.learn.stacked_training import StackedBCRNN, stacked_nll, train_stacked
from mimicgen_pipe.learn.training import (
    SequenceData,
    TrainConfig,
    TrainingRun,
    split_episodes,
    subset,
)
from tests.test_policy_learning import toy_data

torch.set_num_threads(1)


def two_models(hidden: int = 16) -> list[BCRNN]:
    """Two policies of one architecture, observations 5 and 8 wide, normalised apart."""
    models = []
    for seed, width in ((0, 5), (1, 8)):
        torch.manual_seed(seed)
        m = BCRNN(PolicyConfig(("x",), (width,), 7, hidden=hidden, layers=2, seq_len=4, modes=3))
        m.set_normalisation(np.linspace(-1, 1, width), np.linspace(0.5, 2, width))
        models.append(m)
    return models


def padded(obs: list[torch.Tensor]) -> torch.Tensor:
    width = max(o.shape[-1] for o in obs)
    return torch.stack([torch.nn.functional.pad(o, (0, width - o.shape[-1])) for o in obs])


def test_each_slice_computes_its_own_policy_and_loss_and_gradient():
    models = two_models()
    net = StackedBCRNN(models)
    gen = torch.Generator().manual_seed(0)
    obs = [torch.randn(6, 4, m.config.obs_dim, generator=gen) * 2 for m in models]
    actions = torch.rand(2, 6, 4, 7, generator=gen) * 2 - 1
    means, scales, logits = net(padded(obs))
    per_run = stacked_nll(means, scales, logits, actions).mean((1, 2))
    per_run.sum().backward()
    for i, m in enumerate(models):
        own = m(obs[i])
        for stacked, single in zip((means, scales, logits), own[:3], strict=True):
            torch.testing.assert_close(stacked[i], single, rtol=1e-5, atol=1e-6)
        loss = nll_loss(m, obs[i], actions[i])
        torch.testing.assert_close(per_run[i], loss, rtol=1e-5, atol=1e-6)
        loss.backward()
        d = m.config.obs_dim
        torch.testing.assert_close(net.weight_ih[0].grad[i][:, :d], m.lstm.weight_ih_l0.grad)
        torch.testing.assert_close(net.weight_hh[1].grad[i], m.lstm.weight_hh_l1.grad)
        torch.testing.assert_close(net.heads["means_weight"].grad[i], m.means.weight.grad)
    # the narrower policy's padded input columns see zeros: no gradient, never trained
    assert not net.weight_ih[0].grad[0][:, 5:].any()


def test_a_slice_is_its_policy_state_dict_again():
    models = two_models()
    net = StackedBCRNN(models)
    for i, m in enumerate(models):
        state = net.policy_state(i)
        assert state.keys() == m.state_dict().keys()
        for k, v in m.state_dict().items():
            assert torch.equal(state[k], v), k


def test_stacked_policies_need_one_architecture():
    a = BCRNN(PolicyConfig(("x",), (3,), 7, hidden=8))
    b = BCRNN(PolicyConfig(("x",), (3,), 7, hidden=16))
    with pytest.raises(ValueError, match="one architecture"):
        StackedBCRNN([a, b])


def toy_runs(epochs: int, seeds=(3, 4)) -> list[TrainingRun]:
    data = toy_data()
    tr, va = split_episodes(data.n_episodes, 0.2, np.random.default_rng(0))
    wide = toy_data(seed=5)  # a second dataset, 2 more observation columns
    wide = SequenceData(
        np.column_stack([wide.obs, wide.obs[:, 1:3] ** 2]), wide.actions, wide.episode_ends
    )
    runs = []
    for seed, d in zip(seeds, (data, wide), strict=True):
        width = d.obs.shape[1]
        policy = PolicyConfig(("x",), (width,), 3, hidden=32, layers=1, seq_len=5)
        cfg = TrainConfig(
            policy,
            batch_size=32,
            lr=3e-3,
            epochs=epochs,
            steps_per_epoch=20,
            checkpoint_every=10,
        )
        runs.append(TrainingRun(subset(d, tr), subset(d, va), cfg, seed))
    return runs


def test_stacked_training_learns_each_runs_mapping_and_checkpoints_loadable_policies():
    runs = toy_runs(epochs=30)
    saved: dict[tuple[int, int], dict] = {}
    history = train_stacked(runs, lambda i, e, s: saved.__setitem__((i, e), s))
    assert sorted(saved) == [(i, e) for i in range(2) for e in (10, 20, 30)]
    for i, run in enumerate(runs):
        rows = history[i]
        assert [r["epoch"] for r in rows] == list(range(1, 31))
        assert rows[-1]["step"] == 600
        assert rows[-1]["loss"] < rows[0]["loss"] - 2.0
        assert np.isfinite(rows[-1]["val_loss"])
        model = BCRNN(run.config.policy)
        model.load_state_dict(saved[(i, 30)])  # strict: the BCRNN layout exactly
        policy = RolloutPolicy(model)
        policy.reset(0)
        err = [
            np.abs(policy.act({"x": o}) - a)[:2].max()
            for o, a in zip(run.val_data.obs, run.val_data.actions, strict=False)
        ]
        assert np.median(err) < 0.15


def test_a_deadline_stops_after_the_epoch_it_passes_with_that_epoch_checkpointed():
    saved = []
    history = train_stacked(toy_runs(epochs=30), lambda i, e, s: saved.append((i, e)), deadline=0)
    assert [len(h) for h in history] == [1, 1]
    assert saved == [(0, 1), (1, 1)]


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA graphs need a GPU")
def test_cuda_graph_training_matches_eager_training_on_the_gpu():
    runs = [
        dataclasses.replace(r, config=dataclasses.replace(r.config, device="cuda"))
        for r in toy_runs(epochs=5)
    ]
    results = []
    for graph in (False, True):
        saved = {}
        train_stacked(runs, lambda i, e, s, d=saved: d.__setitem__((i, e), s), graph=graph)
        results.append(saved[(1, 5)])
    for k, v in results[0].items():
        torch.testing.assert_close(results[1][k], v, rtol=1e-4, atol=1e-5)


def test_the_train_stage_gets_a_stacks_results_as_it_gets_side_by_side_runs():
    from mimicgen_pipe.learn.training import stacked_trainings

    runs = toy_runs(epochs=10)
    results = list(stacked_trainings(runs))
    assert len(results) == 2
    for run, (rows, models) in zip(runs, results, strict=True):
        assert [r["epoch"] for r in rows][-1] == 10
        assert [e for e, _ in models] == [10]
        assert isinstance(models[0][1], BCRNN)
        assert models[0][1].config == run.config.policy


def test_paper_profile_script_packs_trains_returns_and_unpacks_loadable_checkpoints(tmp_path):
    """scripts/paper_profile.py end to end on the CPU with a tiny network: the packed arrays
    come back bit for bit, and the returned checkpoints (float32 exactly, or float16) load as the
    train stage's."""
    import importlib.util
    import json

    from mimicgen_pipe.learn.training import load_checkpoint

    spec = importlib.util.spec_from_file_location("paper_profile", "scripts/paper_profile.py")
    pp = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(pp)
    run = toy_runs(epochs=1)[1]
    arrays = {}
    for split, d in (("train", run.train_data), ("val", run.val_data)):
        arrays |= {f"{split}_obs": d.obs, f"{split}_actions": d.actions}
        arrays[f"{split}_ends"] = d.episode_ends
    meta = {"task": "peg_insertion", "backend": "maniskill", "robot": "panda", "data": "D0",
            "data_run_id": "r", "train_episodes": 9, "val_episodes": 3}  # fmt: skip
    header = {
        "name": "peg_insertion_D0",
        "policy": run.config.policy.as_dict(),
        "schedule": {"batch_size": 16, "lr": 3e-3, "epochs": 2, "steps_per_epoch": 5,
                     "checkpoint_every": 1, "lr_schedule": "constant", "seeds": [0, 1]},
        "meta": meta,
    }  # fmt: skip
    packed = tmp_path / "peg_insertion_D0.npz"
    pp.write_packed(packed, header, arrays)
    back, train, val = pp.read_packed(str(packed))
    assert back["meta"] == meta
    for got, want in ((train, run.train_data), (val, run.val_data)):
        for key in ("obs", "actions", "episode_ends"):
            assert np.array_equal(getattr(got, key), getattr(want, key))
            assert getattr(got, key).dtype == getattr(want, key).dtype
    trained, out, half = tmp_path / "trained", tmp_path / "out", tmp_path / "half"
    pp.main(["train", "--packed", str(packed), "--out", str(trained), "--every", "1",
             "--epochs", "4", "--device", "cpu"])  # fmt: skip
    # epoch 1 asked for, 2 of --spread 2 (halfway to the last), 4 the last; 3 left there
    pp.main(["collect", "--trained", str(trained), "--epochs", "1", "--spread", "2", "--out",
             str(out), "--file-mb", "0.05"])  # fmt: skip
    assert len(list(out.glob("bundle*.pt"))) > 1  # the files kept under --file-mb
    pp.main(["collect", "--trained", str(trained), "--spread", "1", "--dtype", "float16",
             "--out", str(half)])  # fmt: skip
    for bundles, dtype, epochs in ((out, "float32", (1, 2, 4)), (half, "float16", (4,))):
        policies, metrics = tmp_path / f"policies_{dtype}", tmp_path / f"train_{dtype}.json"
        pp.main(["unpack", "--bundles", str(bundles), "--packed", str(packed), "--policies",
                 str(policies), "--metrics", str(metrics), "--plot",
                 str(tmp_path / f"curve_{dtype}.csv")])  # fmt: skip
        assert sorted(p.name for p in (policies / "seed0").glob("*.pt")) == [
            f"epoch{e:05d}.pt" for e in epochs
        ]
        for seed in (0, 1):
            for epoch in epochs:
                model, m = load_checkpoint(policies / f"seed{seed}" / f"epoch{epoch:05d}.pt")
                assert (m["seed"], m["epoch"], m["step"]) == (seed, epoch, 5 * epoch)
                assert m["weights_returned_as"] == dtype and m["task"] == "peg_insertion"
                path = trained / "peg_insertion_D0" / f"seed{seed}" / f"epoch{epoch:05d}.pt"
                full = torch.load(path)
                for k, v in model.state_dict().items():
                    assert torch.equal(v, full[k].to(getattr(torch, dtype)).float())
        assert json.loads(metrics.read_text())["weights_returned_as"] == dtype
    written = json.loads(metrics.read_text())
    assert (written["profile"], written["seeds"], written["epochs"]) == ("paper", 2, 4)
    assert written["gradient_steps"] == 40 and written["matmul"] == "fp32"
    # a directory of anything but checkpoints is never written into
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="mine"):
        pp.main(["unpack", "--bundles", str(out), "--packed", str(packed), "--policies",
                 str(mine), "--metrics", str(tmp_path / "m2.json"), "--plot",
                 str(tmp_path / "c2.csv")])  # fmt: skip
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
