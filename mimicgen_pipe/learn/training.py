"""Behavioural cloning on episode stores: dataset assembly, episode-aware sequence
sampling, the training config (built from train params), the training loop, checkpoints and
the policy directories that hold them, and the train stage's trainings of several policies
and seeds side by side."""

from __future__ import annotations

import dataclasses
import os
import pickle
import re
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from tqdm import tqdm

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.core.interrupts import Interrupted
from mimicgen_pipe.data.outputs import directory_kind
from mimicgen_pipe.data.params import Params, TrainParams, key_range, training_params
from mimicgen_pipe.learn.policy import BCRNN, PolicyConfig, RolloutPolicy, nll_loss
from mimicgen_pipe.learn.stacked_training import train_stacked
from mimicgen_pipe.learn.training_setup import (
    MappedImages,
    SequenceData,
    TrainConfig,
    TrainingRun,
    initial_policy,
    lr_scheduler,
    shift_images,
    validation_windows,
    window_index,
)
from mimicgen_pipe.run.executors import Executor, map_blocks

if TYPE_CHECKING:
    from mimicgen_pipe.data.store import StoreView

CHECKPOINT_VERSION = 1


@dataclass(frozen=True)
class TrainingData:
    """What a training reads from a store: its training and validation episodes, each key's
    observation width, the action width and the store's attributes; for an image policy, the
    cameras whose images the episodes hold and their (height, width) [px]."""

    train: SequenceData
    val: SequenceData
    obs_dims: tuple[int, ...]
    action_dim: int
    attrs: Mapping[str, Any]
    cameras: tuple[str, ...] = ()
    image_size: tuple[int, int] = (84, 84)


def train_config(train: TrainParams, data: TrainingData) -> TrainConfig:
    """The training of the active profile of ``train`` for a policy of ``data``'s
    observation layout (train.obs_keys, in that order); device ``auto``: cuda when there is
    one."""
    p = train.active
    assert train.obs_keys is not None  # mimicgen_pipe.stages.stage_params fills in the task's own
    h, w = data.image_size
    images = (
        {
            "image_keys": tuple(f"{c}_image" for c in data.cameras),
            "image_size": (h, w),
            "channels": p.channels,
            "keypoints": p.keypoints,
            "image_features": p.image_features,
        }
        if data.cameras
        else {}
    )
    policy = PolicyConfig(
        tuple(train.obs_keys),
        data.obs_dims,
        data.action_dim,
        hidden=p.hidden,
        layers=p.layers,
        seq_len=p.seq_len,
        **images,
    )
    return TrainConfig(
        policy,
        batch_size=p.batch_size,
        lr=p.lr,
        epochs=p.epochs,
        steps_per_epoch=p.steps_per_epoch,
        checkpoint_every=p.checkpoint_every,
        lr_schedule=p.lr_schedule,
        device=p.device if p.device != "auto" else default_device(),
        shift=(int(p.shift * h), int(p.shift * w)) if data.cameras else (0, 0),
    )


def load_training_data(
    path: str | os.PathLike,
    obs_keys: Sequence[str],
    num_demos: int | None,
    val_fraction: float,
    split_seed: int,
    task: str | None = None,
    kind: str | Sequence[str] | None = None,
    cameras: Sequence[str] = (),
    image_size: tuple[int, int] = (84, 84),
) -> TrainingData:
    """The successful episodes of the store at ``path`` (the first ``num_demos`` of them
    when given), split by episode into training and validation sets
    (:func:`split_episodes` with ``val_fraction`` and a generator seeded ``split_seed``):
    observations from ``data/obs/<key>`` in ``obs_keys`` order, and actions, as float32;
    with ``cameras``, each camera's images ``data/obs/<camera>_image``, which must be
    ``image_size`` (height, width) [px].

    Only those arrays and those episodes' rows are read (mimicgen_pipe.data.store.open_store),
    so memory is what the training holds, whatever else the store has. Raises InputError
    naming the store and what is missing or wrong, before any work."""
    # imported here so that the trainers import on a machine with torch alone (a GPU
    # machine training from arrays packed elsewhere, scripts/paper_profile.py)
    from mimicgen_pipe.data.store import open_store

    view = open_store(path, required=["actions"], task=task, kind=kind)
    missing = [k for k in obs_keys if f"obs/{k}" not in view.data_keys]
    if missing:
        available = [k[4:] for k in view.data_keys if k.startswith("obs/")]
        raise InputError(
            f"{view.path}: observation keys {missing} not in the store "
            f"(data/obs/ has: {', '.join(available) or 'nothing'})"
        )
    check_images(view, cameras, image_size)
    if "success" in view.episode_keys:
        success = np.asarray(view.episode_field("success"), bool)
    else:
        success = np.ones(view.n_episodes, bool)
    keep = np.flatnonzero(success)
    if len(keep) == 0:
        raise InputError(f"{view.path}: no successful episodes ({view.n_episodes} in the store)")
    if num_demos is not None:
        if len(keep) < num_demos:
            raise InputError(
                f"{view.path}: {len(keep)} successful episodes, {num_demos} wanted "
                "(generate more or lower train.num_demos)"
            )
        keep = keep[:num_demos]
    if val_fraction > 0 and len(keep) < 2:
        why = f"train.num_demos is {num_demos}" if num_demos else "1 successful in the store"
        raise InputError(
            f"{view.path}: 1 episode to train on ({why}), but train.val_fraction "
            f"{val_fraction} holds out at least one for validation: at least 2 are needed "
            "(or set train.val_fraction: 0 to train without validation)"
        )
    train_eps, val_eps = split_episodes(len(keep), val_fraction, np.random.default_rng(split_seed))
    dims = tuple(int(np.prod(view.shape(f"obs/{k}")[1:])) for k in obs_keys)
    action_dim = int(np.prod(view.shape("actions")[1:]))
    return TrainingData(
        _read_sequences(view, obs_keys, dims, action_dim, keep[train_eps], cameras),
        _read_sequences(view, obs_keys, dims, action_dim, keep[val_eps], cameras),
        dims,
        action_dim,
        view.attrs,
        tuple(cameras),
        image_size,
    )


def check_images(view: StoreView, cameras: Sequence[str], image_size: tuple[int, int]) -> None:
    """InputError naming the store unless it holds images of every camera of ``cameras``
    (an image policy's), each ``image_size`` (height, width) [px]."""
    from mimicgen_pipe.data.store import store_cameras

    if not cameras:
        return
    have = store_cameras(view.attrs)
    if not have:
        raise InputError(
            f"{view.path}: no camera images, but the image policy sees {', '.join(cameras)}; "
            "train it on an observed store (the observe stage renders one from this store)"
        )
    missing = [c for c in cameras if c not in have]
    if missing:
        raise InputError(
            f"{view.path}: no images of camera {', '.join(map(repr, missing))} (the store "
            f"has {', '.join(have)}); observe it with those cameras or train on these"
        )
    wrong = {c: have[c] for c in cameras if have[c] != tuple(image_size)}
    if wrong:
        c, (h, w) = next(iter(wrong.items()))
        raise InputError(
            f"{view.path}: {c} images are {h}x{w} px (height x width), the policy's "
            f"image_size is {image_size[0]}x{image_size[1]}"
        )


def _read_sequences(
    view: StoreView,
    obs_keys: Sequence[str],
    dims: Sequence[int],
    action_dim: int,
    episodes: np.ndarray,
    cameras: Sequence[str] = (),
) -> SequenceData:
    """``episodes`` (ascending store indices) as float32 SequenceData, each key read straight
    into its columns: no copy of the data beyond the result; with ``cameras``, their uint8
    images, read straight into the camera axis."""
    ends = np.cumsum(view.lengths[episodes]).astype(np.int64)
    n = int(ends[-1]) if len(ends) else 0
    obs = np.empty((n, sum(dims)), np.float32)
    column = 0
    for key, dim in zip(obs_keys, dims, strict=True):
        view.read_rows(f"obs/{key}", episodes, obs[:, column : column + dim])
        column += dim
    actions = view.read_rows("actions", episodes, np.empty((n, action_dim), np.float32))
    images = None
    if cameras:
        from mimicgen_pipe.data.store import image_key

        shape = view.shape(image_key(cameras[0]))[1:]
        images = np.empty((n, len(cameras), *shape), np.uint8)
        for i, camera in enumerate(cameras):
            view.read_rows(image_key(camera), episodes, images[:, i])
    return SequenceData(obs, actions, ends, images)


def subset(data: SequenceData, episodes: np.ndarray) -> SequenceData:
    """The episodes ``episodes`` of ``data``, in that order (none: empty arrays)."""
    images = data.images
    if len(episodes) == 0:
        empty = None if images is None else images[:0]
        return SequenceData(data.obs[:0], data.actions[:0], np.zeros(0, np.int64), empty)
    starts, ends = data.episode_starts, data.episode_ends
    index = np.concatenate([np.arange(starts[i], ends[i]) for i in episodes])
    return SequenceData(
        data.obs[index],
        data.actions[index],
        np.cumsum(ends[episodes] - starts[episodes]),
        None if images is None else images[index],
    )


def split_episodes(
    n_episodes: int, val_fraction: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """(train, validation) episode indices, by episode; at least one of each when n >= 2."""
    n_val = int(round(n_episodes * val_fraction))
    if val_fraction > 0 and n_episodes >= 2:
        n_val = min(max(n_val, 1), n_episodes - 1)
    perm = rng.permutation(n_episodes)
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])


# a policy directory: the checkpoints of every training seed (checkpoint_path)
POLICY_DIR = directory_kind("policy directory", r"seed\d+/epoch\d+\.pt")


def checkpoint_path(directory: Path, seed: int, epoch: int) -> Path:
    """Training seed ``seed``'s checkpoint of epoch ``epoch`` in a policy directory."""
    return directory / f"seed{seed}" / f"epoch{epoch:05d}.pt"


def find_checkpoints(directory: Path) -> dict[int, list[Path]]:
    """Training seed -> its checkpoints in epoch order (layout: seed<k>/epoch<NNNNN>.pt)."""
    runs: dict[int, list[Path]] = {}
    for run_dir in sorted(directory.glob("seed*")):
        ckpts = sorted(run_dir.glob("epoch*.pt"))
        if ckpts and run_dir.name[4:].isdigit():
            runs[int(run_dir.name[4:])] = ckpts
    if not runs:
        raise InputError(f"{directory}: no checkpoints (expected seed<k>/epoch<N>.pt)")
    return runs


def check_meta(ckpt: Path, meta: dict) -> None:
    """The meta keys an evaluation reads: ``task`` (a string) and ``epoch`` (a positive
    integer); one line naming the file and the key otherwise."""
    for key, kind, ok in (
        ("task", "a task name", lambda v: isinstance(v, str)),
        ("epoch", "a positive integer", lambda v: type(v) is int and v > 0),
    ):
        if key not in meta:
            raise InputError(
                f"{ckpt}: meta has no {key!r} (expected {kind}); not a checkpoint the train "
                "stage wrote"
            )
        if not ok(meta[key]):
            raise InputError(f"{ckpt}: meta {key!r} is {meta[key]!r}, expected {kind}")


def save_checkpoint(path: Path, model: BCRNN, meta: dict[str, Any]) -> None:
    """Write atomically: a checkpoint file is complete or absent."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    torch.save(
        {
            "version": CHECKPOINT_VERSION,
            "config": model.config.as_dict(),
            "state_dict": {k: v.cpu() for k, v in model.state_dict().items()},
            "meta": meta,
        },
        tmp,
    )
    os.replace(tmp, path)


def load_checkpoint(path: str | os.PathLike) -> tuple[BCRNN, dict[str, Any]]:
    """A policy and its meta from a checkpoint written by :func:`save_checkpoint`.

    The file is unpickled with torch's weights-only loader, which builds tensors and plain
    containers and refuses any other object, so a crafted file cannot run code. Raises
    InputError naming the file for anything else: a foreign object, a wrong layout or
    version, and NaN or infinite weights (a diverged training: its rollouts would fail)."""
    path = Path(path)
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        # torch's message is a page of advice; the part after this marker says what failed
        detail = " ".join(str(exc).split()).partition("WeightsUnpickler error:")[2]
        detail = re.split(r"\. | Check the documentation", detail)[0].strip()[:160]
        raise InputError(
            f"{path}: not a policy checkpoint, or one holding objects other than tensors and "
            f"plain values, which are never unpickled ({detail or _one_line(exc)})"
        ) from exc
    except (OSError, RuntimeError, EOFError, ValueError) as exc:
        raise InputError(f"{path}: not a policy checkpoint ({_one_line(exc)})") from exc
    try:
        version = ckpt.get("version") if isinstance(ckpt, dict) else None
        if version != CHECKPOINT_VERSION:
            raise InputError(
                f"{path}: checkpoint version {version!r}, expected {CHECKPOINT_VERSION}"
            )
        check_config(path, ckpt["config"])  # before a network of its sizes is built
        model = BCRNN(PolicyConfig.from_dict(ckpt["config"]))
        state = ckpt["state_dict"]
        model.load_state_dict(state)
        meta = ckpt["meta"]
    except (RuntimeError, KeyError, TypeError, AttributeError, ValueError) as exc:
        raise InputError(f"{path}: not a policy checkpoint ({_one_line(exc)})") from exc
    if not isinstance(meta, dict):
        raise InputError(f"{path}: meta is a {type(meta).__name__}, expected a dict")
    for name, tensor in state.items():
        if tensor.is_floating_point() and not torch.isfinite(tensor).all():
            raise InputError(
                f"{path}: state_dict[{name!r}] has NaN or infinite values (the training "
                "diverged?); a policy with them cannot act"
            )
    return model, meta


# A checkpoint's config sizes the network built from it: each size is held to the range the
# params file allows the train profile's key of that name (train.*.hidden, ...), the others
# to these, before anything is built
_CONFIG_RANGES: dict[str, tuple[float, float]] = {
    "action_dim": (1, 1024),
    "modes": (1, 1024),
    "obs_dims": (1, 1_000_000),  # each
    "min_std": (0.0, 1.0),
}
MAX_CONFIG_KEYS = 1024  # entries of obs_keys or image_keys (cameras)


def check_config(path: Path, config: Any) -> None:
    """InputError naming the checkpoint and the key unless ``config`` is a mapping whose
    sizes are numbers in their ranges (:data:`_CONFIG_RANGES`, else the params file's for
    ``train.<profile>.<key>``) and whose key lists are short lists of names."""
    if not isinstance(config, dict):
        raise InputError(f"{path}: config is a {type(config).__name__}, expected a dict")
    for key, value in config.items():
        values = value if isinstance(value, list | tuple) else [value]
        if len(values) > MAX_CONFIG_KEYS:
            raise InputError(f"{path}: config.{key}: {len(values)} entries, expected a few")
        if key in ("obs_keys", "image_keys"):
            if not all(isinstance(v, str) for v in values):
                raise InputError(f"{path}: config.{key}: expected a list of names")
            continue
        bounds = _CONFIG_RANGES.get(key) or key_range(f"train.checkpoint.{key}")
        for v in values:
            number = isinstance(v, int | float) and not isinstance(v, bool)
            if bounds is not None and not (number and bounds[0] <= v <= bounds[1]):
                raise InputError(
                    f"{path}: config.{key}: {v!r}, expected a value in [{bounds[0]}, "
                    f"{bounds[1]}] (a checkpoint the train stage wrote has one)"
                )


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text[:200]}"


def train_policy(
    train_data: SequenceData,
    val_data: SequenceData,
    config: TrainConfig,
    seed: int,
    on_checkpoint: Callable[[int, BCRNN], None],
    progress: Callable[[int, dict[str, float]], None] | None = None,
) -> list[dict[str, float]]:
    """Train one BC-RNN (``config.policy``) from ``seed``. Calls ``on_checkpoint(epoch,
    model)`` every ``checkpoint_every`` epochs and after the last. Returns one row per epoch:
    epoch, step, loss (training NLL, mean over the epoch), val_loss (NLL on fixed validation
    windows; NaN without validation episodes), seconds."""
    device = torch.device(config.device)
    seq_len = config.policy.seq_len
    model = initial_policy(config.policy, train_data, seed)
    rng = np.random.default_rng(seed)  # the training windows' starts
    model.to(device)
    opt = torch.optim.Adam(model.parameters(), lr=config.lr)
    schedule = lr_scheduler(opt, config)
    train_obs = torch.from_numpy(train_data.obs).to(device)
    train_actions = torch.from_numpy(train_data.actions).to(device)
    images = train_data.images  # an image policy's, gathered per batch from host memory
    shifts = torch.Generator().manual_seed(seed)  # the image augmentation's draws
    val_idx = None
    if val_data.n_episodes:
        limit = VAL_WINDOWS_IMAGES if images is not None else 2000
        val_idx = validation_windows(val_data, seq_len, limit)
    history: list[dict[str, float]] = []
    t0 = time.perf_counter()
    for epoch in range(1, config.epochs + 1):
        model.train()
        total = 0.0
        for _ in range(config.steps_per_epoch):
            windows = window_index(
                train_data, rng.integers(0, len(train_data.obs), config.batch_size), seq_len
            )
            idx = torch.from_numpy(windows).to(device)
            frames = None
            if images is not None:
                frames = _frames(images, windows, config.shift, shifts).to(device)
            loss = nll_loss(model, train_obs[idx], train_actions[idx], frames)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            if schedule is not None:
                schedule.step()
            total += loss.item()
        val = float("nan")
        if val_idx is not None:
            model.eval()
            with torch.no_grad():
                val = _validation_loss(model, val_data, val_idx, device)
        row = {
            "epoch": epoch,
            "step": epoch * config.steps_per_epoch,
            "loss": total / config.steps_per_epoch,
            "val_loss": val,
            "seconds": time.perf_counter() - t0,
        }
        history.append(row)
        if progress is not None:
            progress(epoch, row)
        if epoch % config.checkpoint_every == 0 or epoch == config.epochs:
            on_checkpoint(epoch, model)  # save_checkpoint stores CPU tensors
    return history


VAL_WINDOWS_IMAGES = 200  # an image policy's validation windows: ~4000 images per camera
VAL_CHUNK = 50  # windows per forward pass of an image policy's validation


def _frames(
    images: np.ndarray, windows: np.ndarray, shift: tuple[int, int], generator: torch.Generator
) -> torch.Tensor:
    """The (B, T, cameras, H, W, 3) uint8 images of (B, T) step ``windows``, each image
    shifted on its own (:func:`shift_images`)."""
    frames = torch.from_numpy(images[windows])
    flat = frames.view(-1, *frames.shape[-3:])
    return shift_images(flat, shift, generator).view(frames.shape)


def _validation_loss(
    model: BCRNN, data: SequenceData, windows: np.ndarray, device: torch.device
) -> float:
    """The NLL of the validation ``windows``: one pass for a low-dim policy; an image
    policy's in chunks of VAL_CHUNK windows, unshifted, averaged over the windows."""

    def loss(rows: np.ndarray) -> torch.Tensor:
        frames = None
        if data.images is not None:
            frames = torch.from_numpy(data.images[rows]).to(device)
        obs = torch.from_numpy(data.obs[rows]).to(device)
        return nll_loss(model, obs, torch.from_numpy(data.actions[rows]).to(device), frames)

    if data.images is None:
        return float(loss(windows))
    chunks = [windows[i : i + VAL_CHUNK] for i in range(0, len(windows), VAL_CHUNK)]
    return float(sum(float(loss(c)) * len(c) for c in chunks) / len(windows))


def run_training(
    run: TrainingRun,
) -> tuple[list[dict[str, float]], list[tuple[int, dict[str, torch.Tensor]]]]:
    """:func:`train_policy` with a progress bar: its rows, and the model's CPU state dict at
    every checkpoint epoch, (epoch, state)."""
    states: list[tuple[int, dict[str, torch.Tensor]]] = []
    bar = tqdm(
        total=run.config.epochs, desc=run.label, unit="epoch", position=run.position, leave=True
    )

    def checkpoint(epoch: int, model: BCRNN) -> None:
        states.append((epoch, {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}))

    def progress(epoch: int, row: dict[str, float]) -> None:
        bar.update(1)
        bar.set_postfix(loss=f"{row['loss']:.2f}", val=f"{row['val_loss']:.2f}")

    try:
        history = train_policy(
            run.train_data, run.val_data, run.config, run.seed, checkpoint, progress
        )
    finally:
        bar.close()
    return history, states


def _set_threads(threads: int) -> None:
    if threads:
        torch.set_num_threads(threads)


def run_trainings(
    runs: Sequence[TrainingRun], workers: int, threads: int
) -> Iterator[tuple[list[dict[str, float]], list[tuple[int, BCRNN]]]]:
    """:func:`run_training` of every run, results in run order: its rows and its model at
    every checkpoint epoch, (epoch, model). Runs train on ``workers`` processes side by side
    (in this process when 1), each with ``threads`` torch threads (0: torch's default).

    A run's result does not depend on which process trained it or what ran beside it: every
    run seeds its own generators, and each process does the same arithmetic for a fixed
    thread count. The models are rebuilt here around the caller's own ``run.config.policy``, so
    that a checkpoint of them pickles to the same bytes whichever process trained it (pickle
    shares strings by identity, e.g. the observation keys of the config and of the meta)."""
    results = map_blocks(run_training, runs, Executor("local", workers), _set_threads, (threads,))
    try:
        for run, (history, states) in zip(runs, results, strict=True):
            yield history, _models(run.config.policy, states)
    finally:
        results.close()


def _models(
    policy: PolicyConfig, states: Sequence[tuple[int, dict[str, torch.Tensor]]]
) -> list[tuple[int, BCRNN]]:
    """(epoch, BCRNN of ``policy`` holding that epoch's state dict) for each of ``states``."""
    models = []
    for epoch, state in states:
        model = BCRNN(policy)
        model.load_state_dict(state)
        models.append((epoch, model))
    return models


def stacked_trainings(
    runs: Sequence[TrainingRun],
) -> Iterator[tuple[list[dict[str, float]], list[tuple[int, BCRNN]]]]:
    """:func:`run_trainings`' results for runs on a GPU, all trained at once as one stacked
    network (mimicgen_pipe.learn.stacked_training), with one progress bar for the stack."""
    states: list[list[tuple[int, dict[str, torch.Tensor]]]] = [[] for _ in runs]
    bar = tqdm(total=runs[0].config.epochs, desc=f"train {len(runs)} stacked", unit="epoch")

    def progress(epoch: int, rows: list[dict[str, float]]) -> None:
        bar.update(1)
        bar.set_postfix(loss=f"{np.mean([r['loss'] for r in rows]):.2f}")

    try:
        history = train_stacked(runs, lambda i, e, s: states[i].append((e, s)), progress)
    finally:
        bar.close()
    for run, rows, saved in zip(runs, history, states, strict=True):
        yield rows, _models(run.config.policy, saved)


SPLIT_SEED = 0  # the train/validation split is the same for every training seed


@dataclass(frozen=True)
class PolicyTraining:
    """One policy, trained from every training seed: ``config`` on ``data``, which is the
    training data ``name`` ("source" or a reset variant); each of its checkpoints carries
    ``meta`` and the checkpoint's seed, epoch and gradient step."""

    name: str
    data: TrainingData
    config: TrainConfig
    meta: dict[str, Any]


def policy_training(params: Params, name: str, store: Path) -> PolicyTraining:
    """The training that ``params`` ask for on the training data ``name`` in ``store``:
    "source", every source demo, or a reset variant, the first train.num_demos successful
    generated demos (:func:`load_training_data`, split with SPLIT_SEED); with the meta its
    checkpoints carry."""
    train, source = params.train, name == "source"
    assert train.obs_keys is not None  # mimicgen_pipe.stages.stage_params fills in the task's own
    data = load_training_data(
        store,
        train.obs_keys,
        None if source else train.num_demos,
        train.val_fraction,
        SPLIT_SEED,
        task=params.task,
        kind="source" if source else "generated",
        cameras=train.active.cameras,
        image_size=(train.active.image_size[0], train.active.image_size[1]),
    )
    return PolicyTraining(
        name,
        data,
        train_config(train, data),
        {
            "task": params.task,
            "backend": params.backend,
            "robot": data.attrs.get("robot"),
            "data": name,
            "store": str(store),
            # the generate run whose data this is (none for source demos): the report checks it
            "data_run_id": data.attrs.get("run_id"),
            "control_mode": data.attrs.get("control_mode"),
            # the task version the data was made with (none: version 1)
            **{k: v for k, v in data.attrs.items() if k == "task_version"},
            "train_episodes": int(data.train.n_episodes),
            "val_episodes": int(data.val.n_episodes),
            "train_params": training_params(train),
        },
    )


@dataclass(frozen=True)
class PolicyToTrain:
    """One policy the train stage trains: on ``data`` read from ``store``, written to ``out``
    (checkpoints), ``metrics`` and ``plot`` (training curve)."""

    data: str
    store: Path
    out: Path
    metrics: Path
    plot: Path
    num_demos: int  # the first N kept demos of a generated store (not used for "source")


@dataclass(frozen=True)
class TrainJob:
    """One train run, checked (mimicgen_pipe.stages.train.resolve): each policy of
    ``policies`` (on task ``task`` of back end ``backend``) trained as its training of
    ``trainings`` says (its store read and checked), from every training seed of the active
    profile of ``train``, ``side_by_side`` trainings at a time."""

    task: str
    backend: str
    train: TrainParams
    policies: tuple[PolicyToTrain, ...]
    trainings: tuple[PolicyTraining, ...]
    side_by_side: int


def train_policies(job: TrainJob, directories: Sequence[Path]) -> list[list[dict[str, float]]]:
    """Train every policy of ``job`` from every training seed (:func:`run_trainings`: the
    job's ``side_by_side`` trainings at a time, the profile's torch threads each) and write
    each policy's checkpoints into its policy directory of ``directories``
    (:func:`checkpoint_path`). Returns each policy's training curve: one row per (seed,
    epoch), the seed and then :func:`train_policy`'s row. An Interrupted on the way up says
    how many trainings finished."""
    image = bool(job.trainings[0].config.policy.image_keys)
    if not image or job.side_by_side <= 1:
        return _train_policies(job, directories, job.trainings, image)
    # image trainings in other processes: each policy's images mapped from one file
    with tempfile.TemporaryDirectory(prefix="mimicgen-pipe-images-") as folder:
        return _train_policies(job, directories, _mapped(job.trainings, Path(folder)), image)


def _mapped(trainings: Sequence[PolicyTraining], folder: Path) -> list[PolicyTraining]:
    """``trainings`` with each image array written to ``folder`` and mapped from there
    (MappedImages)."""
    out = []
    for k, t in enumerate(trainings):
        parts = {}
        for part in ("train", "val"):
            seq: SequenceData = getattr(t.data, part)
            assert seq.images is not None
            images = MappedImages.write(folder / f"{k}_{part}.npy", np.asarray(seq.images))
            parts[part] = dataclasses.replace(seq, images=images)
        out.append(dataclasses.replace(t, data=dataclasses.replace(t.data, **parts)))
    return out


def _train_policies(
    job: TrainJob, directories: Sequence[Path], trainings: Sequence[PolicyTraining], image: bool
) -> list[list[dict[str, float]]]:
    prof = job.train.active
    runs: list[TrainingRun] = []
    owners: list[int] = []  # the policy each run trains
    for k, training in enumerate(trainings):
        data = training.data
        for seed in prof.seeds:
            label = f"train {training.name} seed {seed}"
            runs.append(TrainingRun(data.train, data.val, training.config, seed, label, len(runs)))
            owners.append(k)
    # the stacked network is the LSTM's alone: image policies train as networks of their own
    on_gpu = torch.device(runs[0].config.device).type == "cuda" and not image
    results = (
        stacked_trainings(runs) if on_gpu else run_trainings(runs, job.side_by_side, prof.threads)
    )
    curves: list[list[dict[str, float]]] = [[] for _ in trainings]
    finished = 0
    try:
        for k, run, (history, checkpoints) in zip(owners, runs, results, strict=True):
            training = trainings[k]
            for epoch, model in checkpoints:
                step = epoch * training.config.steps_per_epoch
                meta = {**training.meta, "seed": run.seed, "epoch": epoch, "step": step}
                save_checkpoint(checkpoint_path(directories[k], run.seed, epoch), model, meta)
            curves[k] += [{"seed": run.seed, **r} for r in history]
            finished += 1
    except Interrupted as exc:
        exc.detail = f"with {finished} of {len(runs)} trainings finished"
        raise
    return curves


def training_metrics(
    train: TrainParams,
    training: PolicyTraining,
    curve: Sequence[dict[str, float]],
    side_by_side: int,
) -> dict[str, Any]:
    """A policy's training metrics from its curve (:func:`train_policies`): the final
    training and validation losses (mean over training seeds), gradient steps and wall time
    [s] over all seeds, each (seed, epoch, seconds since the start) of the curve
    (``epoch_seconds``), and how the trainings ran (torch threads, trainings side by
    side)."""
    prof = train.active
    last = [r for r in curve if r["epoch"] == prof.epochs]
    seconds = sum(r["seconds"] for r in last)
    steps = prof.epochs * prof.steps_per_epoch * len(prof.seeds)
    return {
        "profile": train.profile,
        "seeds": len(prof.seeds),
        "data_run_id": training.meta["data_run_id"],
        "train_episodes": training.meta["train_episodes"],
        "val_episodes": training.meta["val_episodes"],
        "gradient_steps": steps,
        "final_loss": float(np.mean([r["loss"] for r in last])),
        "final_val_loss": float(np.mean([r["val_loss"] for r in last])),
        "wall_seconds": seconds,
        "seconds_per_1000_steps": 1000 * seconds / steps,
        "epoch_seconds": [[int(r["seed"]), int(r["epoch"]), r["seconds"]] for r in curve],
        "torch_threads": prof.threads or torch.get_num_threads(),
        "trainings_side_by_side": side_by_side,
        **{k: v for k, v in training.meta.items() if k == "task_version"},
    }


def default_device() -> str:
    return "cuda" if torch.cuda.is_available() else "cpu"


def load_rollout_policy(path: str, component: str = "drawn") -> RolloutPolicy:
    """A checkpoint as a policy for mimicgen_pipe.learn.evaluation (picklable by name; component:
    mimicgen_pipe.learn.policy.COMPONENTS)."""
    return RolloutPolicy(load_checkpoint(path)[0], component)
