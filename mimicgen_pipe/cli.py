"""``mimicgen-pipe <stage>``: every pipeline stage from the command line."""

from __future__ import annotations

import argparse
import importlib
import sys

from mimicgen_pipe.errors import InputError

STAGES = {
    "source": "record source demos on D0 (motion planners or a trajectory file)",
    "parse": "split source demos into object-centric subtask segments",
    "pose_noise": "add pose-estimation error to the source demos' object poses",
    "generate": "generate demos for one reset variant (MimicGen)",
    "coverage": "support coverage of a generated dataset's initial scenes, with heat maps",
    "train": "train BC-RNN policies on the source demos or a generated dataset",
    "evaluate": "roll out every checkpoint of a training run in one reset variant",
    "report": "report.md and report.html: our metrics beside the paper's, with ablations",
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="mimicgen-pipe",
        description="MimicGen data generation as DVC stages; `dvc repro` runs them all.",
    )
    sub = parser.add_subparsers(dest="stage", required=True, metavar="STAGE")
    modules = {}
    for name, help_text in STAGES.items():
        module = importlib.import_module(f"stages.{name}")
        modules[name] = module
        module.add_arguments(sub.add_parser(name, help=help_text, description=module.__doc__))
    args = parser.parse_args(argv)
    try:
        modules[args.stage].run(args)
    except InputError as exc:
        print(f"mimicgen-pipe {args.stage}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
