"""The image-agent pipeline (images/dvc.yaml): its report beside the paper's Fig. 4, the
settings it names against the paper's, its headline numbers, and the check that the agents'
image size is the one observed."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data.params import Params, load_params
from mimicgen_pipe.report import build_images_report
from mimicgen_pipe.report.blocks import render_markdown
from mimicgen_pipe.report.inputs import MetricsSet
from mimicgen_pipe.report.paper import load_paper_results
from mimicgen_pipe.report.summary import images_headline_numbers
from mimicgen_pipe.stages.check import check_image_size
from tests.conftest import cli
from tests.test_report import PAPER, STACK_CUBE, m, rows_of

REPO = Path(__file__).resolve().parents[1]


def image_params() -> Params:
    return load_params(REPO / "images/params.yaml")


def agents(source_max: float, d0_max: float) -> tuple:
    """Train and evaluate metrics of both agents: 3 seeds, 50 episodes each."""
    files = []
    for data, best in (("source", source_max), ("D0", d0_max)):
        episodes = (10, 0) if data == "source" else (900, 100)
        files += [
            m("train", "stack_cube", data=data, seeds=3, train_episodes=episodes[0],
              val_episodes=episodes[1]),
            m("evaluate", "stack_cube", "D0", data=data, seeds=3, episodes=50,
              success_rate_max=best, success_rate_max_std=2.0, success_rate_last=best - 4,
              success_rate_last_std=1.0),
        ]  # fmt: skip
    return tuple(files)


def test_the_report_sets_each_agent_beside_fig_4():
    params = image_params()
    paper = load_paper_results(PAPER)
    md = render_markdown(build_images_report(params, STACK_CUBE, MetricsSet(agents(6.0, 84.0)),
                                             paper))  # fmt: skip
    assert rows_of(md, "| source demos", "| generated D0 demos") == [
        "| source demos | 10 | 3 | 6.0 ± 2.0 [3.2–11.0] | 2.0 ± 1.0 [0.7–5.7] | 26.0 |",
        "| generated D0 demos | 1000 | 3 | 84.0 ± 2.0 [77.3–89.0] | 80.0 ± 1.0 [72.9–85.6] "
        "| 100.0 |",
    ]
    # nothing made up: without metrics, each of our cells says so, and the paper's stays
    empty = render_markdown(build_images_report(params, STACK_CUBE, MetricsSet(()), paper))
    assert rows_of(empty, "| source demos") == [
        "| source demos | missing | missing | missing | missing | 26.0 |"
    ]


def test_the_profile_table_reads_every_setting_from_the_params():
    params = image_params()
    p = params.train.cpu_image
    changed = replace(
        params,
        train=replace(params.train, cpu_image=replace(p, channels=24, epochs=7, seeds=[4])),
    )
    md = render_markdown(build_images_report(changed, STACK_CUBE, MetricsSet(()),
                                             load_paper_results(PAPER)))  # fmt: skip
    rows = dict(
        (r.split(" | ")[0][2:], r.split(" | ")[2].rstrip(" |"))
        for r in rows_of(md, "| ")
        if r.count(" | ") == 2
    )
    assert rows["encoder per camera"].startswith("3 convolutions of 24 channels")
    assert rows["gradient steps"] == f"{7 * p.steps_per_epoch:,} (7 epochs × {p.steps_per_epoch})"
    assert rows["training seeds"] == "1"
    h, w = p.image_size
    assert rows["image size [px]"] == f"{h} × {w}"


def test_the_headline_numbers_are_the_tables():
    numbers = images_headline_numbers(image_params(), MetricsSet(agents(6.0, 84.0)))
    assert numbers["sr_source_on_D0"] == 6.0 and numbers["sr_D0_on_D0"] == 84.0
    assert numbers["sr_D0_on_D0_lo"] == 77.3 and numbers["sr_D0_on_D0_hi"] == 89.0
    assert images_headline_numbers(image_params(), MetricsSet(())) == {}


def test_the_agents_image_size_must_be_the_observed_one(tmp_path):
    params = image_params()
    check_image_size(params, "images/params.yaml")  # the committed file agrees
    wrong = replace(params, observe=replace(params.observe, height=params.observe.height + 1))
    with pytest.raises(InputError, match=r"images/params.yaml: observe.height, observe.width"):
        check_image_size(wrong, "images/params.yaml")
    # a low-dim profile reads no images: any observe size
    check_image_size(replace(wrong, train=replace(wrong.train, profile="cpu")), "p.yaml")


def test_the_check_stage_refuses_it_before_any_stage_runs(tmp_path):
    raw = yaml.safe_load((REPO / "images/params.yaml").read_text())
    raw["observe"]["width"] = raw["observe"]["width"] + 1
    bad = tmp_path / "params.yaml"
    bad.write_text(yaml.safe_dump(raw))
    stamp = tmp_path / "params.checked"
    result = cli("check", "--params", str(bad), "--stamp", str(stamp), cwd=tmp_path, check=False)
    assert result.returncode != 0 and "observe.height, observe.width" in result.stderr
    assert not stamp.exists()
