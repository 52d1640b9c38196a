"""Stand-in for torchvision in the LeRobot check venv: PyPI's torchvision builds for torch
2.13.0 link CUDA libraries, and lerobot imports torchvision at module level although a dataset
without images or videos never calls it."""

from . import transforms  # noqa: F401

__version__ = "0.0.0+stub"


def set_video_backend(backend: str) -> None:
    raise NotImplementedError("torchvision stub: no video support in the LeRobot check venv")
