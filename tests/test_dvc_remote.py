"""The DVC remote of docs/workflow.md ("Sharing data through a DVC remote"): a pipeline's
outputs pushed to a local-folder remote come back, byte for byte, on a clone that never ran
the pipeline."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

DVC = [sys.executable, "-m", "dvc"]

PIPELINE = """stages:
  make:
    cmd: python make.py
    deps: [make.py]
    outs: [data/store]
    metrics: [{metrics.json: {cache: false}}]
"""
MAKE = """import json, pathlib
store = pathlib.Path("data/store")
store.mkdir(parents=True)
(store / "a.bin").write_bytes(bytes(range(256)) * 64)
pathlib.Path("metrics.json").write_text(json.dumps({"n": 16384}))
"""


def _run(cmd: list[str], cwd: Path) -> str:
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    res = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    assert res.returncode == 0, f"{' '.join(cmd)} failed:\n{res.stdout}\n{res.stderr}"
    return res.stdout


def _git(cwd: Path, *args: str) -> None:
    _run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd)


def test_push_then_pull_restores_a_pipelines_outputs(tmp_path):
    origin, remote, clone = tmp_path / "origin", tmp_path / "remote", tmp_path / "clone"
    origin.mkdir()
    _git(origin, "init", "-q")
    _run([*DVC, "init", "-q"], origin)
    _run([*DVC, "config", "core.analytics", "false"], origin)
    (origin / "dvc.yaml").write_text(PIPELINE)
    (origin / "make.py").write_text(MAKE)
    _run([*DVC, "repro", "-q"], origin)
    made = (origin / "data/store/a.bin").read_bytes()
    # as the docs say: a default remote in .dvc/config, committed, then dvc push
    _run([*DVC, "remote", "add", "-d", "shared", str(remote)], origin)
    _git(origin, "add", "-A")
    _git(origin, "commit", "-qm", "run")
    _run([*DVC, "push", "-q"], origin)
    assert any(p.is_file() for p in remote.rglob("*")), "dvc push copied nothing"

    _git(tmp_path, "clone", "-q", str(origin), str(clone))
    assert not (clone / "data/store").exists()
    _run([*DVC, "pull", "-q", "dvc.yaml"], clone)
    pulled = (clone / "data/store/a.bin").read_bytes()
    assert hashlib.md5(pulled).digest() == hashlib.md5(made).digest()
    assert "up to date" in _run([*DVC, "status", "dvc.yaml"], clone).lower()
