"""The README's five-minute command, run as a newcomer runs it: `dvc repro
quickstart/dvc.yaml` in a copy of the repository, giving a generated dataset, its DGR, a
robomimic export and a report, with the numbers committed in quickstart/metrics/."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.test_cross_cpu import locked_outs, made_the_locks
from tests.test_output_safety import tree_digest

REPO = Path(__file__).resolve().parents[1]


def repository_copy(dest: Path) -> Path:
    """The files git would check out (tracked and new, not ignored), in a fresh git repo."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=REPO, capture_output=True, check=True,
    ).stdout.decode().split("\0")  # fmt: skip
    for name in filter(None, listed):
        if (REPO / name).is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / name, dest / name)
    for sub in ("metrics", "plots", "report", "dvc.lock"):  # made by the run itself
        path = dest / "quickstart" / sub
        shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
    subprocess.run(["git", "init", "-q"], cwd=dest, check=True)
    return dest


@pytest.mark.sim
@pytest.mark.slow
def test_the_quickstart_pipeline_gives_data_an_export_and_a_report(tmp_path):
    work = repository_copy(tmp_path)
    env = dict(os.environ, PYTHONPATH=str(work), PYTHONWARNINGS="ignore")
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env['PATH']}"
    res = subprocess.run(
        ["dvc", "repro", "quickstart/dvc.yaml"], cwd=work, env=env, capture_output=True, text=True
    )
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    q = work / "quickstart"
    ran = json.loads((q / "metrics/generate_stack_cube_D0.json").read_text())
    committed = json.loads((REPO / "quickstart/metrics/generate_stack_cube_D0.json").read_text())
    # on the CPU type that made the lock (mimicgen_pipe.arithmetic), the committed run bit for
    # bit: the same run id (a digest of the parsed store's bytes) and every store and export
    # with the md5 the committed lock holds; elsewhere MKL gives other last bits, and the
    # committed DGR holds within seed noise
    if made_the_locks():
        for key in ("attempts", "successes", "dgr", "run_id"):
            assert ran[key] == committed[key], key
        assert locked_outs(q / "dvc.lock") == locked_outs(REPO / "quickstart/dvc.lock")
    assert same_rate_within_noise(ran["dgr"], ran["attempts"], committed["dgr"]), (ran, committed)
    assert ran["successes"] == committed["successes"]
    # bit for bit on this machine: the same run on one worker gives the same stores and id
    one = work / "one.yaml"
    one.write_text((q / "params.yaml").read_text().replace("workers: 2", "workers: 1"))
    again = tmp_path / "again/stack_cube_D0.zarr"
    cmd = ["mimicgen-pipe", "generate", "--params", str(one), "--variant", "D0",
           "--parsed", "quickstart/data/parsed/stack_cube.zarr", "--out", str(again),
           "--metrics", str(tmp_path / "again.json")]  # fmt: skip
    res = subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    assert json.loads((tmp_path / "again.json").read_text())["run_id"] == ran["run_id"]
    for name in ("stack_cube_D0.zarr", "stack_cube_D0_failed.zarr"):
        kept = q / "data/generated" / name
        assert tree_digest(again.parent / name) == tree_digest(kept), name
    summary = json.loads((q / "report/summary.json").read_text())
    assert summary["dgr_D0"] == round(ran["dgr"], 1)
    assert "DGR" in (q / "report/report.html").read_text()

    import h5py

    with h5py.File(q / "data/export/stack_cube_D0/demos.hdf5") as f:
        assert len(f["data"]) == ran["successes"] == 20
    check_a_typo_loses_nothing(work, env)
    check_experiments_and_compare(work, env)


def check_a_typo_loses_nothing(work: Path, env: dict[str, str]) -> None:
    """A typo in the quickstart's params, then `dvc repro`: the pipeline's first stage refuses
    it in one line before DVC removes any stage's outputs, so every store, export and
    tracked metrics file is as the run left it."""
    q = work / "quickstart"
    params = q / "params.yaml"
    before = {p: tree_digest(p) for p in (q / "data", q / "metrics", q / "code_deps")}
    good = params.read_text()
    params.write_text(good.replace("action_noise:", "action_nois:"))
    res = subprocess.run(["dvc", "repro", "quickstart/dvc.yaml"], cwd=work, env=env,
                         capture_output=True, text=True)  # fmt: skip
    params.write_text(good)
    assert res.returncode != 0
    assert "generate.action_nois: unknown key" in res.stdout + res.stderr
    assert {p: tree_digest(p) for p in before} == before


def same_rate_within_noise(percent: float, trials: int, committed: float) -> bool:
    """Whether a success rate (%) measured over ``trials`` lies within 3 binomial standard
    errors of the committed rate (the committed rate's error at this many trials; at least
    one trial's worth, so that a committed 100 % still allows one failure)."""
    p = committed / 100
    sigma = max((p * (1 - p) / trials) ** 0.5, 1 / trials)
    return abs(percent / 100 - p) <= 3 * sigma


def test_a_rate_within_noise_and_one_outside_it():
    assert same_rate_within_noise(90.9, 22, 90.9)
    assert same_rate_within_noise(80.0, 25, 90.9)  # 1.8 standard errors below
    assert not same_rate_within_noise(50.0, 40, 90.9)  # 9 below
    assert same_rate_within_noise(95.2, 21, 100.0) and not same_rate_within_noise(80.0, 25, 100.0)


def ran_stages(output: str) -> set[str]:
    """The stages a dvc repro / dvc exp run ran, from its output (without their
    ``<dvc.yaml>:``)."""
    return set(re.findall(r"Running stage '(?:[^':]+:)?([^']+)'", output))


def check_experiments_and_compare(work: Path, env: dict[str, str]) -> None:
    """Two real experiments on the quickstart after its run, each `dvc exp run
    quickstart/dvc.yaml -S quickstart/params.yaml:<key>=<value>`: each edits the quickstart's
    own params file and re-runs exactly the stages downstream of the key; `mimicgen-pipe
    compare` then shows both beside the commit, within 120 columns."""

    def run(*args: str) -> str:
        res = subprocess.run(args, cwd=work, env=env, capture_output=True, text=True)
        assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
        return res.stdout + res.stderr

    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t"]
    run(*git, "add", "-A")
    run(*git, "commit", "-qm", "base")
    root_params = (work / "params.yaml").read_text()
    q = "quickstart/params.yaml"
    out = run("dvc", "exp", "run", "quickstart/dvc.yaml", "-n", "noise02",
              "-S", f"{q}:generate.action_noise=0.02")  # fmt: skip
    assert ran_stages(out) == {"code_deps", "generate@D0", "coverage@D0", "export@D0", "report"}
    assert "action_noise: 0.02" in (work / q).read_text()
    assert (work / "params.yaml").read_text() == root_params  # not the root's file
    run("git", "checkout", "--", q)
    out = run("dvc", "exp", "run", "quickstart/dvc.yaml", "-n", "bins4",
              "-S", f"{q}:coverage.bins=4")  # fmt: skip
    # from the workspace noise02 left: generate runs back to the committed store
    assert (
        {"code_deps", "coverage@D0", "report"}
        <= ran_stages(out)
        <= {"code_deps", "generate@D0", "coverage@D0", "export@D0", "report"}
    )
    shown = run("mimicgen-pipe", "compare", "--pipeline", "quickstart", "--width", "120")
    lines = shown.splitlines()
    head = lines[0].split()
    assert head[-1] == "workspace" and {"noise02", "bins4"} <= set(head[1:-1])
    assert head[0] not in ("noise02", "bins4")  # the commit comes first
    assert max(map(len, lines)) <= 120
    rows = {line.split()[0]: line.split()[1:] for line in lines[1:] if line.strip()}
    noise = rows["generate.action_noise"]
    assert noise[head.index("noise02")] == "0.02" and noise[0] == "0.05"
    assert rows["coverage.bins"][head.index("bins4")] == "4"
    assert "dgr_D0" in rows and "coverage_D0" in rows
