"""Stand-in for torchvision.transforms (see the package docstring)."""


class ToTensor:
    def __call__(self, pic):
        raise NotImplementedError("torchvision stub: no image support in the LeRobot check venv")
