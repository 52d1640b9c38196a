"""BC-RNN (robomimic's recurrent behavioural cloning, paper N): an LSTM over a sequence of
low-dim observations, and for an image policy camera images, with a Gaussian-mixture action
head, written in PyTorch.

An image policy (``PolicyConfig.image_keys``, the paper's image agents) encodes each
camera's image with its own small convolutional encoder trained from scratch
(:class:`ImageEncoder`: strided convolutions reduced by a spatial softmax to keypoint
coordinates, as robomimic's image agents reduce their features) and feeds the features to
the LSTM beside the low-dim observation.

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


# PolicyConfig's fields of an image policy, left out of a low-dim policy's as_dict, so that
# low-dim checkpoints keep the bytes they had before image policies
IMAGE_FIELDS = ("image_keys", "image_size", "channels", "keypoints", "image_features")


@dataclass(frozen=True)
class PolicyConfig:
    """obs_keys / obs_dims: the low-dim observation layout (concatenated in this order).
    hidden, layers: LSTM size. seq_len: training window and rollout context [steps].
    modes: Gaussian-mixture components.

    image_keys: for an image policy, the observation keys of its camera images
    (``<camera>_image``, each (height, width, 3) uint8 RGB of ``image_size`` (height, width)
    [px]), one :class:`ImageEncoder` each of ``channels`` convolution channels,
    ``keypoints`` spatial-softmax keypoints and ``image_features`` output features; empty:
    a low-dim policy."""

    obs_keys: tuple[str, ...]
    obs_dims: tuple[int, ...]
    action_dim: int
    hidden: int = 400
    layers: int = 2
    seq_len: int = 10
    modes: int = 5
    min_std: float = 1e-4
    image_keys: tuple[str, ...] = ()
    image_size: tuple[int, int] = (84, 84)
    channels: int = 32
    keypoints: int = 32
    image_features: int = 64

    @property
    def obs_dim(self) -> int:
        return int(sum(self.obs_dims))

    @property
    def lstm_input(self) -> int:
        """The LSTM's input width: the low-dim observation, then each camera's features."""
        return self.obs_dim + len(self.image_keys) * self.image_features

    def as_dict(self) -> dict:
        d = asdict(self)
        if not self.image_keys:
            for key in IMAGE_FIELDS:
                del d[key]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> PolicyConfig:
        d = dict(d)
        for key in ("obs_keys", "obs_dims", "image_keys", "image_size"):
            if key in d:
                d[key] = tuple(d[key])
        return cls(**d)


class ImageEncoder(nn.Module):
    """One camera's encoder: (N, H, W, 3) uint8 RGB images -> (N, features) float. Three
    ReLU convolutions (5x5 stride 2, 3x3 stride 2, 3x3), a 1x1 convolution to ``keypoints``
    maps, a spatial softmax that takes each map's expected pixel position as (x, y) in
    [-1, 1] of the image (robomimic's keypoint reduction), and a linear layer."""

    def __init__(self, height: int, width: int, channels: int, keypoints: int, features: int):
        super().__init__()
        c = channels
        self.conv = nn.Sequential(
            nn.Conv2d(3, c, 5, stride=2),
            nn.ReLU(),
            nn.Conv2d(c, c, 3, stride=2),
            nn.ReLU(),
            nn.Conv2d(c, c, 3),
            nn.ReLU(),
            nn.Conv2d(c, keypoints, 1),
        )
        h, w = height, width  # the keypoint maps' size, through each convolution
        for conv in self.conv:
            if isinstance(conv, nn.Conv2d):
                (kh, kw), (sh, sw) = conv.kernel_size, conv.stride
                h, w = (h - kh) // sh + 1, (w - kw) // sw + 1
        if h < 1 or w < 1:
            raise ValueError(f"images of {height}x{width} px are too small for the encoder")
        ys, xs = torch.meshgrid(torch.linspace(-1, 1, h), torch.linspace(-1, 1, w), indexing="ij")
        self.register_buffer("grid", torch.stack([xs.reshape(-1), ys.reshape(-1)], -1))
        self.out = nn.Linear(2 * keypoints, features)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        x = images.permute(0, 3, 1, 2).float() / 255.0 - 0.5
        maps = self.conv(x).flatten(2)  # (N, K, h*w)
        keypoints = torch.softmax(maps, -1) @ self.grid  # (N, K, 2): expected (x, y)
        return self.out(keypoints.flatten(1))


class BCRNN(nn.Module):
    """LSTM + GMM head. ``forward`` maps (B, T, obs_dim) raw low-dim observations, and for an
    image policy (B, T, cameras, H, W, 3) uint8 images, to a mixture over (B, T,
    action_dim) actions."""

    def __init__(self, config: PolicyConfig) -> None:
        super().__init__()
        self.config = config
        self.register_buffer("obs_mean", torch.zeros(config.obs_dim))
        self.register_buffer("obs_std", torch.ones(config.obs_dim))
        self.lstm = nn.LSTM(config.lstm_input, config.hidden, config.layers, batch_first=True)
        a, k = config.action_dim, config.modes
        self.means = nn.Linear(config.hidden, k * a)
        self.scales = nn.Linear(config.hidden, k * a)
        self.logits = nn.Linear(config.hidden, k)
        if config.image_keys:  # made last: a low-dim policy's seeded weights stay as they were
            h, w = config.image_size
            self.encoders = nn.ModuleList(
                ImageEncoder(h, w, config.channels, config.keypoints, config.image_features)
                for _ in config.image_keys
            )

    def set_normalisation(self, mean: np.ndarray, std: np.ndarray) -> None:
        self.obs_mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
        # constant features (std 0) pass through centred instead of blowing up
        self.obs_std.copy_(torch.as_tensor(np.where(std < 1e-6, 1.0, std), dtype=torch.float32))

    def forward(
        self,
        obs: torch.Tensor,
        state: tuple[torch.Tensor, torch.Tensor] | None = None,
        images: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """Returns mixture (means, scales, logits) with shapes (B, T, K, A), (B, T, K, A),
        (B, T, K) and the LSTM state. ``images``: an image policy's, camera axis in
        config.image_keys order."""
        x = (obs - self.obs_mean) / self.obs_std
        if self.config.image_keys:
            if images is None:
                raise ValueError(f"an image policy needs images of {self.config.image_keys}")
            b, t = obs.shape[:2]
            frames = images.reshape(b * t, *images.shape[2:])
            features = [enc(frames[:, i]).view(b, t, -1) for i, enc in enumerate(self.encoders)]
            x = torch.cat([x, *features], -1)
        h, state = self.lstm(x, state)
        b, t = h.shape[:2]
        k, a = self.config.modes, self.config.action_dim
        means = torch.tanh(self.means(h)).view(b, t, k, a)
        scales = nn.functional.softplus(self.scales(h)).view(b, t, k, a) + self.config.min_std
        return means, scales, self.logits(h), state


def mixture(means: torch.Tensor, scales: torch.Tensor, logits: torch.Tensor):
    return MixtureSameFamily(Categorical(logits=logits), Independent(Normal(means, scales), 1))


def nll_loss(
    model: BCRNN, obs: torch.Tensor, actions: torch.Tensor, images: torch.Tensor | None = None
) -> torch.Tensor:
    """Mean negative log-likelihood of (B, T, A) actions under the policy's mixture."""
    means, scales, logits, _ = model(obs, images=images)
    return -mixture(means, scales, logits).log_prob(actions).mean()


class RolloutPolicy:
    """A trained BC-RNN acting one step at a time: ``reset(seed)`` at each episode start,
    then ``act(obs)`` with the observation dict of mimicgen_pipe.core.observations.
    component: one of ``COMPONENTS``, the mixture component acted on at each step."""

    def __init__(self, model: BCRNN, component: str = "drawn") -> None:
        if component not in COMPONENTS:
            raise ValueError(f"component: expected one of {COMPONENTS}, got {component!r}")
        self.component = component
        self.model = model.eval()
        self.keys = model.config.obs_keys
        self.image_keys = model.config.image_keys
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
        images = None
        if self.image_keys:
            frames = np.stack([obs[k] for k in self.image_keys])  # (cameras, H, W, 3) uint8
            images = torch.from_numpy(frames)[None, None]
        means, _, logits, self._state = self.model(x.view(1, 1, -1), self._state, images)
        if self.component == "drawn":
            k = int(torch.multinomial(torch.softmax(logits[0, 0], -1), 1, generator=self._gen))
        else:
            k = int(torch.argmax(logits[0, 0]))
        mean = means[0, 0, k]
        noise = torch.randn(mean.shape, generator=self._gen) * EVAL_STD
        return (mean + noise).numpy().astype(np.float32)
