"""A robomimic checkpoint (``.pth``, as robomimic's ``train.py`` saves it), trained on our
robomimic export: its inputs are the export's ``obs/<key>`` names, MimicGen's
(``robot0_eef_pos``, ``object``, ``agentview_image``, ``robot0_eye_in_hand_image``, ...: the
exporter's own ``robomimic_obs``); a checkpoint trained on an export written before those
names, on our own keys (``eef_pos``, ``eye_in_hand_image``), is given them too. Quaternions
are given xyzw, as the export writes them (exports before that wrote wxyz).

The server loads it with ``torch.load(weights_only=True)``, which rebuilds tensors,
numbers, strings, lists and dicts alone (robomimic's checkpoints hold nothing else), and
robomimic's own ``policy_from_checkpoint``: the policy acts as in robomimic's rollouts
(its RNN context, its action sampling), its random state seeded at each reset. Nothing of
the checkpoint reaches the network: a pretrained initialisation its config asks for (an
encoder's ``pretrained``) is turned off, since robomimic then loads every weight from the
checkpoint itself (a strict ``load_state_dict``), and encoders that are pretrained networks
fetched by another library (R3M, MVP) are not among the classes it may name.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

DESCRIPTION = "robomimic checkpoint .pth file, or a folder of a run's model_epoch_<N>.pth"
# robomimic builds its encoders from class names in the checkpoint's config, some by eval()
# (VisualCore's backbone_class and pool_class): a name is accepted only where it is one of
# robomimic's own classes, so that no string of a checkpoint reaches eval. R3MConv and
# MVPConv are left out: they download their pretrained networks (r3m, mvp) when built.
BACKBONES = ("ResNet18Conv", "ShallowConv")
CLASSES = {
    "core_class": ("VisualCore", "ScanCore"),
    "backbone_class": BACKBONES,
    # a config of robomimic < 0.2 names its backbone so; robomimic's update_config makes
    # it the backbone_class that VisualCore evals
    "visual_core": BACKBONES,
    "pool_class": ("SpatialSoftmax", "SpatialMeanPool"),
    "obs_randomizer_class": ("CropRandomizer", "ColorRandomizer", "GaussianNoiseRandomizer"),
}


def run_checkpoints(path: Path) -> list[Path]:
    """The checkpoints ``path`` names, in training order: a folder's ``model_epoch_<N>.pth``
    (robomimic's ``models/`` folder, train_robomimic's output) by epoch; a file, itself."""
    if not path.is_dir():
        return [path]
    found = [(checkpoint_epoch(p), p) for p in path.glob("model_epoch_*.pth")]
    return [p for epoch, p in sorted((e, p) for e, p in found if e is not None)]


def why_not(path: Path) -> str | None:
    """A file torch.save wrote (a zip archive with a data.pkl), or a folder of checkpoints
    named by epoch, each such a file; else why not."""
    if path.is_dir():
        found = run_checkpoints(path)
        if not found:
            return f"{path}: a folder without model_epoch_<N>.pth checkpoints"
        return next((why for p in found if (why := why_not(p))), None)
    if not path.is_file():
        return f"{path}: no such file"
    if not zipfile.is_zipfile(path):
        return f"{path}: not a checkpoint torch saved (not a zip archive)"
    with zipfile.ZipFile(path) as z:
        if not any(n.endswith("/data.pkl") for n in z.namelist()):
            return f"{path}: a zip archive without data.pkl, not a checkpoint torch saved"
    return None


def check_classes(config: object, where: str = "config") -> None:
    """ValueError naming the key, for a ``*_class`` entry anywhere in a robomimic config
    (the checkpoint's parsed ``config``) that is not null or one of :data:`CLASSES`' names
    for that key."""
    if isinstance(config, dict):
        items = list(config.items())
    else:
        items = list(enumerate(config)) if isinstance(config, list) else []
    for key, value in items:
        at = f"{where}.{key}"
        if (
            isinstance(key, str)
            and (key.endswith("_class") or key in CLASSES)
            and value is not None
        ):
            allowed = CLASSES.get(key)
            if allowed is None or value not in allowed:
                shown = repr(value) if len(repr(value)) <= 60 else repr(value)[:57] + "..."
                expected = f"one of {', '.join(allowed)} or null" if allowed else "null"
                raise ValueError(f"{at}: {shown} is not a class this server builds ({expected})")
        check_classes(value, at)


def pretrained_off(config: object) -> object:
    """``config`` with every true ``*pretrained*`` entry, at any depth (an encoder's
    ``backbone_kwargs.pretrained``, robomimic < 0.2's ``visual_core_kwargs.pretrained``),
    made false: torchvision would download the weights, which robomimic then replaces by
    the checkpoint's own."""
    if isinstance(config, list):
        return [pretrained_off(v) for v in config]
    if not isinstance(config, dict):
        return config
    return {
        k: False if isinstance(k, str) and "pretrained" in k.lower() and v else pretrained_off(v)
        for k, v in config.items()
    }


def checkpoint_config(ckpt: dict) -> dict:
    """The checkpoint's robomimic config (a JSON object in ``config``), its class names
    checked (:func:`check_classes`) and its pretrained initialisations off
    (:func:`pretrained_off`); ValueError naming the key otherwise."""
    try:
        config = json.loads(ckpt["config"])
    except RecursionError:  # json recurses once per level of nesting
        raise ValueError("config: JSON nested too deep for a robomimic config") from None
    except (KeyError, TypeError, json.JSONDecodeError) as exc:
        raise ValueError(f"config: not a robomimic config JSON string ({exc})") from None
    if not isinstance(config, dict):
        raise ValueError("config: not a JSON object")
    try:
        check_classes(config)
    except RecursionError:
        raise ValueError("config: JSON nested too deep for a robomimic config") from None
    return pretrained_off(config)


def observation(obs: dict[str, np.ndarray], obs_keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """One step's ``obs/<key>`` arrays as the export writes them (a camera's images too,
    uint8 HWC), and our own keys as earlier exports named them."""
    from mimicgen_pipe.formats.exporters.robomimic import arms_of, robomimic_obs

    step = {k: np.asarray(v)[None] for k, v in obs.items()}
    named = robomimic_obs(step, obs_keys, arms_of(list(obs)))
    return dict(obs) | {k: v[0] for k, v in named.items()}


def image_key(camera: str) -> str:
    """The export's name of a camera's images (robot0_eye_in_hand_image, agentview_image)."""
    from mimicgen_pipe.formats.exporters.robomimic import camera_name

    return f"{camera_name(camera)}_image"


def image_keys(camera: str) -> tuple[str, ...]:
    """Every name a checkpoint may read a camera's images by: the export's, then the one
    exports written before MimicGen's names gave them."""
    return tuple(dict.fromkeys((image_key(camera), f"{camera}_image")))


class RobomimicPolicy:
    """The checkpoint at ``path`` as robomimic's RolloutPolicy, on the CPU."""

    def __init__(self, path: str) -> None:
        import robomimic.utils.file_utils as file_utils
        import robomimic.utils.obs_utils as obs_utils
        import torch

        self._torch, self._obs_utils = torch, obs_utils
        # one thread, like the evaluator's workers: its env steps in the other process
        torch.set_num_threads(1)
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        config = checkpoint_config(ckpt)  # before robomimic builds anything from it
        if config != json.loads(ckpt["config"]):
            ckpt["config"] = json.dumps(config)
        self.policy, _ = file_utils.policy_from_checkpoint(
            device=torch.device("cpu"), ckpt_dict=ckpt
        )
        shapes = ckpt["shape_metadata"]["all_shapes"]
        self.observations: dict[str, dict[str, Any]] = {}
        for key in ckpt["shape_metadata"]["all_obs_keys"]:
            if obs_utils.key_is_obs_modality(key, "rgb"):
                c, h, w = shapes[key]  # robomimic's processed image: CHW float in [0, 1]
                self.observations[key] = {"shape": [h, w, c], "dtype": "uint8"}
            elif obs_utils.key_is_obs_modality(key, "low_dim"):
                self.observations[key] = {"shape": list(shapes[key]), "dtype": "float32"}
            else:
                raise ValueError(f"observation {key!r}: a modality other than low_dim and rgb")
        self.action_dim = int(ckpt["shape_metadata"]["ac_dim"])
        self.meta = {"env_kwargs": (ckpt.get("env_metadata") or {}).get("env_kwargs")}

    def reset(self, seed: int) -> None:
        self._torch.manual_seed(seed)
        np.random.seed(seed % 2**32)
        self.policy.start_episode()

    def act(self, arrays: dict[str, np.ndarray]) -> np.ndarray:
        ob = self._obs_utils.process_obs_dict({k: arrays[k] for k in self.observations})
        return np.asarray(self.policy(ob))


def load(path: str, task: str) -> RobomimicPolicy:
    return RobomimicPolicy(path)


EPOCH_UNIT = "epoch"


def checkpoint_epoch(path: Path) -> int | None:
    """The epoch robomimic's train.py names a checkpoint by: ``model_epoch_<N>.pth`` (also
    ``model_epoch_<N>_best_validation_<loss>.pth`` and ``..._<env>_success_<rate>.pth``);
    None for a file named otherwise (a checkpoint holds no epoch of its own)."""
    stem = path.name.removesuffix(".pth")
    if stem == path.name or not stem.startswith("model_epoch_"):
        return None
    digits = stem.removeprefix("model_epoch_").split("_")[0]
    return int(digits) if digits.isdigit() else None
