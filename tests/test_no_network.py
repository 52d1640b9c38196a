"""Nothing in a policy trained elsewhere reaches outside it (mimicgen_pipe.formats.external): a
pretrained initialisation its config asks for is turned off, what would fetch a model by
name is refused, every file a LeRobot folder makes lerobot read lies inside the folder
(covered by its sha256), and the policy server runs with the Hugging Face libraries
offline. Checked in this process, with no framework installed."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import pytest

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.formats import external
from mimicgen_pipe.formats.external import ExternalPolicy, _serve, parse_policy
from mimicgen_pipe.formats.external import lerobot as lerobot_format
from mimicgen_pipe.formats.external import robomimic as robomimic_format
from tests.test_external_policy import stand_in

NORMALIZER = "policy_preprocessor_step_3_normalizer_processor.safetensors"
UNNORMALIZER = "policy_postprocessor_step_0_unnormalizer_processor.safetensors"


def rgb_encoder(**backbone_kwargs: object) -> dict:
    """A robomimic image encoder config as its train.py saves it."""
    return {"core_class": "VisualCore",
            "core_kwargs": {"backbone_class": "ResNet18Conv", "pool_class": "SpatialSoftmax",
                            "backbone_kwargs": backbone_kwargs}}  # fmt: skip


def checkpoint(config: dict) -> dict:
    return {"config": json.dumps(config)}


def test_robomimic_pretrained_encoders_are_turned_off_at_any_depth():
    """torchvision would download ImageNet weights for backbone_kwargs.pretrained (and an
    old config's visual_core_kwargs.pretrained); the checkpoint holds every weight."""
    config = {
        "algo": {"actor": {"pretrained_policy": "x"}},
        "observation": {"encoder": {"rgb": rgb_encoder(pretrained=True, input_coord_conv=False)}},
        "observation_old": [{"encoder": {"visual_core_kwargs": {"pretrained": 1}}}],
    }
    out = robomimic_format.checkpoint_config(checkpoint(config))
    assert out["observation"]["encoder"]["rgb"]["core_kwargs"]["backbone_kwargs"] == {
        "pretrained": False, "input_coord_conv": False}  # fmt: skip
    assert out["observation_old"][0]["encoder"]["visual_core_kwargs"]["pretrained"] is False
    assert out["algo"]["actor"]["pretrained_policy"] is False
    unchanged = {"observation": {"encoder": {"rgb": rgb_encoder(pretrained=False)}}}
    assert robomimic_format.checkpoint_config(checkpoint(unchanged)) == unchanged


@pytest.mark.parametrize(
    ("key", "value"),
    [("core_kwargs.backbone_class", "R3MConv"), ("core_kwargs.backbone_class", "MVPConv"),
     ("visual_core", "R3MConv"), ("visual_core", "__import__('os').system('true')")],
)  # fmt: skip
def test_robomimic_encoders_that_fetch_or_eval_are_refused_naming_the_key(key, value):
    """R3M's and MVP's encoders download their networks when built; a robomimic < 0.2
    config's visual_core becomes the backbone_class robomimic evals."""
    rgb = rgb_encoder()
    if key == "visual_core":
        rgb = {"visual_core": value}
    else:
        rgb["core_kwargs"]["backbone_class"] = value
    config = checkpoint({"observation": {"encoder": {"rgb": rgb}}})
    with pytest.raises(ValueError, match=rf"config\.observation\.encoder\.rgb\.{key}: "
                       r".* is not a class this server builds"):  # fmt: skip
        robomimic_format.checkpoint_config(config)


def lerobot_folder(path: Path) -> Path:
    """A policy folder as lerobot-train saves an ACT's pretrained_model (its weights not
    real: nothing here loads them), with ACT's default pretrained backbone named."""
    path.mkdir(parents=True, exist_ok=True)
    config = {"type": "act", "vision_backbone": "resnet18",
              "pretrained_backbone_weights": "ResNet18_Weights.IMAGENET1K_V1",
              "pretrained_path": None}  # fmt: skip
    (path / "config.json").write_text(json.dumps(config))
    for name in ("model.safetensors", NORMALIZER, UNNORMALIZER):
        (path / name).write_bytes(b"weights of " + name.encode())
    pre = [
        {"registry_name": "rename_observations_processor", "config": {"rename_map": {}}},
        {"registry_name": "to_batch_processor", "config": {}},
        {"registry_name": "device_processor", "config": {"device": "cpu"}},
        {"registry_name": "normalizer_processor", "config": {}, "state_file": NORMALIZER},
    ]
    post = [{"registry_name": "unnormalizer_processor", "config": {}, "state_file": UNNORMALIZER},
            {"registry_name": "device_processor", "config": {"device": "cpu"}}]  # fmt: skip
    write_steps(path, "policy_preprocessor.json", pre)
    write_steps(path, "policy_postprocessor.json", post)
    return path


def write_steps(path: Path, name: str, steps: list[dict]) -> None:
    (path / name).write_text(json.dumps({"name": name.removesuffix(".json"), "steps": steps}))


def pre_steps(path: Path) -> list[dict]:
    return json.loads((path / "policy_preprocessor.json").read_text())["steps"]


def test_a_lerobot_folder_as_lerobot_saves_it_is_accepted_and_its_state_files_hashed(tmp_path):
    policy = lerobot_folder(tmp_path / "policy")
    assert parse_policy(f"lerobot:{policy}") == ("lerobot", policy)
    digest = external.policy_digest(policy)
    (policy / NORMALIZER).write_bytes(b"other weights")
    assert external.policy_digest(policy) != digest


@pytest.mark.parametrize(
    ("where", "why"),
    [("../outside.safetensors", "lies outside the policy directory"),
     ("{outside}", "lies outside the policy directory"),
     ("link.safetensors", "lies outside the policy directory"),
     ("missing.safetensors", "no such file in the policy directory"),
     (7, "is not a file name")],
)  # fmt: skip
def test_a_lerobot_state_file_outside_its_folder_is_refused(tmp_path, where, why):
    """lerobot reads a step's state_file from <folder>/<state_file> (any path, absolute
    ones too) and fetches one it does not find from the Hub; the policy's sha256 covers
    the folder alone."""
    outside = tmp_path / "outside.safetensors"
    outside.write_bytes(b"someone else's statistics")
    policy = lerobot_folder(tmp_path / "policy")
    (policy / "link.safetensors").symlink_to(outside)
    steps = pre_steps(policy)
    steps[3]["state_file"] = where.format(outside=outside) if isinstance(where, str) else where
    write_steps(policy, "policy_preprocessor.json", steps)
    with pytest.raises(InputError, match=rf"{policy}: policy_preprocessor.json steps.3.state_file "
                       rf".*{why}"):  # fmt: skip
        parse_policy(f"lerobot:{policy}")


def test_a_lerobot_file_linked_from_outside_its_folder_is_refused(tmp_path):
    elsewhere = lerobot_folder(tmp_path / "elsewhere")
    policy = lerobot_folder(tmp_path / "policy")
    (policy / "model.safetensors").unlink()
    (policy / "model.safetensors").symlink_to(elsewhere / "model.safetensors")
    with pytest.raises(InputError, match="model.safetensors 'model.safetensors' lies outside"):
        parse_policy(f"lerobot:{policy}")
    # a link inside the folder (lerobot-train's checkpoints/last) is the folder's own
    (tmp_path / "last").symlink_to(policy.parent)
    (policy / "model.safetensors").unlink()
    (policy / "model.safetensors").write_bytes(b"weights")
    assert parse_policy(f"lerobot:{tmp_path / 'last' / 'policy'}")[0] == "lerobot"


@pytest.mark.parametrize(
    ("change", "why"),
    [({"type": "sac", "vision_encoder_name": "helper2424/resnet10"}, "type 'sac' is not a policy"),
     ({"type": "smolvla", "vlm_model_name": "HuggingFaceTB/SmolVLM2-500M-Video-Instruct"},
      "type 'smolvla' is not a policy")],
)  # fmt: skip
def test_lerobot_policies_that_load_models_by_name_are_refused(tmp_path, change, why):
    policy = lerobot_folder(tmp_path / "policy")
    config = json.loads((policy / "config.json").read_text()) | change
    (policy / "config.json").write_text(json.dumps(config))
    with pytest.raises(InputError, match=rf"{policy}/config.json: {why} this server builds"):
        parse_policy(f"lerobot:{policy}")


@pytest.mark.parametrize(
    "step",
    [{"registry_name": "tokenizer_processor", "config": {"tokenizer_name": "google/paligemma"}},
     {"registry_name": "reward_classifier_processor", "config": {"pretrained_path": "a/b"}},
     {"class": "mypackage.Step", "config": {}}],
)  # fmt: skip
def test_lerobot_processor_steps_that_load_models_or_code_are_refused(tmp_path, step):
    policy = lerobot_folder(tmp_path / "policy")
    write_steps(policy, "policy_preprocessor.json", [*pre_steps(policy), step])
    shown = step.get("registry_name") or step["class"]
    with pytest.raises(InputError, match=rf"policy_preprocessor.json: steps.4: '{shown}' is not "
                       "a processor step this server loads"):  # fmt: skip
        parse_policy(f"lerobot:{policy}")


def test_lerobot_pretrained_fields_are_turned_off():
    """What the server does to the loaded config before building the policy: ACT's
    default pretrained backbone would download ImageNet weights from torchvision."""

    @dataclasses.dataclass
    class ACTConfig:  # the fields of lerobot's ACTConfig that matter here
        vision_backbone: str = "resnet18"
        pretrained_backbone_weights: str | None = "ResNet18_Weights.IMAGENET1K_V1"
        pretrained_path: str | None = "lerobot/act_base"

    config = ACTConfig()
    lerobot_format.pretrained_off(config)
    assert config == ACTConfig(pretrained_backbone_weights=None, pretrained_path=None)


def test_the_policy_server_runs_with_the_hugging_face_libraries_offline(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "0")
    monkeypatch.delenv("TRANSFORMERS_OFFLINE", raising=False)
    monkeypatch.delenv("HF_DATASETS_OFFLINE", raising=False)
    command = stand_in(tmp_path, report_env=list(_serve.OFFLINE))
    with ExternalPolicy(command, dict, "stand_in:test") as policy:
        env = policy.hello["meta"]["env"]
    assert env == {"HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1"}
    assert os.environ["HF_HUB_OFFLINE"] == "0"  # ours is left as it was
