"""compare: the runs of one pipeline side by side (commits and `dvc exp run` experiments, from
`dvc exp show --json`): the params that differ between them and the pipeline's headline
numbers (its report's summary.json), each with its change from the first run. Prints only."""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

from mimicgen_pipe.core.errors import InputError, StageError
from mimicgen_pipe.core.jsonfile import MAX_BYTES, parse_json, read_json
from mimicgen_pipe.report.compare import PIPELINES, CompareJob, comparison, runs_of, select


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "runs",
        nargs="*",
        help="experiment names, commit names or short revs, in the order to show (default: "
        "every run dvc exp show lists: the workspace, HEAD and its experiments)",
    )
    p.add_argument(
        "--pipeline",
        choices=sorted(PIPELINES),
        default="default",
        help="whose params and headline numbers (default: the default pipeline's)",
    )
    p.add_argument(
        "--json",
        help="read dvc exp show --json output from this file ('-': stdin) instead of running it",
    )
    p.add_argument("--all-params", action="store_true", help="every params key, not only changed")
    p.add_argument(
        "--width",
        type=int,
        default=shutil.get_terminal_size((120, 24)).columns,
        help="line width to fit (default: the terminal's)",
    )


def exp_show() -> object:
    """``dvc exp show --json`` of the repository here, parsed."""
    dvc = shutil.which("dvc") or str(Path(sys.executable).with_name("dvc"))
    try:
        res = subprocess.run(
            [dvc, "exp", "show", "--json"], capture_output=True, text=True, check=False
        )
    except OSError as exc:
        raise StageError(f"cannot run dvc ({exc.strerror}); is it installed?") from exc
    if res.returncode != 0:
        last = (res.stderr.strip().splitlines() or ["no output"])[-1]
        raise StageError(f"dvc exp show failed: {last}")
    return parse_json(res.stdout, "dvc exp show --json")


def read_shown(given: str) -> object:
    """The dvc exp show --json output in the file ``given`` ('-': stdin), parsed, bounded
    as every JSON file a stage reads (:mod:`mimicgen_pipe.core.jsonfile`)."""
    try:
        if given != "-":
            return read_json(given, "dvc exp show --json output")
        text = sys.stdin.read(MAX_BYTES + 1)
        if len(text) > MAX_BYTES:
            raise InputError(f"{given}: more than {MAX_BYTES} bytes")
        return parse_json(text, given)
    except InputError as exc:
        why = str(exc).removeprefix(f"{given}: ")
        raise InputError(f"{given}: not dvc exp show --json output ({why})") from None


def resolve(args: argparse.Namespace) -> CompareJob:
    """The runs ``args`` name, read from dvc exp show (run here, or its given output)."""
    shown = exp_show() if args.json is None else read_shown(args.json)
    pipeline = PIPELINES[args.pipeline]
    runs = select(runs_of(shown, pipeline), args.runs)
    if not runs:
        raise InputError(f"no run in dvc exp show has {pipeline.params}")
    return CompareJob(tuple(runs), args.all_params, args.width)


def run(job: CompareJob) -> None:
    sys.stdout.write(comparison(job))
