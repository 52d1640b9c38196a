"""The image-agent pipeline's report (images/dvc.yaml): image BC-RNN agents trained on the
main task's generated D0 demos and on its source demos, each rolled out on D0 with its
cameras rendered, beside the paper's image agents (Fig. 4), and every way the training
profile differs from the paper's."""

from __future__ import annotations

from mimicgen_pipe.core.taskspec import TaskSpec
from mimicgen_pipe.data.metrics import Metrics
from mimicgen_pipe.data.params import Params
from mimicgen_pipe.report.blocks import Block, Heading, Table, Text
from mimicgen_pipe.report.fmt import CI_NOTE, MISSING, fmt, fmt_pm, fmt_sr
from mimicgen_pipe.report.inputs import MetricsSet, evaluation, policy_robot
from mimicgen_pipe.report.paper import PaperResults

VARIANT = "D0"  # the reset variant the agents are rolled out on
DATA = ("source", VARIANT)  # what the agents train on: the source demos, the generated ones

# The paper's image agents (paper N: robomimic's BC-RNN with its image defaults, as
# configs/robomimic/bc_rnn_image.json spells them for our stores), one row per setting
# the profile sets; ours comes from train.cpu_image and the observe stage's image size.
PAPER_PROFILE = (
    ("encoder per camera", "ResNet18 trunk, spatial softmax (32 keypoints), 64 features"),
    ("LSTM", "2 × 1000"),
    ("image size [px]", "84 × 84"),
    ("pixel shift", "up to 10 % of each dimension"),
    ("batch × window", "16 × 10"),
    ("learning rate", "0.0001"),
    ("gradient steps", "300,000 (600 epochs × 500)"),
    ("generated demos", "1000"),
    ("training seeds", "3"),
    ("rollouts per checkpoint", "50, every 20 epochs"),
)


def _train(ms: MetricsSet, params: Params, data: str) -> Metrics | None:
    robot = policy_robot(params, data)
    return ms.one(stage="train", task=params.task, backend=params.backend, data=data, robot=robot)


def agent_rows(
    params: Params, spec: TaskSpec, ms: MetricsSet, paper: PaperResults
) -> list[tuple[str, ...]]:
    """One row per training data (source, D0): demos trained on, training seeds, success
    % on D0 of the best checkpoint and of the last (mean ± std over seeds), the paper's."""
    rows = []
    for data in DATA:
        tr = _train(ms, params, data)
        ev = evaluation(ms, params, params.task, params.backend, data, VARIANT)
        theirs = paper.find(
            task=spec.paper_task, variant=VARIANT, metric="sr_image", data=data, table="Fig. 4"
        )
        demos = (
            MISSING if tr is None else fmt(tr.values["train_episodes"] + tr.values["val_episodes"])
        )
        rows.append(
            (
                "source demos" if data == "source" else f"generated {VARIANT} demos",
                demos,
                MISSING if tr is None else fmt(tr.values["seeds"]),
                fmt_sr(ev.values if ev else None, "max"),
                fmt_sr(ev.values if ev else None, "last"),
                ", ".join(fmt_pm(e.value, e.std) for e in theirs) or MISSING,
            )
        )
    return rows


def profile_rows(params: Params) -> list[tuple[str, str, str]]:
    """(setting, the paper's, ours) for every setting of the image profile."""
    p = params.train.cpu_image
    h, w = p.image_size
    ours = (
        f"3 convolutions of {p.channels} channels, spatial softmax ({p.keypoints} "
        f"keypoints), {p.image_features} features",
        f"{p.layers} × {p.hidden}",
        f"{h} × {w}",
        f"up to {p.shift * 100:.0f} % of each dimension",
        f"{p.batch_size} × {p.seq_len}",
        f"{p.lr:g}",
        f"{p.epochs * p.steps_per_epoch:,} ({p.epochs} epochs × {p.steps_per_epoch})",
        fmt(params.train.num_demos),
        fmt(len(p.seeds)),
        f"{params.evaluate.episodes}, every {params.evaluate.every_epochs} epochs and the last",
    )
    return [(name, theirs, o) for (name, theirs), o in zip(PAPER_PROFILE, ours, strict=True)]


def images_blocks(
    params: Params, spec: TaskSpec, ms: MetricsSet, paper: PaperResults
) -> list[Block]:
    task = params.task
    return [
        Heading(1, f"Image agents on {task}"),
        Text(
            f"BC-RNN agents that see the front and wrist cameras and the robot's own pose "
            f"and gripper (train profile `cpu_image`), trained on {task}'s source demos and "
            f"on its generated {VARIANT} demos, each rolled out "
            f"{params.evaluate.episodes} times per checkpoint on {VARIANT} with its cameras "
            "rendered: success % of each seed's best checkpoint and of its last, mean ± std "
            f"over training seeds. Paper: {spec.paper_task}'s image agents, Fig. 4. "
            f"`{MISSING}` marks a run the pipeline did not produce. {CI_NOTE}"
        ),
        Table(
            ("trained on", "demos", "seeds", "success % max", "success % last", "paper (Fig. 4)"),
            tuple(agent_rows(params, spec, ms, paper)),
        ),
        Heading(2, "How the profile differs from the paper's"),
        Text(
            "The paper trains robomimic's image BC-RNN on a GPU; the `cpu_image` profile is "
            "sized for two CPU cores (params.yaml's train.cpu_image). Every setting of the two:"
        ),
        Table(("setting", "paper", "ours"), tuple(profile_rows(params))),
    ]
