"""BC-RNN (robomimic's recurrent behavioural cloning, paper N): an LSTM over a sequence of
low-dim observations with a Gaussian-mixture action head, written in PyTorch.

Observations are normalised with the training set's mean and std (stored in the model, so a
checkpoint is self-contained). The mixture's means are squashed by tanh into the action
range [-1, 1]; its scales are softplus + ``min_std``. At rollout time the hidden state is
reset every ``seq_len`` steps, so the policy always sees a context like the training
windows, and actions are drawn from the mixture with a tiny fixed scale (robomimic's
"low noise" evaluation): the component is drawn, the spread is not. ``component="most_likely"``
takes the component of the largest weight instead (a rollout-protocol factor; not the
default, as robomimic draws it).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn
from torch.distributions import Categorical, Independent, MixtureSameFamily, Normal

EVAL_STD = 1e-4
COMPONENTS = ("drawn", "most_likely")  # how RolloutPolicy picks the mixture component


@dataclass(frozen=True)
class PolicyConfig:
    """obs_keys / obs_dims: the observation layout (concatenated in this order).
    hidden, layers: LSTM size. seq_len: training window and rollout context [steps].
    modes: Gaussian-mixture components."""

    obs_keys: tuple[str, ...]
    obs_dims: tuple[int, ...]
    action_dim: int
    hidden: int = 400
    layers: int = 2
    seq_len: int = 10
    modes: int = 5
    min_std: float = 1e-4

    @property
    def obs_dim(self) -> int:
        return int(sum(self.obs_dims))

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> PolicyConfig:
        d = dict(d)
        d["obs_keys"], d["obs_dims"] = tuple(d["obs_keys"]), tuple(d["obs_dims"])
        return cls(**d)


class BCRNN(nn.Module):
    """LSTM + GMM head. ``forward`` maps (B, T, obs_dim) raw observations to a mixture over
    (B, T, action_dim) actions."""

    def __init__(self, config: PolicyConfig) -> None:
        super().__init__()
        self.config = config
        self.register_buffer("obs_mean", torch.zeros(config.obs_dim))
        self.register_buffer("obs_std", torch.ones(config.obs_dim))
        self.lstm = nn.LSTM(config.obs_dim, config.hidden, config.layers, batch_first=True)
        a, k = config.action_dim, config.modes
        self.means = nn.Linear(config.hidden, k * a)
        self.scales = nn.Linear(config.hidden, k * a)
        self.logits = nn.Linear(config.hidden, k)

    def set_normalisation(self, mean: np.ndarray, std: np.ndarray) -> None:
        self.obs_mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
        # constant features (std 0) pass through centred instead of blowing up
        self.obs_std.copy_(torch.as_tensor(np.where(std < 1e-6, 1.0, std), dtype=torch.float32))

    def forward(
        self, obs: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor] | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """Returns mixture (means, scales, logits) with shapes (B, T, K, A), (B, T, K, A),
        (B, T, K) and the LSTM state."""
        h, state = self.lstm((obs - self.obs_mean) / self.obs_std, state)
        b, t = h.shape[:2]
        k, a = self.config.modes, self.config.action_dim
        means = torch.tanh(self.means(h)).view(b, t, k, a)
        scales = nn.functional.softplus(self.scales(h)).view(b, t, k, a) + self.config.min_std
        return means, scales, self.logits(h), state


def mixture(means: torch.Tensor, scales: torch.Tensor, logits: torch.Tensor):
    return MixtureSameFamily(Categorical(logits=logits), Independent(Normal(means, scales), 1))


def nll_loss(model: BCRNN, obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
    """Mean negative log-likelihood of (B, T, A) actions under the policy's mixture."""
    means, scales, logits, _ = model(obs)
    return -mixture(means, scales, logits).log_prob(actions).mean()


class RolloutPolicy:
    """A trained BC-RNN acting one step at a time: ``reset(seed)`` at each episode start,
    then ``act(obs)`` with the observation dict of mimicgen_pipe.observations.
    component: one of ``COMPONENTS``, the mixture component acted on at each step."""

    def __init__(self, model: BCRNN, component: str = "drawn") -> None:
        if component not in COMPONENTS:
            raise ValueError(f"component: expected one of {COMPONENTS}, got {component!r}")
        self.component = component
        self.model = model.eval()
        self.keys = model.config.obs_keys
        self._state: tuple[torch.Tensor, torch.Tensor] | None = None
        self._t = 0
        self._gen = torch.Generator()

    def reset(self, seed: int) -> None:
        self._state, self._t = None, 0
        self._gen.manual_seed(int(seed))

    @torch.no_grad()
    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        if self._t % self.model.config.seq_len == 0:
            self._state = None
        self._t += 1
        x = torch.from_numpy(np.concatenate([obs[k] for k in self.keys]).astype(np.float32))
        means, _, logits, self._state = self.model(x.view(1, 1, -1), self._state)
        if self.component == "drawn":
            k = int(torch.multinomial(torch.softmax(logits[0, 0], -1), 1, generator=self._gen))
        else:
            k = int(torch.argmax(logits[0, 0]))
        mean = means[0, 0, k]
        noise = torch.randn(mean.shape, generator=self._gen) * EVAL_STD
        return (mean + noise).numpy().astype(np.float32)
