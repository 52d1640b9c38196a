"""The paper's BC-RNN profile (params train.paper: hidden 400, 2000 epochs x 100 steps, 3
seeds) trained on a GPU machine that has torch but not this package's simulators or stores,
then checkpointed and evaluated here as the train stage's own policies.

    # here: a task's training data (the train stage's demos and split) as one file
    python scripts/paper_profile.py pack --task peg_insertion \\
        --store data/generated/peg_insertion_D0_train.zarr --out data/gpu/peg_insertion_D0.npz
    # on the GPU machine, with a copy of this repository (PYTHONPATH=. where the package is
    # not installed): every task and seed as one stacked network
    # (mimicgen_pipe.learn.stacked_training), checkpoints every --every epochs, --deadline seconds
    # at most
    python scripts/paper_profile.py train --packed data/gpu/*.npz --out /tmp/paper --deadline 450
    # there too: each run's checkpoints of --epochs, of --spread N (N in all, one period
    # apart, the last included; the period printed) and its last, in files of at most
    # --file-mb (16 MiB: two float32 checkpoints at hidden 400; --dtype float16 halves them)
    # for a machine that sends back a few small files; --part k/n: the k-th share of them
    python scripts/paper_profile.py collect --trained /tmp/paper --spread 4 --out OUT
    # here: the train stage's checkpoints, curve and metrics, then the evaluate stage (with
    # params whose evaluate.every_epochs is the period collect printed)
    python scripts/paper_profile.py unpack --bundles OUT --packed data/gpu/peg_insertion_D0.npz \\
        --policies data/policies/peg_insertion_D0_paper \\
        --metrics suite/metrics/profiles/paper_gpu/train_peg_insertion_D0.json \\
        --plot suite/plots/profiles/paper_gpu/train_peg_insertion_D0.csv
    mimicgen-pipe evaluate --params <file> --task peg_insertion --data D0 --variant D0 \\
        --policies data/policies/peg_insertion_D0_paper \\
        --metrics suite/metrics/profiles/paper_gpu/evaluate_peg_insertion_D0_on_D0.json \\
        --plot suite/plots/profiles/paper_gpu/evaluate_peg_insertion_D0_on_D0.csv
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import lzma
import time
from pathlib import Path

import numpy as np
import torch

from mimicgen_pipe.learn.policy import BCRNN, PolicyConfig
from mimicgen_pipe.learn.training import POLICY_DIR, SequenceData, TrainConfig, TrainingRun


def pack(args: argparse.Namespace) -> None:
    import dataclasses

    from mimicgen_pipe import backends
    from mimicgen_pipe.data.params import load_params
    from mimicgen_pipe.learn.training import policy_training

    params = load_params(args.params)
    spec = backends.task_spec(params.backend, args.task)
    train = dataclasses.replace(params.train, profile="paper", obs_keys=list(spec.default_obs_keys))
    params = dataclasses.replace(params, task=args.task, train=train)
    training = policy_training(params, args.data, Path(args.store))
    c = training.config
    header = {
        "name": f"{args.task}_{args.data}",
        "policy": c.policy.as_dict(),
        "schedule": {
            k: getattr(c, k)
            for k in ("batch_size", "lr", "epochs", "steps_per_epoch", "checkpoint_every")
        }
        | {"lr_schedule": c.lr_schedule, "seeds": list(params.train.paper.seeds)},
        "meta": training.meta,
    }
    arrays = {}
    for split in ("train", "val"):
        d: SequenceData = getattr(training.data, split)
        arrays |= {f"{split}_obs": d.obs, f"{split}_actions": d.actions}
        arrays[f"{split}_ends"] = d.episode_ends
    write_packed(Path(args.out), header, arrays)
    print(
        f"{args.out}: {training.data.train.n_episodes} + {training.data.val.n_episodes} "
        f"episodes, {Path(args.out).stat().st_size / 1e6:.1f} MB"
    )


def _encode(a: np.ndarray) -> bytes:
    """A 2-d (or 1-d) array's bytes column by column, each column's values split into byte
    planes, then xz: smooth trajectories compress ~30 % better than by zip."""
    cols = np.ascontiguousarray(a.reshape(len(a), -1).T)
    planes = cols.view(np.uint8).reshape(cols.shape[0], -1, a.itemsize).transpose(0, 2, 1)
    return lzma.compress(np.ascontiguousarray(planes).tobytes())


def _decode(raw: np.ndarray, shape: list[int], dtype: str) -> np.ndarray:
    n, width, size = shape[0], int(np.prod(shape[1:])), np.dtype(dtype).itemsize
    planes = np.frombuffer(lzma.decompress(raw.tobytes()), np.uint8).reshape(width, size, n)
    cols = np.ascontiguousarray(planes.transpose(0, 2, 1)).view(dtype).reshape(width, n)
    return np.ascontiguousarray(cols.T).reshape(shape)


def write_packed(path: Path, header: dict, arrays: dict[str, np.ndarray]) -> None:
    """A packed file: ``header`` (JSON: name, policy, schedule, meta) and ``arrays``
    (train/val obs, actions, episode ends), each array encoded by :func:`_encode`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    encoded = {k: np.frombuffer(_encode(a), np.uint8) for k, a in arrays.items()}
    header = header | {"arrays": {k: [list(a.shape), a.dtype.str] for k, a in arrays.items()}}
    np.savez(path, header=np.array(json.dumps(header)), **encoded)


def read_packed(path: str) -> tuple[dict, SequenceData, SequenceData]:
    with np.load(path) as f:
        header = json.loads(str(f["header"]))
        arrays = {k: _decode(f[k], *header["arrays"][k]) for k in header["arrays"]}
    data = [
        SequenceData(arrays[f"{s}_obs"], arrays[f"{s}_actions"], arrays[f"{s}_ends"])
        for s in ("train", "val")
    ]
    return header, data[0], data[1]


def train(args: argparse.Namespace) -> None:
    from mimicgen_pipe.learn.stacked_training import train_stacked

    out = Path(args.out)
    # TF32 matmuls: 1.6x faster on an H200 here (fp32 GEMMs are most of a step), 10-bit
    # mantissa products; off by default as in PyTorch
    torch.backends.cuda.matmul.allow_tf32 = args.tf32
    runs, names = [], []
    for path in args.packed:
        header, tr, va = read_packed(path)
        s = header["schedule"]
        config = TrainConfig(
            PolicyConfig.from_dict(header["policy"]),
            s["batch_size"],
            s["lr"],
            args.epochs or s["epochs"],
            s["steps_per_epoch"],
            args.every,
            s["lr_schedule"],
            args.device,
        )
        for seed in s["seeds"]:
            runs.append(TrainingRun(tr, va, config, seed))
            names.append(f"{header['name']}/seed{seed}")
    t0 = time.perf_counter()

    def checkpoint(i: int, epoch: int, state: dict) -> None:
        path = out / names[i] / f"epoch{epoch:05d}.pt"
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save(state, path)

    def progress(epoch: int, rows: list[dict]) -> None:
        if epoch % 10 == 0 or epoch == 1:
            losses = " ".join(f"{r['loss']:.2f}" for r in rows)
            print(f"epoch {epoch} {time.perf_counter() - t0:.0f} s: {losses}", flush=True)

    history = train_stacked(runs, checkpoint, progress, args.deadline, graph=not args.eager)
    for name, rows in zip(names, history, strict=True):
        with (out / name / "curve.csv").open("w", newline="") as f:
            w = csv.DictWriter(f, ["epoch", "step", "loss", "val_loss", "seconds"])
            w.writeheader()
            w.writerows(rows)
    summary = {
        "device": torch.cuda.get_device_name() if torch.cuda.is_available() else "cpu",
        "torch": torch.__version__,
        "matmul": "tf32" if args.tf32 else "fp32",
        "runs": len(runs),
        "epochs": history[0][-1]["epoch"],
        "steps": history[0][-1]["step"],
        "wall_seconds": time.perf_counter() - t0,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary))


def collect(args: argparse.Namespace) -> None:
    trained, out = Path(args.trained), Path(args.out)
    saved = {d: sorted(d.glob("epoch*.pt")) for d in trained.glob("*/seed*")}
    wanted = set(args.epochs)
    for paths in saved.values():
        # --spread N: the multiples of one period (a multiple of the saving period) and the
        # last, N in all, so that evaluate.every_epochs = period rolls out exactly these
        epochs = [int(p.stem[5:]) for p in paths]
        period = epochs[0] * -(-epochs[-1] // (args.spread * epochs[0]))
        wanted |= set(range(period, epochs[-1] + 1, period))
        print(f"{paths[0].parent}: evaluate.every_epochs {period} rolls out the spread")
    chosen = sorted(
        p for paths in saved.values() for p in paths if int(p.stem[5:]) in wanted or p == paths[-1]
    )
    k, n = (int(x) for x in args.part.split("/"))
    share = chosen[k - 1 :: n]
    curves = {
        str(p.parent.relative_to(trained)): p.read_text() for p in trained.glob("*/seed*/curve.csv")
    }
    summary = json.loads((trained / "summary.json").read_text())
    out.mkdir(parents=True, exist_ok=True)
    dtype, limit = getattr(torch, args.dtype), args.file_mb * 2**20
    bundles: list[dict] = [{}]
    for p in share:  # as many checkpoints per file as --file-mb allows, by their saved size
        key = str(p.relative_to(trained))
        state = {name: v.to(dtype) for name, v in torch.load(p, weights_only=True).items()}
        if _saved_size({key: state}) > limit:
            raise SystemExit(f"{p}: over --file-mb {args.file_mb} as {args.dtype}")
        if _saved_size(bundles[-1] | {key: state}) > limit:
            bundles.append({})
        bundles[-1][key] = state
    for b, bundle in enumerate(bundles):
        torch.save(bundle, out / f"bundle{k}_{b}.pt")
    (out / f"curves{k}.json").write_text(json.dumps({"summary": summary, "curves": curves}))
    print(f"part {k}/{n}: {len(share)} checkpoints of {len(chosen)} in {len(bundles)} files")


def _saved_size(obj: dict) -> int:
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    return buffer.tell()


def unpack(args: argparse.Namespace) -> None:
    from mimicgen_pipe.data.outputs import claim, claims

    with claims():  # as a stage: refuses to write over anything but its own kinds of output
        claim(
            (Path(args.policies), POLICY_DIR),
            Path(args.metrics),
            Path(args.plot),
            inputs=[args.bundles, args.packed],
        )
        _unpack(args)


def _unpack(args: argparse.Namespace) -> None:
    from mimicgen_pipe.core.errors import InputError
    from mimicgen_pipe.data.metrics import metrics_identity, write_metrics, write_timings
    from mimicgen_pipe.learn.training import checkpoint_path, save_checkpoint
    from mimicgen_pipe.stages.train import write_curve

    header, tr, va = read_packed(args.packed)
    config = PolicyConfig.from_dict(header["policy"])
    s, meta = header["schedule"], header["meta"]
    curves, summary = {}, None
    for path in Path(args.bundles).glob("curves*.json"):
        d = json.loads(path.read_text())
        curves |= d["curves"]
        summary = d["summary"]
    written = 0
    for path in sorted(Path(args.bundles).glob("bundle*.pt")):
        for key, state in torch.load(path, weights_only=True).items():
            name, seed_dir, ckpt = key.split("/")
            if name != header["name"]:
                continue
            seed, epoch = int(seed_dir[4:]), int(ckpt[5:10])
            model = BCRNN(config)
            model.load_state_dict({k: v.float() for k, v in state.items()})
            extra = {"seed": seed, "epoch": epoch, "step": epoch * s["steps_per_epoch"]}
            returned_as = str(next(iter(state.values())).dtype).removeprefix("torch.")
            extra |= {
                "trained_on": summary["device"],
                "matmul": summary.get("matmul", "fp32"),
                "weights_returned_as": returned_as,
            }
            save_checkpoint(checkpoint_path(Path(args.policies), seed, epoch), model, meta | extra)
            written += 1
    if not written:
        raise InputError(f"{args.bundles}: no checkpoint of {header['name']} in its bundles")
    rows = []
    for key, text in sorted(curves.items()):
        name, seed_dir = key.split("/")
        if name == header["name"]:
            rows += [{"seed": int(seed_dir[4:]), **r} for r in csv.DictReader(text.splitlines())]
    Path(args.plot).parent.mkdir(parents=True, exist_ok=True)
    write_curve(Path(args.plot), rows)  # as the train stage writes its curve
    last_epoch = max(int(r["epoch"]) for r in rows)
    last = [r for r in rows if int(r["epoch"]) == last_epoch]
    task, data = meta["task"], meta["data"]
    identity = metrics_identity("train", task, meta["backend"], meta["robot"], data=data)
    metrics = identity | {
        "profile": "paper",
        "device": summary["device"],
        "matmul": summary.get("matmul", "fp32"),
        "weights_returned_as": returned_as,
        "seeds": len(last),
        "epochs": last_epoch,
        "data_run_id": meta["data_run_id"],
        "train_episodes": meta["train_episodes"],
        "val_episodes": meta["val_episodes"],
        "gradient_steps": int(last[0]["step"]) * len(last),
        "final_loss": float(np.mean([float(r["loss"]) for r in last])),
        "final_val_loss": float(np.mean([float(r["val_loss"]) for r in last])),
        "trainings_stacked": summary["runs"],
    }
    write_metrics(Path(args.metrics), metrics)
    write_timings(args.metrics, identity, {"wall_seconds": summary["wall_seconds"]})
    print(f"{args.policies}: {written} checkpoints; {args.metrics}")


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    a = sub.add_parser("pack")
    a.add_argument("--task", required=True)
    a.add_argument("--data", default="D0", help="the reset variant the store was generated in")
    a.add_argument("--store", required=True)
    a.add_argument("--out", required=True)
    a.add_argument("--params", default="params.yaml")
    a = sub.add_parser("train")
    a.add_argument("--packed", nargs="+", required=True)
    a.add_argument("--out", required=True)
    a.add_argument("--every", type=int, default=250, help="checkpoint every N epochs")
    a.add_argument("--epochs", type=int, help="in place of the packed schedule's")
    a.add_argument("--deadline", type=float, help="[s] stop after the epoch that passes it")
    a.add_argument("--device", default="cuda")
    a.add_argument("--eager", action="store_true", help="no CUDA graph")
    a.add_argument("--tf32", action="store_true", help="TF32 matrix products (faster, coarser)")
    a = sub.add_parser("collect")
    a.add_argument("--trained", required=True)
    a.add_argument("--epochs", type=int, nargs="*", default=[], help="and each run's last")
    a.add_argument("--spread", type=int, default=1, help="N checkpoints per run, one period apart")
    a.add_argument("--dtype", choices=["float16", "float32"], default="float32")
    a.add_argument("--file-mb", type=float, default=16, help="[MiB] most bytes in one file")
    a.add_argument("--part", default="1/1")
    a.add_argument("--out", required=True)
    a = sub.add_parser("unpack")
    a.add_argument("--bundles", required=True)
    a.add_argument("--packed", required=True)
    a.add_argument("--policies", required=True)
    a.add_argument("--metrics", required=True)
    a.add_argument("--plot", required=True)
    args = p.parse_args(argv)
    {"pack": pack, "train": train, "collect": collect, "unpack": unpack}[args.command](args)


if __name__ == "__main__":
    main()
