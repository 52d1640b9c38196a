"""A LeRobot policy directory (``config.json`` + ``model.safetensors``, as ``lerobot-train``
saves a checkpoint's ``pretrained_model``), trained on our LeRobot export: its inputs are
the export's ``observation.state`` and ``observation.environment_state`` (built by the
exporter's own function from params' train.obs_keys) and ``observation.images.<camera>``.

The server loads it with the policy class's ``from_pretrained`` (safetensors, JSON) and its
saved pre/post-processors (normalisation: JSON and safetensors). It acts as lerobot's own
evaluation does: observation -> preprocessor -> ``select_action`` -> postprocessor, its
random state seeded at each reset.

Nothing of the folder reaches outside it: its policy type is one whose network is built from
the folder's files alone, each processor step one of those lerobot saves for such a type,
and every file lerobot reads (a step's ``state_file`` among them) lies inside the folder, so
that the policy's sha256 covers it. A pretrained initialisation the config names
(``pretrained_backbone_weights``: ACT's default) is turned off, since every weight is then
loaded from ``model.safetensors`` (strictly).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

DESCRIPTION = "LeRobot policy directory: config.json, model.safetensors, processors"
PROCESSORS = ("policy_preprocessor.json", "policy_postprocessor.json")
# ACT, Diffusion Policy and VQ-BeT build their image encoder as
# getattr(torchvision.models, config.vision_backbone)(...): any callable of that module by a
# name from the file; only these backbones are accepted
BACKBONES = ("resnet18", "resnet34", "resnet50")
# the policy types whose networks are built from the folder alone; the others load models,
# processors or tokenizers by Hub name when built (pi0, smolvla, groot, sac's encoder, ...)
POLICY_TYPES = ("act", "diffusion", "tdmpc", "vqbet")
# the processor steps lerobot saves for those types, by their registered names; another
# step may load a model by name (a tokenizer, a reward classifier) or name a class to import
STEPS = (
    "rename_observations_processor",
    "to_batch_processor",
    "device_processor",
    "normalizer_processor",
    "unnormalizer_processor",
)


def run_checkpoints(path: Path) -> list[Path]:
    """A policy folder (a pretrained_model) is one checkpoint."""
    return [path]


def why_not(path: Path) -> str | None:
    """A directory with config.json (a JSON object naming one of :data:`POLICY_TYPES`),
    model.safetensors and the pre/post-processors (normalisation) lerobot saves beside
    them, each file inside it (:func:`why_outside`), else why not."""
    if not path.is_dir():
        return f"{path}: no such directory"
    files = ("config.json", "model.safetensors", *PROCESSORS)
    missing = [f for f in files if not (path / f).is_file()]
    if missing:
        return f"{path}: no {' and no '.join(missing)} (not a LeRobot policy directory)"
    outside = next((why for f in files if (why := why_outside(path, f, f))), None)
    if outside:
        return outside
    config = _json(path / "config.json")
    if isinstance(config, str):
        return config
    if not isinstance(config, dict) or not isinstance(config.get("type"), str):
        return f"{path}/config.json: names no policy type"
    if config["type"] not in POLICY_TYPES:
        return (
            f"{path}/config.json: type {config['type'][:60]!r} is not a policy this server "
            f"builds (one of {', '.join(POLICY_TYPES)})"
        )
    backbone = config.get("vision_backbone")
    if backbone is not None and backbone not in BACKBONES:
        shown = repr(backbone)[:60]
        return (
            f"{path}/config.json: vision_backbone {shown} is not a backbone this server builds "
            f"(one of {', '.join(BACKBONES)})"
        )
    return next((why for name in PROCESSORS if (why := _why_not_processor(path, name))), None)


def _json(file: Path) -> object:
    """The JSON in ``file``, or a str saying why it is not JSON."""
    try:
        return json.loads(file.read_text())
    except (ValueError, UnicodeDecodeError) as exc:
        return f"{file}: not JSON ({exc})"
    except RecursionError:  # json recurses once per level of nesting
        return f"{file}: JSON nested too deep for a policy config"


def why_outside(folder: Path, name: object, key: str) -> str | None:
    """Why the file that ``name`` (a relative path, from the folder's file at ``key``)
    names is not a file inside ``folder`` once links are followed (lerobot fetches a file
    it does not find from the Hub, and the policy's sha256 covers the folder alone), or
    None."""
    if not isinstance(name, str) or not name:
        return f"{folder}: {key} {str(name)[:60]!r} is not a file name"
    root, file = os.path.realpath(folder), os.path.realpath(folder / name)
    if os.path.commonpath([root, file]) != root:
        return f"{folder}: {key} {name[:60]!r} lies outside the policy directory"
    if not os.path.isfile(file):
        return f"{folder}: {key} {name[:60]!r}: no such file in the policy directory"
    return None


def _why_not_processor(folder: Path, name: str) -> str | None:
    """Why the saved processor ``name`` is not one this server loads: a step other than
    :data:`STEPS` (by its registered name), or a ``state_file`` outside the folder."""
    config = _json(folder / name)
    if isinstance(config, str):
        return config
    steps = config.get("steps") if isinstance(config, dict) else None
    if not isinstance(steps, list) or not all(isinstance(s, dict) for s in steps):
        return f"{folder / name}: steps: expected a list of objects"
    for i, step in enumerate(steps):
        registered = step.get("registry_name")
        if registered not in STEPS:
            shown = str(registered or step.get("class"))[:60]
            return (
                f"{folder / name}: steps.{i}: {shown!r} is not a processor step this server "
                f"loads (one of {', '.join(STEPS)})"
            )
        if "state_file" in step:
            why = why_outside(folder, step["state_file"], f"{name} steps.{i}.state_file")
            if why:
                return why
    return None


def pretrained_off(config: Any) -> None:
    """Set every ``*pretrained*`` field of a policy config (a dataclass) to None: a
    torchvision backbone's initial weights would be downloaded, and every weight is
    loaded from model.safetensors after (``pretrained_path``, where training started
    from, is a record only)."""
    import dataclasses

    for field in dataclasses.fields(config):
        if "pretrained" in field.name:
            setattr(config, field.name, None)


def observation(obs: dict[str, np.ndarray], obs_keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """One frame's features as the LeRobot export writes them."""
    from mimicgen_pipe.formats.exporters.lerobot import observation_features, state_keys

    frame = {k: np.asarray(obs[k])[None] for k in obs_keys}
    out = {k: v[0] for k, v in observation_features(frame, state_keys(obs_keys)).items()}
    images = {image_key(k.removesuffix("_image")): v for k, v in obs.items()
              if k.endswith("_image")}  # fmt: skip
    return out | images


def image_key(camera: str) -> str:
    """As the export names a camera's video feature (uint8 HWC frames here)."""
    return f"observation.images.{camera}"


class LeRobotPolicy:
    """The policy directory at ``path`` on the CPU, with its processors."""

    def __init__(self, path: str, task: str) -> None:
        why = why_not(Path(path))  # the client checked it; the folder may have changed since
        if why:
            raise ValueError(why)
        import torch
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.configs.types import FeatureType
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors

        self._torch, self.task = torch, task
        # one thread, like the evaluator's workers: its env steps in the other process
        torch.set_num_threads(1)
        config = PreTrainedConfig.from_pretrained(path)
        config.device = "cpu"
        pretrained_off(config)
        self.policy = get_policy_class(config.type).from_pretrained(
            path, config=config, strict=True
        )
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
