"""Stage scripts: argument parsing and I/O around the library (mimicgen_pipe)."""

from __future__ import annotations

import argparse

from mimicgen_pipe.params import Params, load_params, with_overrides


def add_selection_arguments(p: argparse.ArgumentParser, robot: bool = False) -> None:
    """--params, and --backend/--task (and --robot) overriding params.yaml's choices."""
    p.add_argument("--params", default="params.yaml", help="params file (default: params.yaml)")
    p.add_argument("--backend", help="simulator back end (default: params.yaml's backend)")
    p.add_argument("--task", help="task name (default: params.yaml's task)")
    if robot:
        p.add_argument("--robot", help="arm to generate with (default: generate.robot)")


def stage_params(args: argparse.Namespace) -> Params:
    """params.yaml, validated, with the command line's --backend/--task/--robot applied."""
    return with_overrides(
        load_params(args.params),
        getattr(args, "backend", None),
        getattr(args, "task", None),
        getattr(args, "robot", None),
    )
