"""Each sub-pipeline's params file is params.yaml with that pipeline's overrides, as
scripts/params_files.py writes it: a default is written once, in params.yaml."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("params_files", REPO / "scripts/params_files.py")
params_files = importlib.util.module_from_spec(spec)
spec.loader.exec_module(params_files)


def _copy(tmp_path: Path) -> Path:
    shutil.copy(REPO / "params.yaml", tmp_path / "params.yaml")
    for pipeline in params_files.PIPELINES:
        (tmp_path / pipeline).mkdir()
        for name in ("params.yaml", params_files.OVERRIDES):
            shutil.copy(REPO / pipeline / name, tmp_path / pipeline / name)
    return tmp_path


def _leaves(tree: object, prefix: str = "") -> dict[str, object]:
    if not isinstance(tree, dict):
        return {prefix: tree}
    out: dict[str, object] = {}
    for key, value in tree.items():
        out |= _leaves(value, f"{prefix}.{key}" if prefix else key)
    return out


def test_every_sub_pipeline_params_file_is_as_written():
    assert params_files.main(["--check", "--root", str(REPO)]) == 0, (
        "run: python scripts/params_files.py --write"
    )


@pytest.mark.parametrize("pipeline", params_files.PIPELINES)
def test_a_sub_pipeline_holds_only_its_differences(pipeline):
    """Every key its overrides set differs from params.yaml, or carries its own comment;
    everything else it holds is params.yaml's value."""
    base = _leaves(yaml.safe_load((REPO / "params.yaml").read_text()))
    mine = _leaves(yaml.safe_load((REPO / pipeline / "params.yaml").read_text()))
    overrides = yaml.safe_load((REPO / pipeline / params_files.OVERRIDES).read_text())
    overrides.pop("leave_out", None)
    changed = set(_leaves(overrides))
    for key, value in mine.items():
        if key not in changed:
            assert key in base and base[key] == value, f"{pipeline}: {key} is not params.yaml's"
    written = (REPO / pipeline / params_files.OVERRIDES).read_text()
    assert written.count("\n") < len((REPO / pipeline / "params.yaml").read_text().splitlines())


def test_a_changed_default_reaches_every_pipeline_and_a_stale_file_is_named(tmp_path, capsys):
    root = _copy(tmp_path)
    text = (root / "params.yaml").read_text()
    (root / "params.yaml").write_text(text.replace("n_interp: 5 ", "n_interp: 7 "))
    assert params_files.main(["--check", "--root", str(root)]) == 1
    assert "suite/params.yaml" in capsys.readouterr().err
    assert params_files.main(["--write", "--root", str(root)]) == 0
    for pipeline in params_files.PIPELINES:
        tree = yaml.safe_load((root / pipeline / "params.yaml").read_text())
        assert tree["generate"]["n_interp"] == 7, pipeline
    assert params_files.main(["--check", "--root", str(root)]) == 0


def test_an_override_wins_and_an_unknown_left_out_key_is_refused(tmp_path):
    root = _copy(tmp_path)
    path = root / "quickstart" / params_files.OVERRIDES
    path.write_text(path.read_text().replace("num_demos: 20 ", "num_demos: 30 "))
    tree = yaml.safe_load(params_files.generated(root, "quickstart"))
    assert tree["generate"]["num_demos"] == 30
    assert "evaluate" not in tree  # left out
    path.write_text(path.read_text().replace("leave_out: [", "leave_out: [train.nope, "))
    with pytest.raises(SystemExit, match="quickstart/params.overrides.yaml: leave_out: "
                       "'train.nope' is not a key of params.yaml"):  # fmt: skip
        params_files.generated(root, "quickstart")
