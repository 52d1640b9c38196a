"""A LeRobot policy directory (``config.json`` + ``model.safetensors``, as ``lerobot-train``
saves a checkpoint's ``pretrained_model``), trained on our LeRobot export: its inputs are
the export's ``observation.state`` and ``observation.environment_state`` (built by the
exporter's own function from params' train.obs_keys) and ``observation.images.<camera>``.

The server loads it with the policy class's ``from_pretrained`` (safetensors, JSON) and its
saved pre/post-processors (normalisation: JSON and safetensors), each processor step one
that lerobot registered by name (a step naming a class to import is refused). It acts as
lerobot's own evaluation does: observation -> preprocessor -> ``select_action`` ->
postprocessor, its random state seeded at each reset.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

DESCRIPTION = "LeRobot policy directory: config.json, model.safetensors, processors"
PROCESSORS = ("policy_preprocessor.json", "policy_postprocessor.json")
# ACT, Diffusion Policy and VQ-BeT build their image encoder as
# getattr(torchvision.models, config.vision_backbone)(...): any callable of that module by a
# name from the file; only these backbones are accepted
BACKBONES = ("resnet18", "resnet34", "resnet50")


def run_checkpoints(path: Path) -> list[Path]:
    """A policy folder (a pretrained_model) is one checkpoint."""
    return [path]


def why_not(path: Path) -> str | None:
    """A directory with config.json (a JSON object naming the policy ``type``),
    model.safetensors and the pre/post-processors (normalisation) lerobot saves beside
    them, else why not."""
    if not path.is_dir():
        return f"{path}: no such directory"
    files = ("config.json", "model.safetensors", *PROCESSORS)
    missing = [f for f in files if not (path / f).is_file()]
    if missing:
        return f"{path}: no {' and no '.join(missing)} (not a LeRobot policy directory)"
    try:
        config = json.loads((path / "config.json").read_text())
    except (ValueError, UnicodeDecodeError) as exc:
        return f"{path}/config.json: not JSON ({exc})"
    except RecursionError:  # json recurses once per level of nesting
        return f"{path}/config.json: JSON nested too deep for a policy config"
    if not isinstance(config, dict) or not isinstance(config.get("type"), str):
        return f"{path}/config.json: names no policy type"
    backbone = config.get("vision_backbone")
    if backbone is not None and backbone not in BACKBONES:
        shown = repr(backbone)[:60]
        return (
            f"{path}/config.json: vision_backbone {shown} is not a backbone this server builds "
            f"(one of {', '.join(BACKBONES)})"
        )
    return None


def observation(obs: dict[str, np.ndarray], obs_keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """One frame's features as the LeRobot export writes them."""
    from mimicgen_pipe.exporters.lerobot import observation_features, state_keys

    frame = {k: np.asarray(obs[k])[None] for k in obs_keys}
    out = {k: v[0] for k, v in observation_features(frame, state_keys(obs_keys)).items()}
    images = {image_key(k.removesuffix("_image")): v for k, v in obs.items()
              if k.endswith("_image")}  # fmt: skip
    return out | images


def image_key(camera: str) -> str:
    """As the export names a camera's video feature (uint8 HWC frames here)."""
    return f"observation.images.{camera}"


def _check_processors(path: Path) -> None:
    """ValueError for a saved processor step that names a class to import rather than a
    step lerobot registered."""
    for name in PROCESSORS:
        steps = json.loads((path / name).read_text()).get("steps", [])
        named = [s.get("class") for s in steps if "registry_name" not in s]
        if named:
            raise ValueError(f"{path / name}: steps {named} name classes to import")


class LeRobotPolicy:
    """The policy directory at ``path`` on the CPU, with its processors."""

    def __init__(self, path: str, task: str) -> None:
        import os

        os.environ.setdefault("HF_HUB_OFFLINE", "1")  # a local directory: never the Hub
        import torch
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.configs.types import FeatureType
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors

        self._torch, self.task = torch, task
        # one thread, like the evaluator's workers: its env steps in the other process
        torch.set_num_threads(1)
        config = PreTrainedConfig.from_pretrained(path)
        config.device = "cpu"
        self.policy = get_policy_class(config.type).from_pretrained(path, config=config)
        _check_processors(Path(path))
        self.pre, self.post = make_pre_post_processors(config, pretrained_path=path)
        self.observations: dict[str, dict[str, Any]] = {}
        self._images = set()
        for key, feature in config.input_features.items():
            shape = list(feature.shape)
            if feature.type == FeatureType.VISUAL:
                c, h, w = shape  # the policy's CHW float image in [0, 1]
                self.observations[key] = {"shape": [h, w, c], "dtype": "uint8"}
                self._images.add(key)
            else:
                self.observations[key] = {"shape": shape, "dtype": "float32"}
        self.action_dim = int(np.prod(config.output_features["action"].shape))
        self.meta: dict[str, Any] = {}

    def reset(self, seed: int) -> None:
        self._torch.manual_seed(seed)
        np.random.seed(seed % 2**32)
        self.policy.reset()
        self.pre.reset()
        self.post.reset()

    def act(self, arrays: dict[str, np.ndarray]) -> np.ndarray:
        torch = self._torch
        batch: dict[str, Any] = {"task": [self.task]}
        for key in self.observations:
            x = torch.from_numpy(np.ascontiguousarray(arrays[key]))[None]
            if key in self._images:  # HWC uint8 -> CHW float in [0, 1], as lerobot's envs
                x = x.permute(0, 3, 1, 2).float() / 255.0
            batch[key] = x.float()
        with torch.inference_mode():
            action = self.post(self.policy.select_action(self.pre(batch)))
        return action[0].cpu().numpy()


def load(path: str, task: str) -> LeRobotPolicy:
    return LeRobotPolicy(path, task)


EPOCH_UNIT = "step"  # lerobot-train counts its training in steps, and saves by step


def checkpoint_epoch(path: Path) -> int | None:
    """The training step of a ``pretrained_model`` directory as lerobot-train saves it in
    ``checkpoints/<step>/``: the step of ``training_state/training_step.json`` beside it,
    else its folder's name (``last`` followed to the step it links to); None for a
    directory elsewhere."""
    folder = path.resolve().parent
    try:
        step = json.loads((folder / "training_state" / "training_step.json").read_text())["step"]
    except (OSError, ValueError, KeyError, TypeError):
        step = None
    if type(step) is int and step >= 0:
        return step
    return int(folder.name) if folder.name.isdigit() and path.name == "pretrained_model" else None
