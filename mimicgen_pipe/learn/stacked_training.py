"""Several BC-RNN trainings as one stacked network, for a GPU.

A BC-RNN of the paper's size keeps a GPU nearly idle: its kernels are tiny and each waits
for the one before. Here the trainings of one architecture (several seeds, tasks or
datasets) are one network whose every weight is a stack, one slice per policy, so that one
batched matrix product per LSTM step serves all of them; on CUDA a whole training step of
all of them is captured once as a CUDA graph and replayed.

Each slice trains as :func:`mimicgen_pipe.learn.training.train_policy` trains its policy: the
same initialisation for its seed, the same normalisation, mixture NLL, Adam and window
sampling (uniform over the training steps, padded at episode ends). What differs: the
windows are drawn on the device from one generator for the stack, and float rounding;
GPU training is not bit-reproducible. Observation widths may differ between slices: each is
zero-padded to the widest, a padded column's weights see zero input, so their gradient is 0
and Adam leaves them untouched, and they are dropped from a policy's state dict.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence

import numpy as np
import torch
from torch import nn

from mimicgen_pipe.learn.policy import BCRNN
from mimicgen_pipe.learn.training_setup import (
    SequenceData,
    TrainConfig,
    TrainingRun,
    annealed_lr,
    initial_policy,
    validation_windows,
)

LOG_SQRT_2PI = 0.5 * math.log(2 * math.pi)
WARMUP_STEPS = 3  # eager steps before a CUDA graph is captured (allocator and cuDNN warm-up)


class StackedBCRNN(nn.Module):
    """``len(models)`` BC-RNNs of one architecture as stacked weights: LSTM layer l's
    ``weight_ih[l]`` (M, 4H, D_l), ``weight_hh[l]`` (M, 4H, H), biases (M, 4H), heads
    (M, out, H) and (M, out); observations padded to the widest model's, D."""

    def __init__(self, models: Sequence[BCRNN]) -> None:
        super().__init__()
        c = models[0].config
        for m in models:
            k = m.config
            same = (k.hidden, k.layers, k.seq_len, k.modes, k.action_dim, k.min_std)
            if same != (c.hidden, c.layers, c.seq_len, c.modes, c.action_dim, c.min_std):
                raise ValueError(
                    f"stacked policies need one architecture: {k} differs from {c} beyond "
                    "its observations"
                )
        self.hidden, self.layers, self.modes = c.hidden, c.layers, c.modes
        self.action_dim, self.min_std = c.action_dim, c.min_std
        self.obs_dims = [m.config.obs_dim for m in models]
        width = max(self.obs_dims)

        def stack(get: Callable[[BCRNN], torch.Tensor], pad: float | None = None) -> torch.Tensor:
            rows = [get(m).detach().float() for m in models]
            if pad is not None:  # the observation axis (last) to the widest
                rows = [nn.functional.pad(r, (0, width - r.shape[-1]), value=pad) for r in rows]
            return torch.stack(rows)

        self.register_buffer("obs_mean", stack(lambda m: m.obs_mean, 0.0))
        self.register_buffer("obs_std", stack(lambda m: m.obs_std, 1.0))

        def lstm(name: str, layer: int, pad: bool = False) -> nn.Parameter:
            return nn.Parameter(
                stack(lambda m: getattr(m.lstm, f"{name}_l{layer}"), 0.0 if pad else None)
            )

        self.weight_ih = nn.ParameterList(
            [lstm("weight_ih", k, pad=k == 0) for k in range(self.layers)]
        )
        self.weight_hh = nn.ParameterList([lstm("weight_hh", k) for k in range(self.layers)])
        self.bias_ih = nn.ParameterList([lstm("bias_ih", k) for k in range(self.layers)])
        self.bias_hh = nn.ParameterList([lstm("bias_hh", k) for k in range(self.layers)])
        self.heads = nn.ParameterDict()
        for head in ("means", "scales", "logits"):
            self.heads[f"{head}_weight"] = nn.Parameter(
                stack(lambda m, h=head: getattr(m, h).weight)
            )
            self.heads[f"{head}_bias"] = nn.Parameter(stack(lambda m, h=head: getattr(m, h).bias))

    def _cell(
        self, x_gates: torch.Tensor, h: torch.Tensor, c: torch.Tensor, w_hh: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One LSTM step of every slice: gates (M, B, 4H) from the input, state (M, B, H)."""
        gates = torch.baddbmm(x_gates, h, w_hh.transpose(1, 2))
        i, f, g, o = gates.chunk(4, -1)  # nn.LSTM's gate order
        c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
        return torch.sigmoid(o) * torch.tanh(c), c

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(M, B, T, D) raw observations -> mixture means, scales (M, B, T, K, A) and logits
        (M, B, T, K), from a zero LSTM state as in training."""
        m, b, t, _ = obs.shape
        x = (obs - self.obs_mean[:, None, None]) / self.obs_std[:, None, None]
        for k in range(self.layers):
            bias = (self.bias_ih[k] + self.bias_hh[k])[:, None]
            gates = torch.baddbmm(bias, x.reshape(m, b * t, -1), self.weight_ih[k].transpose(1, 2))
            gates = gates.view(m, b, t, -1).permute(2, 0, 1, 3).contiguous()  # (T, M, B, 4H)
            h = c = obs.new_zeros(m, b, self.hidden)
            steps = []
            for s in range(t):
                h, c = self._cell(gates[s], h, c, self.weight_hh[k])
                steps.append(h)
            x = torch.stack(steps, 2)
        flat = x.reshape(m, b * t, self.hidden)

        def head(name: str) -> torch.Tensor:
            w, bias = self.heads[f"{name}_weight"], self.heads[f"{name}_bias"]
            return torch.baddbmm(bias[:, None], flat, w.transpose(1, 2))

        shape = (m, b, t, self.modes, self.action_dim)
        means = torch.tanh(head("means")).view(shape)
        scales = nn.functional.softplus(head("scales")).view(shape) + self.min_std
        return means, scales, head("logits").view(m, b, t, self.modes)

    def policy_state(self, index: int) -> dict[str, torch.Tensor]:
        """Slice ``index`` as a BCRNN state dict (CPU tensors, padding dropped)."""
        d = self.obs_dims[index]
        out = {"obs_mean": self.obs_mean[index, :d], "obs_std": self.obs_std[index, :d]}
        for k in range(self.layers):
            out[f"lstm.weight_ih_l{k}"] = (
                self.weight_ih[k][index][:, :d] if k == 0 else (self.weight_ih[k][index])
            )
            out[f"lstm.weight_hh_l{k}"] = self.weight_hh[k][index]
            out[f"lstm.bias_ih_l{k}"] = self.bias_ih[k][index]
            out[f"lstm.bias_hh_l{k}"] = self.bias_hh[k][index]
        for head in ("means", "scales", "logits"):
            out[f"{head}.weight"] = self.heads[f"{head}_weight"][index]
            out[f"{head}.bias"] = self.heads[f"{head}_bias"][index]
        return {k: v.detach().cpu().clone().contiguous() for k, v in out.items()}


def stacked_nll(
    means: torch.Tensor, scales: torch.Tensor, logits: torch.Tensor, actions: torch.Tensor
) -> torch.Tensor:
    """Negative log-likelihood (M, B, T) of (M, B, T, A) actions under each step's mixture
    (the arithmetic of torch.distributions' MixtureSameFamily of diagonal Normals)."""
    z = (actions[..., None, :] - means) / scales
    log_normal = (-0.5 * z * z - scales.log() - LOG_SQRT_2PI).sum(-1)
    return -torch.logsumexp(log_normal + torch.log_softmax(logits, -1), -1)


class _Windows:
    """Every run's steps in one (N, D) array on the device, and each run's window draws:
    ``batch`` window starts uniform over the run's own steps, windows padded at episode ends
    by repeating the last step (mimicgen_pipe.learn.training_setup.window_index)."""

    def __init__(
        self, datas: Sequence[SequenceData], width: int, seq_len: int, device: torch.device
    ) -> None:
        counts = [len(d.obs) for d in datas]
        offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
        obs = np.zeros((sum(counts), width), np.float32)
        for d, o in zip(datas, offsets, strict=True):
            obs[o : o + len(d.obs), : d.obs.shape[1]] = d.obs
        ends = np.concatenate([d.episode_ends + o for d, o in zip(datas, offsets, strict=True)])
        self.obs = torch.from_numpy(obs).to(device)
        self.actions = torch.from_numpy(np.concatenate([d.actions for d in datas])).to(device)
        self.ends = torch.from_numpy(ends.astype(np.int64)).to(device)
        self.offsets = torch.as_tensor(offsets, dtype=torch.int64, device=device)
        self.counts = torch.as_tensor(counts, dtype=torch.float64, device=device)
        self.steps = torch.arange(seq_len, device=device)

    def draw(self, batch: int) -> tuple[torch.Tensor, torch.Tensor]:
        u = torch.rand(len(self.offsets), batch, dtype=torch.float64, device=self.obs.device)
        starts = self.offsets[:, None] + (u * self.counts[:, None]).long()
        last = self.ends[torch.searchsorted(self.ends, starts, right=True)] - 1
        index = torch.minimum(starts[..., None] + self.steps, last[..., None])
        return self.obs[index], self.actions[index]


def _validation(
    runs: Sequence[TrainingRun], width: int, device: torch.device
) -> tuple[torch.Tensor, ...]:
    """Each run's fixed validation windows (training_setup.validation_windows), padded to the
    most windows by repeating its first: obs (M, V, T, D), actions, and a (M, V) weight that
    averages each run's own windows."""
    seq_len = runs[0].config.policy.seq_len
    windows = [validation_windows(r.val_data, seq_len) for r in runs]
    most = max(len(w) for w in windows)
    obs = np.zeros((len(runs), most, seq_len, width), np.float32)
    actions = np.zeros((len(runs), most, seq_len, runs[0].train_data.actions.shape[1]), np.float32)
    weight = np.zeros((len(runs), most), np.float32)
    for i, (r, w) in enumerate(zip(runs, windows, strict=True)):
        padded = np.concatenate([w, np.repeat(w[:1], most - len(w), 0)])
        obs[i, :, :, : r.val_data.obs.shape[1]] = r.val_data.obs[padded]
        actions[i] = r.val_data.actions[padded]
        weight[i, : len(w)] = 1.0 / len(w)
    return tuple(torch.from_numpy(a).to(device) for a in (obs, actions, weight))


def train_stacked(
    runs: Sequence[TrainingRun],
    on_checkpoint: Callable[[int, int, dict[str, torch.Tensor]], None],
    progress: Callable[[int, list[dict[str, float]]], None] | None = None,
    deadline: float | None = None,
    graph: bool = True,
) -> list[list[dict[str, float]]]:
    """Train every run of ``runs`` (one architecture and schedule, any seeds and data) as one
    stacked network on the runs' device. Calls ``on_checkpoint(run, epoch, state_dict)``
    every ``checkpoint_every`` epochs and at the last, with the run's BCRNN state dict.
    ``graph``: on CUDA, replay each training step as a CUDA graph (eager where capture fails).
    ``deadline`` [s]: stop after the first epoch that ends past it (that epoch checkpointed).

    Returns each run's rows as train_policy's (epoch, step, loss, val_loss, seconds), where
    seconds is the run's share of the stack's wall time (wall / M), so that a stack's runs
    sum to its wall time like runs trained one after another."""
    configs = {_schedule(r) for r in runs}
    if len(configs) != 1:
        raise ValueError(f"stacked runs need one schedule, got {sorted(map(str, configs))}")
    cfg = runs[0].config
    device = torch.device(cfg.device)
    # each policy set up as train_policy sets it up: seed, then build, then normalise
    models = [initial_policy(r.config.policy, r.train_data, r.seed) for r in runs]
    net = StackedBCRNN(models).to(device)
    width = max(net.obs_dims)
    torch.manual_seed(runs[0].seed)  # the stack's window draws
    data = _Windows([r.train_data for r in runs], width, cfg.policy.seq_len, device)
    val = _validation(runs, width, device) if all(r.val_data.n_episodes for r in runs) else None
    steps = _StackSteps(net, data, cfg, graph and device.type == "cuda")
    history: list[list[dict[str, float]]] = [[] for _ in runs]
    t0 = time.perf_counter()
    for epoch in range(1, cfg.epochs + 1):
        net.train()
        losses = steps.epoch()
        vals = _validation_losses(net, val, len(runs))
        seconds = (time.perf_counter() - t0) / len(runs)
        rows = [
            {"epoch": epoch, "step": steps.done, "loss": lo, "val_loss": va, "seconds": seconds}
            for lo, va in zip(losses, vals, strict=True)
        ]
        for h, row in zip(history, rows, strict=True):
            h.append(row)
        if progress is not None:
            progress(epoch, rows)
        late = deadline is not None and time.perf_counter() - t0 > deadline
        if epoch % cfg.checkpoint_every == 0 or epoch == cfg.epochs or late:
            for i in range(len(runs)):
                on_checkpoint(i, epoch, net.policy_state(i))
        if late:
            break
    return history


class _StackSteps:
    """The stack's gradient steps: each draws every run's windows, runs the network forward
    and backward, steps Adam and adds each run's loss to its sum. With ``cuda_graph``, the
    first WARMUP_STEPS run eagerly on a side stream, then one step is captured as a CUDA graph
    and replayed (eager steps from there where capture fails)."""

    def __init__(
        self, net: StackedBCRNN, data: _Windows, config: TrainConfig, cuda_graph: bool
    ) -> None:
        device = data.obs.device
        self.net, self.data, self.config, self.cuda_graph = net, data, config, cuda_graph
        self.opt = torch.optim.Adam(
            net.parameters(),
            lr=torch.tensor(config.lr, device=device) if cuda_graph else config.lr,
            capturable=cuda_graph,
        )
        self.loss_sum = torch.zeros(len(net.obs_dims), device=device)
        self.replay: Callable[[], None] | None = None
        self.side = torch.cuda.Stream() if cuda_graph else None
        self.done = 0  # gradient steps so far

    def step(self) -> None:
        """One gradient step of every run (what a CUDA graph captures)."""
        obs, actions = self.data.draw(self.config.batch_size)
        per_run = stacked_nll(*self.net(obs), actions).mean((1, 2))
        per_run.sum().backward()  # each slice's gradient is its own mean loss's
        self.opt.step()
        self.loss_sum.add_(per_run.detach())

    def next(self) -> None:
        """The next gradient step, replayed, warmed up or eager; then the learning rate."""
        if self.replay is None and self.cuda_graph and self.done >= WARMUP_STEPS:
            self.replay = _capture(self.step, self.opt)  # None: capture failed, eager from here
            self.cuda_graph = self.replay is not None
        if self.replay is not None:
            self.replay()
        elif self.cuda_graph and self.side is not None:
            # warm-up before capture, on a side stream as capture wants
            self.side.wait_stream(torch.cuda.current_stream())
            with torch.cuda.stream(self.side):
                self.opt.zero_grad(set_to_none=True)
                self.step()
            torch.cuda.current_stream().wait_stream(self.side)
        else:
            self.opt.zero_grad(set_to_none=True)
            self.step()
        self.done += 1
        _set_lr(self.opt, self.config, self.done)

    def epoch(self) -> list[float]:
        """An epoch's steps; each run's mean training loss over them."""
        for _ in range(self.config.steps_per_epoch):
            self.next()
        losses = (self.loss_sum / self.config.steps_per_epoch).tolist()
        self.loss_sum.zero_()
        return losses


def _set_lr(opt: torch.optim.Optimizer, config: TrainConfig, done: int) -> None:
    """``opt``'s learning rate after ``done`` steps: annealed as train_policy anneals it
    (annealed_lr), in place where the rate is a tensor (a CUDA graph reads it there)."""
    if config.lr_schedule != "cosine":
        return
    lr = annealed_lr(config, done)
    for group in opt.param_groups:
        if isinstance(group["lr"], torch.Tensor):
            group["lr"].fill_(lr)
        else:
            group["lr"] = lr


def _validation_losses(
    net: StackedBCRNN, val: tuple[torch.Tensor, ...] | None, n_runs: int
) -> list[float]:
    """Each run's mean NLL on its validation windows (_validation); NaN without them."""
    if val is None:
        return [float("nan")] * n_runs
    net.eval()
    with torch.no_grad():
        obs, actions, weight = val
        return (stacked_nll(*net(obs), actions).mean(-1) * weight).sum(1).tolist()


def _schedule(run: TrainingRun) -> tuple:
    """What stacked runs must share beside the architecture (StackedBCRNN checks that)."""
    c = run.config
    return (
        c.batch_size,
        c.lr,
        c.epochs,
        c.steps_per_epoch,
        c.checkpoint_every,
        c.lr_schedule,
        c.device,
    )


def _capture(step: Callable[[], None], opt: torch.optim.Optimizer) -> Callable[[], None] | None:
    """``step`` (draw, forward, backward, Adam, loss sum) as a CUDA graph's replay, or None
    where capture fails (the step then runs eagerly)."""
    graph = torch.cuda.CUDAGraph()
    try:
        torch.cuda.synchronize()
        opt.zero_grad(set_to_none=True)  # backward inside the graph writes fresh gradients
        with torch.cuda.graph(graph):
            step()
    except Exception as exc:  # noqa: BLE001 - any failure to capture leaves eager steps
        print(f"CUDA graph capture failed ({' '.join(str(exc).split())[:200]}); eager steps")
        torch.cuda.synchronize()
        return None
    return graph.replay
