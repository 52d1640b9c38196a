"""mimicgen-pipe compare: runs side by side from dvc exp show --json, in DVC 3's layout (a
baseline commit with its experiments under "experiments" -> "revs")."""

from __future__ import annotations

import json

import pytest

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.report import compare
from tests.conftest import cli

QS = compare.PIPELINES["quickstart"]


def entry(rev: str, name: str | None, noise: float, dgr: float, error: object = None) -> dict:
    params = {"task": "stack_cube", "generate": {"action_noise": noise, "variants": ["D0"]}}
    return {
        "rev": rev,
        "name": name,
        "error": error,
        "data": {
            "params": {QS.params: {"data": params}, "params.yaml": {"data": {"task": "x"}}},
            "metrics": {QS.summary: {"data": {"dgr_D0": dgr, "coverage_D0": 40.0}}},
        },
    }


def exp_show() -> list[dict]:
    base = entry("a" * 40, "main", 0.05, 90.0)
    base["experiments"] = [
        {"revs": [entry("b" * 40, "noise02", 0.02, 95.0)], "name": "noise02"},
        {"revs": [entry("c" * 40, "broken", 0.1, 0.0, error={"msg": "x"})], "name": "broken"},
    ]
    return [entry("workspace", None, 0.05, 90.0), base]


def test_runs_columns_and_changes_from_the_first():
    runs = compare.runs_of(exp_show(), QS)
    assert [r.name for r in runs] == ["main", "noise02", "workspace"]  # failed run left out
    rows = compare.table(compare.select(runs, ["main", "noise02"]))
    assert rows[0] == ["", "main", "noise02"]
    by_name = {r[0]: r[1:] for r in rows[1:]}
    assert by_name["generate.action_noise"] == ["0.05", "0.02"]
    assert "generate.variants" not in by_name and "task" not in by_name  # unchanged
    assert by_name["dgr_D0"] == ["90", "95 (+5.0)"]
    assert by_name["coverage_D0"] == ["40", "40"]
    every = {r[0] for r in compare.table(runs, all_params=True)}
    assert {"task", "generate.variants"} <= every


def test_unknown_run_names_those_there_are():
    runs = compare.runs_of(exp_show(), QS)
    with pytest.raises(InputError, match="no run named nope .*there are: main, noise02"):
        compare.select(runs, ["nope"])


def test_render_fits_the_width_by_splitting_the_runs():
    rows = [
        ["", *(f"run{i}" for i in range(12))],
        ["dgr_D0", *(f"{90 + i} (+{i}.0)" for i in range(12))],
    ]
    text = compare.render(rows, width=60)
    assert max(len(line) for line in text.splitlines()) <= 60
    assert text.count("dgr_D0") > 1  # the row name repeats in every block
    assert all(f"run{i}" in text for i in range(12))


def test_the_command_reads_dvc_json(tmp_path):
    (tmp_path / "shown.json").write_text(json.dumps(exp_show()))
    res = cli("compare", "--pipeline", "quickstart", "--json", "shown.json", cwd=tmp_path)
    lines = res.stdout.splitlines()
    assert lines[0].split() == ["main", "noise02", "workspace"]
    assert any(line.split()[:3] == ["dgr_D0", "90", "95"] for line in lines)
    (tmp_path / "bad.json").write_text("{")
    res = cli("compare", "--json", "bad.json", cwd=tmp_path, check=False)
    assert res.returncode == 2 and "bad.json: not dvc exp show --json output" in res.stderr


def test_a_numbers_interval_bounds_share_its_row():
    """A summary's ``<key>_lo`` / ``<key>_hi`` (its 95% interval) are shown in ``<key>``'s
    row, not as rows of their own; a run without them shows the number alone."""
    shown = exp_show()
    bounds = {"dgr_D0_lo": 72.2, "dgr_D0_hi": 97.5}
    shown[1]["data"]["metrics"][QS.summary]["data"] |= bounds
    shown[0]["data"]["metrics"][QS.summary]["data"] |= bounds
    rows = compare.table(compare.runs_of(shown, QS))
    by_name = {r[0]: r[1:] for r in rows[1:]}
    assert "dgr_D0_lo" not in by_name and "dgr_D0_hi" not in by_name
    assert by_name["dgr_D0"] == ["90 [72.2–97.5]", "95 (+5.0)", "90 [72.2–97.5]"]
    assert max(len(line) for line in compare.render(rows).splitlines()) <= 120
