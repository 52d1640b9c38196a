"""The reports: metrics selected by the identity they record, beside the paper's numbers."""

from __future__ import annotations

import argparse
import inspect
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from mimicgen_pipe import backends
from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data.metrics import Metrics, metrics_identity, read_metrics, write_metrics
from mimicgen_pipe.data.outputs import claims
from mimicgen_pipe.data.params import Params
from mimicgen_pipe.report import (
    build_report,
    build_suite_report,
    build_transfer_report,
    build_transit_report,
    suite,
)
from mimicgen_pipe.report.ablations import suite_ablation_blocks
from mimicgen_pipe.report.blocks import Heading, Image, Table, Text, render_html, render_markdown
from mimicgen_pipe.report.curves import draw_curves, read_curves
from mimicgen_pipe.report.fmt import fmt_ci, fmt_sr, sr_counts, wilson_interval
from mimicgen_pipe.report.inputs import MetricsSet, Run, read_metrics_folder
from mimicgen_pipe.report.paper import PaperResults, load_paper_results
from mimicgen_pipe.report.scaling import draw_dataset_size, scaling_blocks
from mimicgen_pipe.report.suite import suite_dgr_blocks, suite_policy_blocks
from mimicgen_pipe.report.summary import headline_numbers
from mimicgen_pipe.report.transfer import transfer_table
from tests.conftest import cli

REPO = Path(__file__).resolve().parents[1]
PAPER = REPO / "reference/paper_results.yaml"
STACK_CUBE = backends.task_spec("maniskill", "stack_cube")


def m(stage: str, task: str, variant: str | None = None, **fields: Any) -> Metrics:
    """Metrics as a stage writes them: identity fields (maniskill, panda unless given) and
    values (every other keyword)."""
    ident = {"backend": "maniskill", "robot": "panda", "data": None, "purpose": None}
    ident |= {k: fields.pop(k) for k in list(fields) if k in ident}
    if stage == "generate" and ident["purpose"] is None:
        ident["purpose"] = "policy_data"
    name = "_".join(str(x) for x in (stage, task, ident["data"], variant) if x)
    return Metrics(Path(f"metrics/{name}.json"), stage, task, variant=variant, **ident,
                   values=fields)  # fmt: skip


def gen(task: str, variant: str, dgr: float, attempts: int = 200, **fields: Any) -> Metrics:
    successes = round(dgr * attempts / 100)
    return m("generate", task, variant, attempts=attempts, successes=successes, dgr=dgr, **fields)


def with_settings(**generate: Any) -> Params:
    p = Params()
    level = generate.pop("level", None)
    if level:
        p = replace(p, pose_noise=replace(p.pose_noise, level=level))
    return replace(p, generate=replace(p.generate, **generate))


def report_md(params: Params, *files: Metrics, ablations=(), heatmaps=None) -> str:
    paper = load_paper_results(PAPER)
    blocks = build_report(
        params, STACK_CUBE, MetricsSet(files), list(ablations), paper, heatmaps or {}, {}, ()
    )
    return render_markdown(blocks)


def rows_of(md: str, *starts: str) -> list[str]:
    return [ln for ln in md.splitlines() if ln.startswith(starts)]


# --- the paper's numbers ------------------------------------------------------------------


def test_paper_entries_are_unambiguous_for_matching():
    paper = load_paper_results(PAPER)
    assert STACK_CUBE.paper_task == "Stack"
    groups = {}
    for e in paper.entries:
        assert e.table and e.value >= 0
        if e.settings:
            groups.setdefault((e.table, e.task, e.variant, e.metric, e.data), []).append(e)
    for entries in groups.values():
        assert len({tuple(sorted(e.settings)) for e in entries}) == 1  # same keys varied
        assert len({tuple(sorted(e.settings.items())) for e in entries}) == len(entries)


def test_a_malformed_paper_file_is_one_clear_error(tmp_path):
    bad = tmp_path / "paper.yaml"
    bad.write_text("entries:\n  - {table: O.1, task: Stack, variant: D0, value: 1}\n")
    with pytest.raises(InputError, match=r"paper.yaml: entries\[0\]: 'metric' missing"):
        load_paper_results(bad)


def test_the_papers_transfer_and_coverage_numbers_come_from_its_file(tmp_path):
    """Table E.1 and the coverage numbers of Appendix Q are read from the paper's file: a
    changed number there is the number in the report."""
    text = PAPER.read_text().replace("value: 37.7, condition: IIWA", "value: 12.3, condition: IIWA")
    text = text.replace("value: 98.8", "value: 97.1")
    changed = tmp_path / "paper.yaml"
    changed.write_text(text)
    blocks = build_report(
        Params(), STACK_CUBE, MetricsSet(()), [], load_paper_results(changed), {}, {}, ()
    )
    md = render_markdown(blocks)
    assert "(e.g. Coffee D1 97.1%, Threading D1 71%, Appendix Q)" in md
    transfer = render_markdown(
        build_transfer_report(Params(), [], MetricsSet(()), load_paper_results(changed))
    )
    assert "Paper Table E.1, Square: D0: Panda 73.7, IIWA 12.3, UR5e 64.7; D1: Panda 48.9" in (
        transfer
    )


# --- blocks -------------------------------------------------------------------------------


def test_html_holds_the_same_tables_and_embeds_images():
    blocks = [Table(("a", "b"), (("1 < 2", "`x`"),)), Image("h.png", "heat map")]
    page = render_html(blocks, {"h.png": b"\x89PNG fake"}, "t")
    assert "<td>1 &lt; 2</td><td><code>x</code></td>" in page
    assert 'src="data:image/png;base64,iVBORyBmYWtl"' in page
    assert "![heat map](h.png)" in render_markdown(blocks)


def test_build_report_and_the_stage_stay_short():
    from mimicgen_pipe.stages import report

    for f in (build_report, build_suite_report, report.resolve, report.run):
        assert len(inspect.getsource(f).splitlines()) <= 60, f.__qualname__


# --- metrics identity ---------------------------------------------------------------------


def test_metrics_say_what_they_are_and_a_file_without_it_is_one_error(tmp_path):
    folder = tmp_path / "metrics"
    ident = metrics_identity("generate", "stack_cube", "maniskill", "panda", variant="D0",
                             purpose="dgr")  # fmt: skip
    write_metrics(folder / "anything.json", ident | {"dgr": 50.0, "attempts": 10})
    back = read_metrics(folder / "anything.json")
    assert (back.stage, back.task, back.variant, back.robot, back.purpose, back.data) == (
        "generate", "stack_cube", "D0", "panda", "dgr", None
    )  # fmt: skip
    assert back.values == {"dgr": 50.0, "attempts": 10}
    (folder / "old.json").write_text(json.dumps({"dgr": 50.0, "task": "stack_cube"}))
    with pytest.raises(InputError) as err:
        read_metrics_folder(folder)
    assert str(err.value).startswith(f"{folder / 'old.json'}: identity fields missing: ")
    assert "stage, backend, variant, robot, data, purpose (" in str(err.value)
    with pytest.raises(ValueError, match="purpose"):
        metrics_identity("train", "stack_cube", "maniskill", "panda", data="D0", purpose="dgr")
    with pytest.raises(ValueError, match="data"):
        metrics_identity("evaluate", "stack_cube", "maniskill", "panda", variant="D0")


def test_two_files_with_one_identity_are_one_error_naming_both():
    ms = MetricsSet((gen("stack_cube", "D0", 90.0), replace(gen("stack_cube", "D0", 91.0),
                     path=Path("metrics/copy.json"))))  # fmt: skip
    with pytest.raises(InputError, match=r"generate_stack_cube_D0.json and metrics/copy.json"):
        report_md(Params(), *ms.files)


def test_params_with_task_stack_read_no_stack_cube_metrics(tmp_path):
    """The committed metrics hold stack_cube's evaluations and stack's robot transfer runs:
    with ``task: stack`` the report shows stack's rows only, none read from stack_cube's
    files (whose names begin with stack_)."""
    (tmp_path / "params.yaml").write_text(
        "task: stack\nbackend: pybullet\ngenerate: {variants: [D0, D1]}\n"
    )
    cli("report", "--metrics", str(REPO / "metrics"), "--plots", str(REPO / "plots"),
        "--paper", str(PAPER), "--out", "report", cwd=tmp_path)  # fmt: skip
    md = (tmp_path / "report/report.md").read_text()
    # no run of stack was trained, evaluated or ablated: stack_cube's are not taken for it
    assert "## Policy success rate" not in md and "## Ablations" not in md
    dgr = md.split("## Data generation rate")[1].split("## ")[0]
    assert rows_of(dgr, "| D0 | missing |", "| D1 | missing |") == rows_of(dgr, "| D")
    assert "Robot transfer" not in md  # robot transfer's own pipeline reports it


def test_the_transfer_report_shows_each_arms_committed_dgr(tmp_path):
    """`report --transfer` on the committed transfer/metrics: each arm's DGR and IK failures
    as its metrics file has them, and the same numbers in summary.json."""
    cli("report", "--params", str(REPO / "transfer/params.yaml"), "--transfer",
        "--metrics", str(REPO / "transfer/metrics"), "--paper", str(PAPER), "--out", "report",
        cwd=tmp_path)  # fmt: skip
    md = (tmp_path / "report/report.md").read_text()
    summary = json.loads((tmp_path / "report/summary.json").read_text())
    cells = []
    for robot in ("panda", "iiwa", "xarm6"):
        m = json.loads((REPO / f"transfer/metrics/generate_stack_D0_{robot}.json").read_text())
        ci = fmt_ci((m["successes"], m["attempts"]))
        cells.append(f"{m['dgr']:.1f}{ci} ({m['ik_failures']}/{m['attempts']} IK)")
        assert summary[f"dgr_stack_D0_{robot}"] == round(m["dgr"], 1)
        assert f" [{summary[f'dgr_stack_D0_{robot}_lo']}–" in ci
    assert f"| stack (D0) | {' | '.join(cells)} |" in md
    # PyBullet Stack Three's D0 policies (transfer.policy_tasks), beside P.1
    ev = json.loads((REPO / "transfer/metrics/evaluate_stack_three_D0_on_D0.json").read_text())
    pooled = (round(ev["success_rate_max"] * 3 * ev["episodes"] / 100), 3 * ev["episodes"])
    sr = f"{ev['success_rate_max']:.1f} ± {ev['success_rate_max_std']:.1f}{fmt_ci(pooled)}"
    sr += " (3 seeds)"
    assert rows_of(md, "| `stack_three` | Stack Three |")[0].split(" | ")[5] == sr
    assert summary["sr_stack_three_D0_on_D0"] == round(ev["success_rate_max"], 1)
    # each DGR and SR with its interval's bounds
    assert "| stack_cube (D1) |" in md and len(summary) == 3 * (3 * 2 * 3 + 2 * 2 + 1)


def test_a_generate_only_experiment_marks_what_is_of_the_earlier_run():
    """generate re-run alone (new run id): the report shows its DGR, and the coverage and
    policy rows measured on the earlier run's data are marked, not refused."""
    files = (
        gen("stack_cube", "D0", 80.0, attempts=1250, run_id="new"),
        gen("stack_cube", "D1", 93.0, attempts=1075, run_id="same"),
        m("coverage", "stack_cube", "D0", run_id="old", support_coverage_joint=59.1),
        m("coverage", "stack_cube", "D1", run_id="same", support_coverage_joint=73.9),
        m("evaluate", "stack_cube", "D0", data="D0", data_run_id="old", success_rate_max=86.0),
        m("evaluate", "stack_cube", "D1", data="D1", data_run_id="same", success_rate_max=90.0),
        m("evaluate", "stack_cube", "D0", data="source", data_run_id=None, success_rate_max=0.0),
    )
    md = report_md(Params(), *files)
    assert rows_of(md, "| D0 | 1250 | 1000 | 80.0 [77.7–82.1] |")  # the new generate run
    assert rows_of(md, "| generated D0 † | D0 | 86.0 |")
    assert rows_of(md, "| generated D1 | D1 | 90.0 |") and rows_of(md, "| source demos | D0 |")
    assert rows_of(md, "| D0 † | missing | missing / missing | 59.1 |")
    assert rows_of(md, "| D1 | missing | missing / missing | 73.9 |")
    notes = [ln for ln in md.splitlines() if ln.startswith("† measured on the data of another")]
    assert len(notes) == 2 and "train/evaluate has not been re-run" in notes[0]


# --- the default pipeline's report --------------------------------------------------------


def test_wilson_interval_is_the_hand_computed_one():
    """95% Wilson score intervals [%] worked by hand from (p + z²/2n ± z·sqrt(p(1-p)/n +
    z²/4n²)) / (1 + z²/n), z = 1.96: e.g. 20 of 22: centre 0.8483, half 0.1264."""
    cases = {(20, 22): (72.18, 97.47), (5, 10): (23.66, 76.34), (0, 10): (0.0, 27.75),
             (10, 10): (72.25, 100.0), (0, 50): (0.0, 7.14)}  # fmt: skip
    for (k, n), (lo, hi) in cases.items():
        got = wilson_interval(k, n)
        assert got is not None and abs(got[0] - lo) < 0.01 and abs(got[1] - hi) < 0.01, (k, n)
    assert wilson_interval(0, 0) is None
    assert fmt_ci((20, 22)) == " [72.2–97.5]" and fmt_ci(None) == ""


def test_success_counts_pool_the_seeds_and_only_when_exact():
    """An evaluation's rates are means over seeds of successes / episodes: pooled counts are
    the mean times episodes × seeds (each seed's best checkpoint for max), or one seed's;
    none when a count is absent or the rate is not of whole episodes."""
    ev = {"success_rate_max": 94.0, "success_rate_last": 88.0, "seed0_success_rate_max": 98.0,
          "episodes": 50, "seeds": 3}  # fmt: skip
    assert sr_counts(ev) == (141, 150) and sr_counts(ev, "last") == (132, 150)
    assert sr_counts(ev, seed=0) == (49, 50)
    assert sr_counts(ev | {"success_rate_max": 33.3}) is None  # 49.95 of 150: no count
    assert sr_counts({"success_rate_max": 94.0, "seeds": 3}) is None  # episodes unknown
    assert fmt_sr(ev) == "94.0" + fmt_ci((141, 150)) and fmt_sr(None) == "missing"


def test_a_generate_only_pipeline_reports_what_it_makes_with_intervals():
    """A pipeline that generates D0 only (the quickstart's): its DGR with its interval and
    failures per subtask; no policy rows, no D1 row, no ablations section; once a D0 policy
    is evaluated, its rows only (not the paper's D1 row), each rate with its interval."""
    d0 = replace(Params(), generate=replace(Params().generate, variants=["D0"]))
    files = (
        gen("stack_cube", "D0", 90.9, attempts=22, failures_place_on_cubeB=2),
        m("coverage", "stack_cube", "D0", support_coverage_joint=2.6),
    )
    md = report_md(d0, *files)
    headings = [ln for ln in md.splitlines() if ln.startswith("#")]
    assert headings == [
        "# MimicGen on stack_cube: our numbers and the paper's",
        "## Data generation rate (DGR, %)",
        "## Support coverage of initial scenes (%, paper Q)",
    ]
    assert "Brackets after a DGR or success rate give its 95% confidence interval" in md
    assert rows_of(md, "| D") == [
        "| D0 | 22 | 20 | 90.9 [72.2–97.5] | grasp_cubeA 0, place_on_cubeB 2 "
        "| 94.3 (Table O.1, Stack D0) | 71.6 (Table M.2, Stack D0) [no NN + no per-subtask] |",
        "| D0 | missing | missing / missing | 2.6 | missing | missing |  |",
    ]
    ev = m("evaluate", "stack_cube", "D0", data="D0", success_rate_max=96.0,
           success_rate_max_std=0.0, success_rate_last=86.0, episodes=50, seeds=1)  # fmt: skip
    md = report_md(d0, *files, ev)
    assert rows_of(md, "| source demos", "| generated ") == [
        "| source demos | D0 | missing | missing | missing | 38.7 ± 4.1 (Table P.1, Stack D0) |",
        "| generated D0 | D0 | 96.0 ± 0.0 [86.5–98.9] | 86.0 [73.8–93.0] | 50 × 1 "
        "| 100.0 ± 0.0 (Table P.1, Stack D0) |",
    ]
    assert headline_numbers(d0, MetricsSet((*files, ev))) == {
        "coverage_D0": 2.6, "dgr_D0": 90.9, "dgr_D0_lo": 72.2, "dgr_D0_hi": 97.5,
        "sr_D0_on_D0": 96.0, "sr_D0_on_D0_lo": 86.5, "sr_D0_on_D0_hi": 98.9,
    }  # fmt: skip


def test_report_shows_missing_metrics_and_never_invents_rows():
    md = report_md(Params(), gen("stack_cube", "D1", 93.0, attempts=1075))
    d0, d1 = rows_of(md, "| D0 | "), rows_of(md, "| D1 | ")
    assert d0[0].startswith(
        "| D0 | missing | missing | missing | missing | 94.3 (Table O.1, Stack D0)"
    )
    assert "| 93.0 [91.3–94.4] | grasp_cubeA 0, place_on_cubeB 0 | 90.0 (Table O.1" in d1[0]
    assert "63.3 (Table M.2, Stack D1) [no NN + no per-subtask]" in d1[0]  # our settings' row
    assert "Heat maps for D0: missing." in md
    # no policy trained or evaluated, no ablation run saved: no such sections
    assert "## Policy success rate" not in md and "## Ablations" not in md

    ev = m("evaluate", "stack_cube", "D1", data="D1", success_rate_max=96.0,
           success_rate_max_std=1.5, success_rate_last=90.0, success_rate_last_std=2.0,
           episodes=50, seeds=3)  # fmt: skip
    md = report_md(Params(), gen("stack_cube", "D1", 93.0, attempts=1075), ev)
    assert rows_of(md, "| generated D1") == [
        "| generated D1 | D1 | 96.0 ± 1.5 [91.5–98.2] | 90.0 ± 2.0 [84.2–93.8] | 50 × 3 "
        "| 100.0 ± 0.0 (Table P.1, Stack D1) |"
    ]
    sr = rows_of(md, "| source demos", "| generated ")  # the paper's P.1 rows, ours missing
    assert len(sr) == 3 and "38.7 ± 4.1 (Table P.1, Stack D0)" in sr[0]
    assert all(ln.count("missing") == 3 for ln in sr[:2])
    # a generate run of another purpose or arm is not the main run's
    other = (
        gen("stack_cube", "D0", 50.0, purpose="dgr"),
        gen("stack_cube", "D0", 60.0, robot="xarm6"),
    )
    assert rows_of(report_md(Params(), *other), "| D0 | missing | missing | missing |")


def test_report_ablations_show_deltas_against_the_base_and_the_papers_direction():
    def run(name: str, params: Params, *dgr: float) -> Run:
        return Run(name, params, MetricsSet(tuple(gen("stack_cube", "D1", d, purpose="dgr")
                                                  for d in dgr)))  # fmt: skip

    runs = [
        run("default", with_settings(), 90.0),
        run("action_noise_0", with_settings(action_noise=0.0), 95.0),
        run("nn_per_subtask", with_settings(selection="nearest_neighbor", per_subtask=True), 92.5),
        run("pose_L2", with_settings(level="L2")),  # its metrics were not produced
        run("seed_1", with_settings(seed=1), 91.0),
        run("seed_2", with_settings(seed=2), 89.0),
        run("other_task", replace(with_settings(), task="stack"), 99.0),  # not stack_cube's
    ]
    paper = load_paper_results(PAPER)
    blocks = build_report(Params(), STACK_CUBE, MetricsSet(()), runs, paper, {}, {}, ())
    at = blocks.index(Heading(2, "Ablations"))
    assert "(`dvc.yaml`: `ablation@<run>`, one per run of `ablations.runs`" in blocks[at + 1].text
    tables = [b for b in blocks if isinstance(b, Table)]
    ablation = next(t for t in tables if t.columns[0] == "run")
    rows = {r[0]: r for r in ablation.rows}
    assert set(rows) == {"default", "action_noise_0", "nn_per_subtask", "seed_1", "seed_2"}
    assert rows["action_noise_0"][1] == "action_noise=0.0" and rows["action_noise_0"][5] == "+5.0"
    assert rows["action_noise_0"][4] == "95.0 [91.0–97.3]"
    assert "Square DGR 48.9 → 50.7 (+1.8, Table M.1)" in rows["action_noise_0"][8]
    assert rows["nn_per_subtask"][5] == "+2.5"
    assert rows["nn_per_subtask"][8].startswith("Stack DGR 63.3 → 90.0 (+26.7, Table M.2)")
    assert rows["default"][1] == "(base)" and rows["default"][5] == ""
    seeds = next(t for t in tables if t.columns[0] == "variant" and "seeds" in t.columns)
    assert seeds.rows[0][1:5] == (
        "0, 1, 2",
        "90.0 [85.1–93.4], 91.0 [86.2–94.2], 89.0 [83.9–92.6]",
        "90.0 ± 1.0 [87.3–92.2]",  # the 600 attempts pooled
        "2.0",
    )
    assert "69.3 ± 0.4 (Table S.1, Stack Three D1)" in seeds.rows[0][5]


def test_transfer_table_reads_each_arms_metrics():
    ms = MetricsSet(
        (
            gen("stack", "D0", 95.0, backend="pybullet", purpose="dgr", ik_failures=7),
            gen("stack", "D0", 78.5, backend="pybullet", robot="iiwa", purpose="dgr",
                ik_failures=42),
            gen("stack_cube", "D0", 93.5, purpose="dgr"),  # no IK check on ManiSkill
            gen("stack_cube", "D0", 96.2, attempts=1039),  # the main run: not a DGR cell
        )
    )  # fmt: skip
    table = transfer_table(ms, "pybullet", ["stack"], ["D0"], ["panda", "iiwa", "xarm6"])
    assert table.rows == (
        ("stack (D0)", "95.0 [91.0–97.3] (7/200 IK)", "78.5 [72.3–83.6] (42/200 IK)", "missing"),
    )
    main = transfer_table(ms, "maniskill", ["stack_cube"], ["D0"], ["panda", "xarm6"])
    assert main.rows == (("stack_cube (D0)", "93.5 [89.2–96.2] (0/200 IK)", "missing"),)


def test_transfer_policies_sit_beside_p1_with_the_generating_arms_dgr():
    """A task of transfer.policy_tasks: the generating arm's fixed attempts on D0 and D1
    beside O.1 (not the policy data's guarantee run, nor another arm's), its D0 policies'
    mean ± std over seeds beside P.1 with the target, and its headline SR; no row for a
    task outside the list."""
    from mimicgen_pipe.report.summary import transfer_headline_numbers
    from mimicgen_pipe.report.transfer import transfer_policy_blocks

    spec = backends.task_spec("pybullet", "stack_three")
    pb = {"backend": "pybullet"}
    files = (
        gen("stack_three", "D0", 79.0, purpose="dgr", **pb),
        gen("stack_three", "D1", 65.0, purpose="dgr", robot="iiwa", **pb),
        gen("stack_three", "D0", 76.0, attempts=1316, **pb),  # the policy data
        m("evaluate", "stack_three", "D0", data="D0", success_rate_max=84.7,
          success_rate_max_std=2.5, seeds=3, **pb),
    )  # fmt: skip
    params = replace(Params(), transfer=replace(Params().transfer, policy_tasks=["stack_three"]))
    paper = load_paper_results(PAPER)
    blocks = transfer_policy_blocks(params, [spec], MetricsSet(files), paper)
    assert blocks[0] == Heading(2, "Policies on pybullet: the paper's own geometry")
    assert blocks[-1].rows == (
        ("`stack_three`", "Stack Three", "79.0 [72.8–84.1] / 71.3", "missing / 68.9", "`cpu`",
         "84.7 ± 2.5 (3 seeds)", "88.0 ± 1.6 (Table P.1, Stack Three D0)", "yes (≥ 83.0)"),
    )  # fmt: skip
    assert transfer_headline_numbers(params, MetricsSet(files))["sr_stack_three_D0_on_D0"] == 84.7
    assert transfer_policy_blocks(Params(), [spec], MetricsSet(files), paper) == []


def write_folder(folder: Path, *files: Metrics) -> Path:
    """``files`` written as the stages write them, in ``folder``."""
    for f in files:
        ident = metrics_identity(f.stage, f.task, f.backend, f.robot, variant=f.variant,
                                 data=f.data, purpose=f.purpose)  # fmt: skip
        write_metrics(folder / f.path.name, ident | dict(f.values))
    return folder


def write_curves(plots: Path, *names: str, seeds: int = 1) -> None:
    """Curve CSVs as train (train_stack_cube_<data>) and evaluate
    (evaluate_stack_cube_<data>_on_<variant>) write them: ``seeds`` training seeds, 3 epochs."""
    plots.mkdir(parents=True, exist_ok=True)
    for name in names:
        if name.startswith("train_"):
            rows = ["seed,epoch,step,loss,val_loss,seconds"]
            rows += [f"{s},{e},{100 * e},{-e - s},{1 - e},{e}" for s in range(seeds)
                     for e in (1, 2, 3)]  # fmt: skip
        else:
            rows = ["seed,epoch,success_rate"]
            rows += [f"{s},{50 * e},{10.0 * e + s}" for s in range(seeds) for e in (1, 2, 3)]
        (plots / f"{name}.csv").write_text("\n".join(rows) + "\n")


def run_report(tmp_path: Path, metrics: Path, plots: Path, out: Path) -> None:
    from mimicgen_pipe.stages import report

    (tmp_path / "params.yaml").write_text("task: stack_cube\ngenerate: {variants: [D0, D1]}\n")
    args = dict(params=str(tmp_path / "params.yaml"), metrics=str(metrics), ablations=None,
                plots=str(plots), paper=str(PAPER), out=str(out), suite=False,
                transit=False, transfer=False, images=False)  # fmt: skip
    with claims():
        report.run(report.resolve(argparse.Namespace(**args)))


def folder_bytes(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


POLICIES = (
    gen("stack_cube", "D0", 96.24, run_id="a"),
    gen("stack_cube", "D1", 93.0, run_id="b"),
    m("coverage", "stack_cube", "D1", run_id="b", bins=3, support_coverage_joint=73.86),
    m("train", "stack_cube", data="source"),
    m("train", "stack_cube", data="D0"),
    m("evaluate", "stack_cube", "D0", data="source", success_rate_max=0.0),
    m("evaluate", "stack_cube", "D0", data="D0", data_run_id="a", success_rate_max=86.66,
      success_rate_max_std=1.2),
)  # fmt: skip


def test_the_coverage_and_report_stages_together(tmp_path):
    """The stage reads the metrics folder and the plots it is pointed at and writes the
    report, its headline numbers and its figures; the heat maps stay where the coverage
    stage writes them, referred to from the report and embedded in its HTML."""
    metrics = write_folder(tmp_path / "metrics", *POLICIES)
    plots = tmp_path / "plots"
    write_curves(plots, "train_stack_cube_source", "train_stack_cube_D0",
                 "evaluate_stack_cube_D0_on_D0")  # fmt: skip
    (plots / "coverage_stack_cube_D1.png").write_bytes(b"\x89PNG fake")
    out = tmp_path / "report"
    run_report(tmp_path, metrics, plots, out)
    assert sorted(p.name for p in out.iterdir()) == [
        "report.html", "report.md", "success_rates.png", "summary.json", "training_curves.png"
    ]  # fmt: skip
    md = (out / "report.md").read_text()
    assert "![initial object positions, stack_cube D1](../plots/coverage_stack_cube_D1.png)" in md
    assert (
        "![training and validation loss per epoch, one panel per policy](training_curves.png)" in md
    )
    assert "![success rate per checkpoint rolled out](success_rates.png)" in md
    assert rows_of(md, "| D1 | 3 | missing / missing | 73.9 |")
    page = (out / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 3  # the heat maps and both figures
    assert 'src="data:image/png;base64,iVBORyBmYWtl"' in page
    assert "Task suite" not in md
    assert (out / "summary.json").read_text() == json.dumps(
        {"coverage_D1": 73.9, "dgr_D0": 96.2, "dgr_D0_hi": 98.0, "dgr_D0_lo": 92.3,
         "dgr_D1": 93.0, "dgr_D1_hi": 95.8, "dgr_D1_lo": 88.6, "sr_D0_on_D0": 86.7,
         "sr_source_on_D0": 0.0}, indent=2
    ) + "\n"  # fmt: skip
    # the same inputs, the same bytes: DVC sees no change
    first = folder_bytes(out)
    run_report(tmp_path, metrics, plots, out)
    assert folder_bytes(out) == first


def test_a_report_folder_with_heat_map_copies_is_replaced_and_one_with_other_files_refused(
    tmp_path,
):
    """A report folder holding heat-map copies (coverage_*.png) is replaced whole, copies
    gone; one holding a file the stage does not write is refused before any work. Without
    policies (no train or evaluate metrics) there are no figures and no success rates."""
    metrics = write_folder(tmp_path / "metrics", *POLICIES[:3])
    write_curves(tmp_path / "plots", "train_stack_cube_D1")  # no train metrics: not drawn
    out = tmp_path / "report"
    out.mkdir()
    (out / "coverage_stack_cube_D0.png").write_bytes(b"\x89PNG old copy")
    (out / "report.md").write_text("old")
    run_report(tmp_path, metrics, tmp_path / "plots", out)
    assert sorted(p.name for p in out.iterdir()) == ["report.html", "report.md", "summary.json"]
    assert json.loads((out / "summary.json").read_text()) == {
        "coverage_D1": 73.9, "dgr_D0": 96.2, "dgr_D0_hi": 98.0, "dgr_D0_lo": 92.3,
        "dgr_D1": 93.0, "dgr_D1_hi": 95.8, "dgr_D1_lo": 88.6,
    }  # fmt: skip
    assert "Policies over training" not in (out / "report.md").read_text()
    (out / "notes.txt").write_text("mine")
    before = folder_bytes(out)
    with pytest.raises(InputError, match=r"holds 'notes.txt', which this stage does not write"):
        run_report(tmp_path, metrics, tmp_path / "plots", out)
    assert folder_bytes(out) == before


# --- headline numbers and figures ---------------------------------------------------------


def test_the_summary_holds_the_numbers_the_report_shows():
    """One key per headline number of the main run, rounded as the report shows it; runs of
    another purpose or arm, and numbers not measured, have none."""
    files = (
        *POLICIES,
        gen("stack_cube", "D1", 50.0, purpose="dgr"),
        m("evaluate", "stack_cube", "D1", data="D1", robot="xarm6", success_rate_max=99.0),
    )
    numbers = headline_numbers(Params(), MetricsSet(files))
    # a DGR's interval from its counts; these evaluations hold no episodes: no SR interval
    assert numbers == {"dgr_D0": 96.2, "dgr_D0_lo": 92.3, "dgr_D0_hi": 98.0, "dgr_D1": 93.0,
                       "dgr_D1_lo": 88.6, "dgr_D1_hi": 95.8, "sr_source_on_D0": 0.0,
                       "sr_D0_on_D0": 86.7, "coverage_D1": 73.9}  # fmt: skip
    md = report_md(Params(), *files)
    assert rows_of(md, "| D0 | 200 | 192 | 96.2 [92.3–98.0] |")
    assert rows_of(md, "| D1 | 200 | 186 | 93.0 [88.6–95.8] |")
    assert rows_of(md, "| generated D0 | D0 | 86.7 ± 1.2 |")
    assert rows_of(md, "| source demos | D0 | 0.0 |") and rows_of(md, "| D1 | 3 | ")
    variants = ["D0", "D1", "D2"]  # every number of every variant: twelve keys
    every = [gen("stack_cube", v, 90.0) for v in variants]
    every += [m("coverage", "stack_cube", v, support_coverage_joint=50.0) for v in variants]
    every += [m("evaluate", "stack_cube", v, data=d, success_rate_max=1.0)
              for v in variants for d in ("source", v)]  # fmt: skip
    d2 = replace(Params(), generate=replace(Params().generate, variants=variants))
    assert sorted(headline_numbers(d2, MetricsSet(tuple(every)))) == sorted(
        f"{k}_{v}{b}"
        for v in variants
        for k in ("dgr", "sr_source_on", f"sr_{v}_on", "coverage")
        for b in (("", "_lo", "_hi") if k == "dgr" else ("",))
    )
    assert headline_numbers(Params(), MetricsSet(POLICIES[:3])) == {
        "dgr_D0": 96.2, "dgr_D0_lo": 92.3, "dgr_D0_hi": 98.0, "dgr_D1": 93.0,
        "dgr_D1_lo": 88.6, "dgr_D1_hi": 95.8, "coverage_D1": 73.9
    }  # fmt: skip


def test_curves_are_read_for_the_policies_the_metrics_name(tmp_path):
    """Train and evaluate CSVs of the policies the metrics say were trained and evaluated,
    averaged over seeds per epoch; an absent CSV is left out, a CSV without metrics unread."""
    plots = tmp_path / "plots"
    write_curves(plots, "train_stack_cube_D0", "train_stack_cube_D1",
                 "evaluate_stack_cube_D0_on_D0", seeds=2)  # fmt: skip
    training, success = read_curves(MetricsSet(POLICIES), Params(), plots)
    assert [c.label for c in training] == ["generated D0"]  # source: no CSV; D1: no metrics
    assert [c.label for c in success] == ["generated D0 on D0"]
    assert training[0].seeds == 2 and training[0].epochs.tolist() == [1, 2, 3]
    assert training[0].columns["loss"].tolist() == [-1.5, -2.5, -3.5]  # seeds 0 and 1
    assert success[0].columns["success_rate"].tolist() == [10.5, 20.5, 30.5]
    assert read_curves(MetricsSet(POLICIES[:3]), Params(), plots) == ([], [])
    (plots / "train_stack_cube_D0.csv").write_text("seed,epoch,loss,val_loss\n0,1,x,2\n")
    with pytest.raises(InputError, match=r"train_stack_cube_D0.csv: line 2: expected numbers"):
        read_curves(MetricsSet(POLICIES), Params(), plots)
    (plots / "train_stack_cube_D0.csv").write_text("seed,epoch,loss\n0,1,2\n")
    with pytest.raises(InputError, match=r"train_stack_cube_D0.csv: columns val_loss missing"):
        read_curves(MetricsSet(POLICIES), Params(), plots)


def test_figures_are_pngs_of_fixed_bytes(tmp_path):
    """The same curves give the same PNG bytes, with no version or date in them; no curves,
    no figure."""
    write_curves(tmp_path, "train_stack_cube_D0", "evaluate_stack_cube_D0_on_D0")
    curves = read_curves(MetricsSet(POLICIES), Params(), tmp_path)
    figures = draw_curves("stack_cube", *curves)
    assert sorted(figures) == ["success_rates.png", "training_curves.png"]
    for data in figures.values():
        assert data.startswith(b"\x89PNG\r\n\x1a\n")
        assert b"atplotlib" not in data and b"tIME" not in data
    assert draw_curves("stack_cube", *curves) == figures
    assert draw_curves("stack_cube", curves[0], []).keys() == {"training_curves.png"}
    assert draw_curves("stack_cube", [], []) == {}


# --- the task suite's report --------------------------------------------------------------


def suite_params(tasks: list[str]) -> Params:
    p = Params()
    scaling = replace(p.suite.scaling, task="peg_insertion")
    suite = replace(p.suite, tasks=tasks, object_transfer=["peg_insertion"], scaling=scaling)
    return replace(p, suite=suite)


def test_the_suite_report_has_the_suite_sections_only():
    tasks = ["peg_insertion", "plug_charger"]
    specs = [backends.task_spec("maniskill", t) for t in tasks]
    fixed = {"steps": 40000, "purpose": "dgr"}
    files = (
        gen("peg_insertion", "D0", 52.0, **fixed),
        gen("peg_insertion", "O1", 43.0, **fixed),
        gen("peg_insertion", "D0", 56.1, attempts=1783, run_id="t"),  # its policy data
        m("evaluate", "peg_insertion", "D0", data="D0", data_run_id="t", success_rate_max=62.0,
          success_rate_last=54.0),
        gen("stack_cube", "D0", 96.2, attempts=1039),  # the main task's: not in this report
    )  # fmt: skip
    paper = load_paper_results(PAPER)

    def report(files: tuple[Metrics, ...]) -> list:
        """The suite's report of ``files`` alone: no ablations, scaling, profiles or
        robomimic runs."""
        return build_suite_report(suite_params(tasks), specs, MetricsSet(files), {}, paper,
                                  MetricsSet(()), {}, ([], {}, {}), MetricsSet(()))  # fmt: skip

    blocks = report(files)
    headings = [b.text for b in blocks if isinstance(b, Heading)]
    assert headings == [
        "MimicGen task suite: our numbers and the paper's",
        "Task suite: data generation rate per task",
        "Object transfer: data generation rate with another object",
        "Task suite: policy success rate (%)",
    ]
    md = render_markdown(blocks)
    assert "stack_cube" not in md
    assert rows_of(md, "| peg_insertion (D0) | Square | 52.0 [45.1–58.8] (104/200) | 0.025 |")
    assert rows_of(
        md, "| peg_insertion | Square | 52.0 [45.1–58.8] (104/200) | 43.0 [36.3–49.9] (86/200) |"
    )
    assert "Mug Cleanup (Table F.1, DGR %): D0 29.5, O1 31.0, O2 24.5" in md
    assert rows_of(md, "| peg_insertion (D0) | Square | missing | 62.0 / 54.0 | missing |")
    assert "†" not in md
    # the policy data generated again since the policy was trained: its row is marked
    files = (*files[:2], gen("peg_insertion", "D0", 50.0, attempts=2000, run_id="u"), *files[3:])
    md = render_markdown(report(files))
    assert rows_of(md, "| peg_insertion (D0) | Square | missing | 62.0 / 54.0 † | missing |")
    assert "† measured on the data of another generate run" in md


def scaling_metrics(run_id: str = "s") -> tuple[Metrics, ...]:
    """The dataset-size comparison's metrics folder: its store, and the policies on 200 and
    1000 of its demos trained and evaluated (5000 not yet)."""
    store = gen("peg_insertion", "D0", 56.0, attempts=8929, run_id=run_id)
    out = [store]
    for n, (best, last, std) in ((200, (20.0, 14.0, 2.0)), (1000, (62.0, 54.0, 0.0))):
        d = f"D0_n{n}"
        out.append(m("train", "peg_insertion", data=d, data_run_id="s",
                     train_episodes=n - n // 10, val_episodes=n // 10))  # fmt: skip
        out.append(m("evaluate", "peg_insertion", "D0", data=d, data_run_id="s", seeds=1,
                     success_rate_max=best, success_rate_last=last, success_rate_max_std=std,
                     success_rate_last_std=std))  # fmt: skip
    return tuple(out)


def test_the_dataset_size_comparison_has_a_row_per_size_and_its_figure():
    """One row per N of suite.scaling.num_demos (missing where not measured), the store the
    policies drew from, the figure of the evaluated sizes; a policy on another run's data is
    marked; no metrics, no section."""
    params = suite_params(["peg_insertion"])
    ms = MetricsSet(scaling_metrics())
    figures = draw_dataset_size(params, ms)
    assert list(figures) == ["dataset_size.png"]
    png = figures["dataset_size.png"]
    assert png.startswith(b"\x89PNG\r\n\x1a\n") and draw_dataset_size(params, ms) == figures
    md = render_markdown(scaling_blocks(params, ms, figures))
    assert "the first N of 5000 demos kept of 8929 attempts (DGR 56.0 [55.0–57.0] %)" in md
    assert rows_of(md, "| 200 | 180 / 20 | 20.0 ± 2.0 | 14.0 ± 2.0 | 1 |")
    assert rows_of(md, "| 1000 | 900 / 100 | 62.0 ± 0.0 | 54.0 ± 0.0 | 1 |")
    assert rows_of(md, "| 5000 | missing | missing | missing | missing |")
    assert "![success rate by dataset size](dataset_size.png)" in md and "†" not in md
    # the store generated again since: the policies measured another run's data
    md = render_markdown(scaling_blocks(params, MetricsSet(scaling_metrics("t")), figures))
    assert rows_of(md, "| 200 | 180 / 20 | 20.0 ± 2.0 † |")
    assert scaling_blocks(params, MetricsSet(()), {}) == []
    assert draw_dataset_size(params, MetricsSet(())) == {}


def test_the_suite_table_states_the_action_noise_each_task_ran_with():
    """plug_charger caps the noise (its 0.5 mm clearance); the others run at the suite's."""
    tasks = ["pull_cube_tool", "plug_charger"]
    specs = [backends.task_spec("maniskill", t) for t in tasks]
    fixed = {"steps": 40000, "purpose": "dgr"}
    ms = MetricsSet((gen("pull_cube_tool", "D0", 64.0, **fixed),
                     gen("plug_charger", "D0", 60.0, **fixed)))  # fmt: skip
    paper = load_paper_results(PAPER)
    table = suite_dgr_blocks(suite_params(tasks), specs, ms, paper)[-1]
    rows = {r[0]: dict(zip(table.columns, r, strict=True)) for r in table.rows}
    assert rows["pull_cube_tool (D0)"]["σ"] == "0.025"
    assert rows["plug_charger (D0)"]["σ"] == "0"
    assert "78.2" in rows["plug_charger (D0)"]["paper DGR"]
    assert rows["plug_charger (D1)"]["DGR % (kept/attempts)"] == "missing"


def test_suite_policy_table_sets_source_beside_generated_and_the_paper():
    spec = backends.task_spec("maniskill", "place_sphere")  # stands for Pick Place
    protocol = {"episodes": 50, "every_epochs": 50, "checkpoints": 4}

    def ev(data: str, variant: str, best: float, last: float, **more: Any) -> Metrics:
        return m("evaluate", "place_sphere", variant, data=data, success_rate_max=best,
                 success_rate_last=last, **(protocol | more))  # fmt: skip

    files = [ev("source", "D0", 6.0, 2.0), ev("D0", "D0", 84.0, 80.0), ev("source", "D1", 0.0, 0.0)]
    paper, params = load_paper_results(PAPER), suite_params(["place_sphere"])
    blocks = suite_policy_blocks(params, [spec], MetricsSet(tuple(files)), paper)
    assert "50 episodes on each of 4 checkpoints per policy (every 50th epoch" in blocks[1].text
    files[2] = ev("source", "D1", 0.0, 0.0, episodes=20)
    mixed = suite_policy_blocks(params, [spec], MetricsSet(tuple(files)), paper)
    assert "as in each evaluate metric" in mixed[1].text
    d0, d1 = blocks[2].rows  # D2: no metric, no row
    assert d0 == (
        "place_sphere (D0)", "Pick Place", "6.0 / 2.0", "84.0 / 80.0", "+78.0",
        "source: 0.0 ± 0.0 (Table P.1, Pick Place D0); D0: 58.7 ± 7.5 (Table P.1, Pick Place D0)",
    )  # fmt: skip
    assert d1 == (
        "place_sphere (D1)", "Pick Place", "0.0 / 0.0", "missing", "missing",
        "– (none in the paper)",
    )  # fmt: skip


def test_paper_geometry_tasks_meet_p1_minus_5_with_their_spread_over_seeds():
    """A task of suite.seeded_policy_tasks gets a row with its D0/D1 DGR beside O.1 and its
    D0 policies' mean ± std over seeds beside P.1, marked by whether it reaches P.1 − 5 (runs
    made outside the pipeline have their own section); one seed shows no spread, and a task
    outside the list gets no row."""
    specs = [backends.task_spec("maniskill", t) for t in ("stack_tower", "peg_insertion_square")]
    files = [
        gen("stack_tower", "D0", 70.0, purpose="dgr"),
        m("evaluate", "stack_tower", "D0", data="D0", success_rate_max=67.3,
          success_rate_max_std=3.4, seeds=3),
        gen("peg_insertion_square", "D1", 87.5, purpose="dgr"),
        m("evaluate", "peg_insertion_square", "D0", data="D0", success_rate_max=96.0,
          success_rate_max_std=0.0, seeds=1),
    ]  # fmt: skip
    params = suite_params(["stack_tower", "peg_insertion_square"])
    params = replace(params, suite=replace(params.suite, seeded_policy_tasks=["stack_tower",
                     "peg_insertion_square"]))  # fmt: skip
    paper = load_paper_results(PAPER)
    blocks = suite.paper_geometry_blocks(params, specs, MetricsSet(tuple(files)), paper)
    assert blocks[0] == Heading(2, "The paper's own geometry")
    p1 = "88.0 ± 1.6 (Table P.1, Stack Three D0)"
    assert blocks[-1].rows == (
        ("`stack_tower`", "Stack Three", "70.0 [63.3–75.9] / 71.3", "missing / 68.9",
         "`cpu` (the suite's)", "67.3 ± 3.4 (3 seeds)", p1, "no (≥ 83.0)"),
        ("`peg_insertion_square`", "Square", "missing / 73.7", "87.5 [82.2–91.4] / 48.9",
         "`cpu` (the suite's)", "96.0 (1 seed)", "98.0 ± 1.6 (Table P.1, Square D0)",
         "yes (≥ 93.0)"),
    )  # fmt: skip
    files[-1] = m("evaluate", "peg_insertion_square", "D0", data="D0", success_rate_max=92.0,
                  seeds=3, success_rate_max_std=1.0)  # fmt: skip
    rows = suite.paper_geometry_blocks(params, specs, MetricsSet(tuple(files)), paper)[-1].rows
    assert rows[1][5:] == ("92.0 ± 1.0 (3 seeds)", "98.0 ± 1.6 (Table P.1, Square D0)",
                           "no (≥ 93.0)")  # fmt: skip
    none = replace(params, suite=replace(params.suite, seeded_policy_tasks=[]))
    assert suite.paper_geometry_blocks(none, specs, MetricsSet(tuple(files)), paper) == []


def test_long_tasks_sit_beside_the_papers_kitchen_and_coffee_preparation():
    """A suite task of five or more subtasks gets a row in the long-task table, with its DGR
    per variant and its D0 policies, under the paper's long tasks; a short task gets none."""
    specs = [backends.task_spec("maniskill", t) for t in ("drawer_cleanup", "place_sphere")]
    files = (
        gen("drawer_cleanup", "D0", 64.0, purpose="dgr"),
        gen("drawer_cleanup", "D2", 30.5, purpose="dgr"),
        m("evaluate", "drawer_cleanup", "D0", data="source", success_rate_max=2.0),
        m("evaluate", "drawer_cleanup", "D0", data="D0", success_rate_max=48.0),
        gen("place_sphere", "D0", 90.0, purpose="dgr"),
    )
    params = suite_params(["drawer_cleanup", "place_sphere"])
    blocks = suite.long_task_blocks(params, specs, MetricsSet(files), load_paper_results(PAPER))
    assert blocks[0] == Heading(2, "Long tasks beside the paper's")
    assert blocks[-1].rows == (
        ("`drawer_cleanup` (ours)", "6", "64.0 [57.1–70.3] (128/200)", "missing",
         "30.5 [24.5–37.2] (61/200)", "2.0", "48.0"),
        ("Kitchen (paper)", "7", "100.0", "42.7", "missing", "43.3 ± 3.4", "100.0 ± 0.0"),
        ("Coffee Preparation (paper)", "5", "53.2", "36.1", "missing", "2.0 ± 0.0",
         "76.0 ± 5.7"),
    )  # fmt: skip
    assert suite.long_task_blocks(params, specs[1:], MetricsSet(files), PaperResults(())) == []


def test_two_arm_tasks_have_their_own_table_and_stay_out_of_the_long_tasks():
    """A two-arm task: its own row with each arm's subtasks, its constraints, DGR with the
    failures charged to each arm, and its D0 policies; the long-task table (the paper's
    one-arm long tasks) leaves it out though it has six subtasks; the DGR table names the arm
    of each subtask's failures."""
    specs = [backends.task_spec("maniskill", t) for t in ("two_robot_stack_cube", "place_sphere")]
    files = (
        gen("two_robot_stack_cube", "D0", 86.5, purpose="dgr", failures_carry_cubeA=10,
            failures_retreat=17, steps=66000),
        m("evaluate", "two_robot_stack_cube", "D0", data="source", success_rate_max=4.0,
          success_rate_last=2.0),
        m("evaluate", "two_robot_stack_cube", "D0", data="D0", success_rate_max=60.0,
          success_rate_last=52.0),
    )  # fmt: skip
    params = suite_params(["two_robot_stack_cube", "place_sphere"])
    ms = MetricsSet(files)
    assert suite.long_task_blocks(params, specs, ms, PaperResults(())) == []
    blocks = suite.two_arm_blocks(params, specs, ms)
    assert blocks[0] == Heading(2, "Two arms")
    (row,) = blocks[-1].rows
    assert row[0] == "`two_robot_stack_cube`"
    assert row[1] == (
        "left: grasp_cubeA, carry_cubeA, stack_cubeA; right: grasp_cubeB, place_cubeB, retreat"
    )
    assert row[2] == "sequential: right place_cubeB → left stack_cubeA"
    assert row[3] == "86.5 [81.1–90.6] (173/200); failed: left 10, right 17"
    assert row[4:] == ("missing", "missing", "4.0 / 2.0", "60.0 / 52.0")
    assert suite.two_arm_blocks(params, specs[1:], ms) == []
    dgr = suite.suite_dgr_blocks(params, specs[:1], ms, PaperResults(()))[-1].rows[0]
    assert "left: carry_cubeA 10" in dgr[4] and "right: retreat 17" in dgr[4]


def test_suite_ablations_compare_with_their_own_default_run():
    """A suite task's ablations have a base of their own (here action noise 0.025, not
    params.yaml's 0.05): deltas are against the run named default, and a folder without it
    says so instead of comparing with the wrong base."""
    paper = load_paper_results(PAPER)

    def run(name: str, params: Params, dgr: float) -> Run:
        params = replace(params, task="pull_cube_tool")
        return Run(name, params, MetricsSet((gen("pull_cube_tool", "D1", dgr, purpose="dgr"),)))

    base, l2 = with_settings(action_noise=0.025), with_settings(action_noise=0.025, level="L2")
    runs = [
        run("default", base, 43.5),
        run("action_noise_0", with_settings(action_noise=0.0), 62.0),
        run("pose_noise_L2", l2, 29.5),
    ]
    blocks = suite_ablation_blocks("pull_cube_tool", "Hammer Cleanup", runs, paper)
    assert blocks[0] == Heading(2, "Ablations on pull_cube_tool (Hammer Cleanup)")
    assert "`suite/ablations/dvc.yaml`: `ablation_suite@pull_cube_tool-<run>`" in blocks[1].text
    assert "`suite/metrics/ablations/pull_cube_tool/<run>/`" in blocks[1].text
    rows = {r[0]: r for r in blocks[-1].rows}
    assert rows["default"][1] == "(base)"
    assert rows["action_noise_0"][1:6] == (
        "action_noise=0.0", "D1", "200", "62.0 [55.1–68.4]", "+18.5"
    )  # fmt: skip
    assert rows["pose_noise_L2"][1] == "pose_noise.level=L2" and rows["pose_noise_L2"][5] == "-14.0"
    lone = suite_ablation_blocks("pull_cube_tool", "Hammer Cleanup", runs[1:], paper)
    assert isinstance(lone[-1], Text)
    assert "missing" in lone[-1].text and "action_noise_0, pose_noise_L2" in lone[-1].text


def test_the_transit_report_sets_each_cells_linear_and_planned_runs_side_by_side():
    def run(task, variant, dgr, planned, **extra):
        fields = dict(purpose="dgr", steps=40000) | extra
        if planned:
            fields |= {"planner_failures": 3}
        return gen(task, variant, dgr, **fields)

    files = [
        run("stack_cube_wall", "wall", 4.5, False),
        run("stack_cube_wall", "wall", 60.0, True),
        run("stack_cube_wall", "D0", 95.0, False),
        run("pull_cube_tool", "D0", 80.0, True),  # its linear run is absent
        # the wall's policies: their data (generated until 100 kept) and their rollouts
        run("stack_cube_wall", "wall", 70.9, True, purpose="policy_data", attempts=141),
        m(
            "evaluate",
            "stack_cube_wall",
            "wall",
            data="wall_planned",
            success_rate_max=6.0,
            success_rate_last=2.0,
        ),  # fmt: skip
    ]
    md = render_markdown(build_transit_report(Params(), MetricsSet(tuple(files))))
    wall = rows_of(md, "| stack_cube_wall (wall)")
    assert wall == [
        "| stack_cube_wall (wall) | 4.5 [2.4–8.3] (9/200) | 60.0 [53.1–66.5] (120/200) | +55.5 "
        "| 3 | 200 | 200 |"
    ]
    assert rows_of(md, "| stack_cube_wall (D0)")[0].startswith(
        "| stack_cube_wall (D0) | 95.0 [91.0–97.3] (190/200) | missing | missing | missing |"
    )
    assert rows_of(md, "| pull_cube_tool (D0)")[0].startswith(
        "| pull_cube_tool (D0) | missing | 80.0 [73.9–85.0] (160/200) | missing | 3 |"
    )
    assert rows_of(md, "| place_sphere (D0)")[0].startswith("| place_sphere (D0) | missing |")
    assert rows_of(md, "| linear |", "| planned |") == [
        "| linear | missing | missing | missing |",
        "| planned | 100 of 141 attempts | 6.0 | 2.0 |",
    ]


def test_no_report_shows_a_wall_clock_time(tmp_path, monkeypatch):
    """A report is tracked: a rerun that reproduces the data must give the same bytes, so
    the times a stage took (different on every run) are in no report, whatever they are."""
    from mimicgen_pipe.report.inputs import read_media
    from mimicgen_pipe.report.videos import video_blocks

    monkeypatch.chdir(tmp_path)  # the render stage's videos under media/, as it lays them out
    (tmp_path / "media" / "stack_cube_D0").mkdir(parents=True)
    (tmp_path / "media" / "stack_cube_D0" / "kept_0.mp4").write_bytes(b"")
    tasks = ["peg_insertion"]
    specs = [backends.task_spec("maniskill", t) for t in tasks]

    def reports(t: float) -> str:
        """The suite's DGR table, the transit report and the videos, with times ``t``."""
        times = {"seconds_per_attempt_mean": t, "seconds_per_attempt_median": t}
        g = gen("peg_insertion", "D0", 52.0, purpose="dgr", steps=40000, **times)
        planned = gen("stack_cube_wall", "wall", 60.0, purpose="dgr", steps=40000,
                      planner_failures=3, **times)  # fmt: skip
        linear = gen("stack_cube_wall", "wall", 4.5, purpose="dgr", steps=40000, **times)
        render = m("render", "stack_cube", "D0", frames=300, ms_per_frame=t)
        media = read_media(MetricsSet((render,)), "stack_cube", "maniskill", ["D0"])
        blocks = [
            *suite_dgr_blocks(suite_params(tasks), specs, MetricsSet((g,)), PaperResults(())),
            *build_transit_report(Params(), MetricsSet((planned, linear))),
            *video_blocks("stack_cube", ["D0"], media, "../media"),
        ]
        return render_markdown(blocks)

    md = reports(123.25)
    assert "kept_0.mp4" in md and "123" not in md
    assert md == reports(7.5)


def test_policies_by_training_profile_show_each_runs_seeds_and_spread(tmp_path):
    from mimicgen_pipe.report.profiles import profile_blocks, read_made_by, read_profile_runs

    assert read_profile_runs(tmp_path) == {}  # no runs: no folder, no section
    specs = [backends.task_spec("maniskill", t) for t in ("peg_insertion", "plug_charger")]
    runs = {
        "cpu_3seeds": [
            m("train", "peg_insertion", data="D0", profile="cpu", seeds=3, gradient_steps=60000,
              train_episodes=4500, val_episodes=500),
            m("evaluate", "peg_insertion", "D0", data="D0", seeds=3, checkpoints=4, horizon=400,
              success_rate_max=60.0,
              success_rate_max_std=4.0, success_rate_last=50.0, success_rate_last_std=8.2),
            m("train", "peg_insertion", data="D1", profile="cpu", seeds=3, gradient_steps=60000),
            m("evaluate", "peg_insertion", "D1", data="D1", seeds=3, checkpoints=4,
              success_rate_max=40.0,
              success_rate_max_std=2.0, success_rate_last=30.0, success_rate_last_std=1.0),
            # D1 data rolled out on D0: not a row of its own variant's
            m("evaluate", "peg_insertion", "D0", data="D1", seeds=3, checkpoints=4,
              success_rate_max=11.0),
        ],
        "paper_gpu": [
            m("train", "peg_insertion", data="D0", profile="paper", seeds=3, epochs=534,
              device="NVIDIA H200", matmul="fp32", gradient_steps=160200,
              weights_returned_as="float16"),
            m("evaluate", "peg_insertion", "D0", data="D0", seeds=3, checkpoints=2,
              success_rate_max=70.7,
              success_rate_max_std=3.4, success_rate_last=64.0, success_rate_last_std=7.5),
            # trained, never evaluated: no row
            m("train", "plug_charger", data="D0", profile="paper", seeds=3, epochs=534),
        ],
    }  # fmt: skip
    for run, files in runs.items():
        for f in files:
            ident = {k: getattr(f, k) for k in ("stage", "task", "backend", "variant", "robot",
                                                "data", "purpose")}  # fmt: skip
            path = tmp_path / "profiles" / run / f.path.name
            path.parent.mkdir(parents=True, exist_ok=True)
            write_metrics(path, ident | dict(f.values))
    read = read_profile_runs(tmp_path)
    assert list(read) == ["cpu_3seeds", "paper_gpu"]
    assert read_made_by(tmp_path) == {}
    (tmp_path / "profiles" / "made_by.yaml").write_text(
        "paper_gpu: {commit: ff94dc9, trained_on: NVIDIA H200, command: scripts/paper_profile.py}\n"
    )
    made_by = read_made_by(tmp_path)
    blocks = profile_blocks(suite_params([]), specs, read, load_paper_results(PAPER), made_by)
    md = render_markdown(blocks)
    assert blocks[0] == Heading(2, "Made outside the pipeline: policies by training profile (%)")
    assert blocks[-1].rows == (
        ("`cpu_3seeds`", "not recorded", "not recorded", "not recorded"),
        ("`paper_gpu`", "ff94dc9", "NVIDIA H200", "scripts/paper_profile.py"),
    )
    (tmp_path / "profiles" / "made_by.yaml").write_text("paper_gpu: {commit: ff94dc9}\n")
    with pytest.raises(InputError, match="made_by.yaml: expected run: {commit, trained_on, "):
        read_made_by(tmp_path)
    assert rows_of(md, "| peg_insertion |") == [
        "| peg_insertion | D0 | cpu_3seeds | 5000 | panda | cpu (cpu) | 100 | 200 | 3 | 4 | 400 "
        "| 60.0 ± 4.0 | 50.0 ± 8.2 | 98.0 ± 1.6 (Table P.1, Square D0) |",
        "| peg_insertion | D0 | paper_gpu | missing | panda | paper (NVIDIA H200, fp32, float16 "
        "weights) | 400 "
        "| 534 | 3 | 2 | missing | 70.7 ± 3.4 | 64.0 ± 7.5 | 98.0 ± 1.6 (Table P.1, Square D0) |",
        "| peg_insertion | D1 | cpu_3seeds | missing | panda | cpu (cpu) | 100 | 200 | 3 | 4 "
        "| missing | 40.0 ± 2.0 | 30.0 ± 1.0 | 80.7 ± 3.4 (Table P.1, Square D1) |",
    ]
    assert "11.0" not in md
    e3 = "Table E.3, low-dim: Square D0 Panda 98.0, other arms 79.3–87.3; Square D1 Panda 80.7"
    e2 = "Table E.2, image agents: Square D0 Panda 90.7, other arms 80.0–86.0; Square D1 Panda"
    assert f"{e3}, other arms 55.3–69.3; {e2} 73.3, other arms 48.0–60.7)" in md
    assert "plug_charger" not in md


def test_the_outside_learner_sits_beside_ours_with_raw_and_normalized_observations():
    """A task of suite.robomimic_tasks gets a row with our D0 policy's seed 0 (and its mean
    over seeds), robomimic's runs with raw and normalized observations told apart by their
    files' names (max, its epoch, last) and P.1; a missing run says so, and no tasks, no
    section."""
    from mimicgen_pipe.report.outside import outside_learner_blocks

    specs = [backends.task_spec("maniskill", t) for t in ("stack_pyramid", "stack_tower")]
    ours = m("evaluate", "stack_pyramid", "D0", data="D0", seeds=1, seed0_success_rate_max=30.0,
             seed0_success_rate_last=26.0, success_rate_max=30.0)  # fmt: skip
    tower = m("evaluate", "stack_tower", "D0", data="D0", seeds=3, success_rate_max=67.3,
              seed0_success_rate_max=66.0, seed0_success_rate_last=66.0,
              success_rate_max_std=3.4)  # fmt: skip

    def outside(obs: str, best: float, epoch: int, last: float) -> Metrics:
        r = m("evaluate", "stack_pyramid", "D0", data="D0", success_rate_max=best,
              seed0_best_epoch=epoch, success_rate_last=last)  # fmt: skip
        return replace(r, path=Path(f"robomimic/evaluate_stack_pyramid_D0_on_D0_{obs}.json"))

    robomimic = MetricsSet((outside("raw", 4.0, 150, 2.0), outside("normalized", 28.0, 200, 28.0)))
    params = suite_params(["stack_pyramid", "stack_tower"])
    params = replace(params, suite=replace(params.suite, robomimic_tasks=["stack_pyramid",
                     "stack_tower"]))  # fmt: skip
    paper = load_paper_results(PAPER)
    blocks = outside_learner_blocks(params, specs, MetricsSet((ours, tower)), robomimic, paper)
    assert blocks[0] == Heading(2, "An outside learner on the same demos")
    assert blocks[-1].rows == (
        ("`stack_pyramid`", "30.0 / 26.0", "4.0 (epoch 150) / 2.0", "28.0 (epoch 200) / 28.0",
         "88.0 ± 1.6 (Table P.1, Stack Three D0)"),
        ("`stack_tower`", "66.0 / 66.0; 67.3 ± 3.4 over 3 seeds", "missing", "missing",
         "88.0 ± 1.6 (Table P.1, Stack Three D0)"),
    )  # fmt: skip
    none = replace(params, suite=replace(params.suite, robomimic_tasks=[]))
    assert outside_learner_blocks(none, specs, MetricsSet((ours,)), robomimic, paper) == []


def test_the_report_says_which_cpu_made_which_results(tmp_path):
    """Each metrics file's CPU comes from its timings file; one line when they agree, a table
    of the types otherwise, a folder of one type folded into one entry; a stage that times
    nothing (no timings file) is not listed, and a run without a recorded CPU says so."""
    from mimicgen_pipe.report.machines import NOT_RECORDED, machine_blocks, read_machines

    zen4 = {"vendor": "AuthenticAMD", "model_name": "AMD EPYC", "family": 25, "model": 17,
            "flags": ["avx2", "fma"]}  # fmt: skip
    zen5 = dict(zen4, family=26, model=2)
    files = {
        "generate_x_D0": zen4, "train_x_D0": zen4, "evaluate_x_D0_on_D0": zen4,
        "ablations/a/generate_x_D1": zen5, "ablations/b/generate_x_D1": zen5,
        "export_x_D0": None,
    }  # fmt: skip
    for name, cpu in files.items():
        (tmp_path / "metrics" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "metrics" / f"{name}.json").write_text("{}")
        (tmp_path / "timings" / name).parent.mkdir(parents=True, exist_ok=True)
        timing = {"wall_seconds": 1.0} | ({"cpu": cpu} if cpu else {})
        (tmp_path / "timings" / f"{name}.json").write_text(json.dumps(timing))
    (tmp_path / "metrics/coverage_x_D0.json").write_text("{}")  # times nothing
    (tmp_path / "metrics/benchmarks").mkdir()
    (tmp_path / "metrics/benchmarks/speed.json").write_text("{}")
    machines = read_machines(tmp_path / "metrics")
    assert set(machines) == set(files)
    assert machines["export_x_D0"] == NOT_RECORDED
    assert machines["train_x_D0"] == (
        "AMD EPYC (AuthenticAMD family 25 model 17; avx2, fma)"
    )  # fmt: skip
    rows = machine_blocks(machines)[-1].rows
    assert rows[0] == (machines["train_x_D0"], "the other 3 files")
    assert rows[1] == (machines["ablations/a/generate_x_D1"], "`ablations/` (2 files)")
    assert rows[2] == (NOT_RECORDED, "`export_x_D0`")
    one = machine_blocks({k: v for k, v in machines.items() if v == machines["train_x_D0"]})
    assert one[-1] == Text(f"Every result here (3 files) was made on {machines['train_x_D0']}.")
    assert machine_blocks({}) == []
