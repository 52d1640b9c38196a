"""``mimicgen-pipe <stage>``: every pipeline stage from the command line.

Failures a user can act on end with one line on stderr, never a traceback: bad input (exit
2, also a second run on outputs that one is writing), a failure outside the input that the
stage can name (exit 1: a Ray cluster that went away), and Ctrl-C or SIGTERM (exit 130/143,
after the stage's worker processes are gone and its temporaries removed)."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import signal
import sys
from pathlib import Path
from typing import Any

from mimicgen_pipe.run import arithmetic

# before anything imports numpy or torch (outputs does): the same bytes on any x86-64 CPU type
UNPINNED = arithmetic.pin()

from mimicgen_pipe.core.errors import InputError, StageError, one_line  # noqa: E402
from mimicgen_pipe.core.interrupts import Interrupted, as_exceptions  # noqa: E402
from mimicgen_pipe.data import outputs  # noqa: E402

STAGES = {
    "check": "validate a pipeline's params file and the files it names (its first stage)",
    "source": "record source demos on D0 (motion planners or a trajectory file)",
    "parse": "split source demos into object-centric subtask segments",
    "boundaries": "print candidate subtask ends (gripper events) for manual annotation",
    "pose_noise": "add pose-estimation error to the source demos' object poses",
    "generate": "generate demos for one reset variant (MimicGen)",
    "coverage": "support coverage of a generated dataset's initial scenes, with heat maps",
    "ablation": "one of the paper's generation ablations: pose_noise, generate, coverage",
    "train": "train BC-RNN policies on the source demos or a generated dataset",
    "evaluate": "roll out a training run's checkpoints in one reset variant",
    "evaluate_external": "roll out a policy trained elsewhere (robomimic, LeRobot) likewise",
    "train_robomimic": "robomimic's own BC-RNN on our robomimic export, at our profile's size",
    "export": "a generated store as robomimic HDF5, LeRobot and ManiSkill trajectories",
    "render": "MP4s and GIFs of the first kept and failed generated episodes, captioned",
    "observe": "camera images of a store's episodes, rendered from their stored states",
    "report": "report.md and report.html: our metrics beside the paper's, with ablations",
    "compare": "a pipeline's runs and experiments side by side: changed params, headline numbers",
}
# the stages that read a params file (--params, default ./params.yaml)
TAKES_PARAMS = frozenset(STAGES) - {"compare"}


def main(argv: list[str] | None = None) -> int:
    if UNPINNED is not None:
        print(f"mimicgen-pipe: warning: {UNPINNED}", file=sys.stderr)
    argv = sys.argv[1:] if argv is None else list(argv)
    stage = next((a for a in argv if a in STAGES), None)
    prog = f"mimicgen-pipe {stage}" if stage else "mimicgen-pipe"
    # the handlers go in before the stages' (slow) imports, so that an early Ctrl-C too
    # ends with one line
    with as_exceptions():
        try:
            return _run_stage(argv)
        except KeyboardInterrupt:  # a library that put Python's own SIGINT handler back
            return _interrupted(prog, Interrupted(signal.SIGINT))
        except Interrupted as exc:
            return _interrupted(prog, exc)


def _interrupted(prog: str, exc: Interrupted) -> int:
    """One line on stderr; the exit status a shell gives a command killed by the signal."""
    _close_progress_bars()
    what = "outputs complete" if outputs.wrote_outputs() else "nothing written"
    print(f"{prog}: {exc.describe()}; {what}", file=sys.stderr)
    return exc.exit_code


def _close_progress_bars() -> None:
    """Finish the progress bars an interrupt left open (their line ends), so that the
    message starts a line of its own."""
    from tqdm import tqdm

    for bar in list(getattr(tqdm, "_instances", ())):
        with contextlib.suppress(Exception):
            bar.close()


def build_parser(only: str | None = None) -> tuple[argparse.ArgumentParser, dict[str, Any]]:
    """The command line's parser, and each stage's module (its ``resolve`` and ``run``):
    every stage's, or with ``only`` just that one's, so that one command imports one stage's
    libraries."""
    parser = argparse.ArgumentParser(
        prog="mimicgen-pipe",
        description="MimicGen data generation as DVC stages: `dvc repro` runs the default "
        "pipeline, `dvc repro quickstart/dvc.yaml` a small one, `dvc repro suite/dvc.yaml` the "
        "task suite.",
    )
    sub = parser.add_subparsers(dest="stage", required=True, metavar="STAGE")
    modules = {}
    for name, help_text in STAGES.items():
        if only is not None and name != only:
            sub.add_parser(name, help=help_text)  # listed in --help, never parsed
            continue
        module = importlib.import_module(f"mimicgen_pipe.stages.{name}")
        modules[name] = module
        stage_parser = sub.add_parser(name, help=help_text, description=module.__doc__)
        module.add_arguments(stage_parser)
        stage_parser.add_argument(
            "--replace-tracked",
            action="store_true",
            help="outside `dvc repro`, write outputs even where a pipeline's dvc.lock tracks "
            "them (refused by default, so that a run by hand never mixes into its results)",
        )
    return parser, modules


def params_file_given(argv: list[str]) -> str | None:
    """The ``--params`` value of a command line (``--params F`` or ``--params=F``), else
    None."""
    for i, arg in enumerate(argv):
        if arg == "--params" and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith("--params="):
            return arg.partition("=")[2]
    return None


def check_params_first(argv: list[str]) -> None:
    """Validate the params file a stage will read (``--params``, else ./params.yaml where it
    exists) before the stage's own, slower imports: a typo costs well under a second. The
    stage validates it again, with its command line's overrides."""
    given = params_file_given(argv)
    path = Path(given if given is not None else "params.yaml")
    if given is not None or path.is_file():
        from mimicgen_pipe.data.params import load_params

        load_params(path)


def _run_stage(argv: list[str]) -> int:
    stage = next((a for a in argv if a in STAGES), None)
    try:
        if stage in TAKES_PARAMS and not {"-h", "--help"} & set(argv):
            check_params_first(argv)
    except InputError as exc:
        print(one_line(f"mimicgen-pipe {stage}: error: {exc}"), file=sys.stderr)
        return 2
    parser, modules = build_parser(only=stage)
    args = parser.parse_args(argv)
    from mimicgen_pipe.stages import check_path_names

    try:
        check_path_names(args)
        with outputs.claims(replace_tracked=args.replace_tracked):
            # every refusal first (resolve claims nothing), then the work
            module = modules[args.stage]
            module.run(module.resolve(args))
    except InputError as exc:
        print(one_line(f"mimicgen-pipe {args.stage}: error: {exc}"), file=sys.stderr)
        return 2
    except StageError as exc:
        print(one_line(f"mimicgen-pipe {args.stage}: failed: {exc}"), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
