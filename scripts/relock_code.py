#!/usr/bin/env python
"""The code deps each pipeline's lock records, against the code in the tree.

DVC hashes a stage's code deps (the folders and files under ``mimicgen_pipe/`` that
scripts/dvc_deps.py lists) when the stage runs. A change to the code that moves no output
(a docstring, a new stage, a new params key) leaves every other stage's lock entry with the
old hashes, and ``dvc repro`` would then re-run the whole pipeline to remake the same
bytes: hours for the suite.

    python scripts/relock_code.py --check   # exit 1 naming each stale entry
    python scripts/relock_code.py --write   # record the tree's hashes in every lock

``--write`` changes only the code deps a lock already records (md5, size, nfiles), hashed as
DVC 3 hashes them; outputs, data deps and params stay as the run recorded them, and a
dep that dvc.yaml lists but the lock lacks stays missing, so that DVC still re-runs that
stage. Use it only after showing that the change moves no output: the quickstart's
rebuild against its lock (tests/test_quickstart.py, tests/test_cross_cpu.py, slow) and a
forced re-run of the stages the change touches, with their outputs compared.
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import os
import sys
from pathlib import Path
from typing import Any

import yaml

REPO = Path(__file__).resolve().parents[1]
CODE = "mimicgen_pipe/"
IGNORED = "__pycache__"  # .dvcignore's one pattern


@functools.cache
def file_md5(path: Path) -> str:
    return hashlib.md5(path.read_bytes()).hexdigest()


@functools.cache
def code_hash(rel: str) -> dict[str, Any]:
    """DVC 3's md5, size and (for a folder) nfiles of a path under the repository."""
    path = REPO / rel
    if path.is_file():
        return {"md5": file_md5(path), "size": path.stat().st_size}
    entries, size = [], 0
    for root, dirs, files in os.walk(path):
        dirs[:] = [d for d in dirs if d != IGNORED]
        for name in files:
            p = Path(root, name)
            entries.append({"md5": file_md5(p), "relpath": p.relative_to(path).as_posix()})
            size += p.stat().st_size
    entries.sort(key=lambda e: e["relpath"])
    digest = hashlib.md5(json.dumps(entries, sort_keys=True).encode()).hexdigest()
    return {"md5": f"{digest}.dir", "size": size, "nfiles": len(entries)}


def locks() -> list[Path]:
    return sorted(p for p in REPO.glob("**/dvc.lock") if ".venv" not in p.parts)


def stale(lock: Path) -> list[tuple[str, dict[str, Any]]]:
    """(stage, dep entry) of each code dep whose recorded hash the tree no longer gives.
    Every stage of the pipelines runs at the repository root (``wdir``), so a lock's paths
    are the repository's."""
    out = []
    for stage, entry in yaml.safe_load(lock.read_text())["stages"].items():
        for dep in entry.get("deps", []):
            if not dep["path"].startswith(CODE):
                continue
            now = code_hash(dep["path"]) if (REPO / dep["path"]).exists() else None
            if now is None or any(dep.get(k) != v for k, v in now.items()):
                out.append((stage, dep))
    return out


def rewrite(lock: Path) -> int:
    """Set each stale code dep's hash fields in place, line by line, so that the rest of the
    file keeps DVC's own layout; the number set."""
    todo = {(s, d["path"]) for s, d in stale(lock)}
    lines = lock.read_text().splitlines(keepends=True)
    done, stage = 0, None
    for i, line in enumerate(lines):
        if line.startswith("  ") and not line.startswith("   ") and line.rstrip().endswith(":"):
            stage = line.strip()[:-1]
        if not line.startswith("    - path: "):
            continue
        path = line.split("- path: ", 1)[1].strip()
        if (stage, path) not in todo:
            continue
        now = code_hash(path)
        j = i + 1
        while j < len(lines) and lines[j].startswith("      "):
            key = lines[j].strip().split(":", 1)[0]
            if key in now:
                lines[j] = f"      {key}: {now[key]}\n"
            j += 1
        done += 1
    lock.write_text("".join(lines))
    return done


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument("--check", action="store_true", help="exit 1 naming each stale entry")
    mode.add_argument("--write", action="store_true", help="record the tree's code hashes")
    args = p.parse_args()
    bad = 0
    for lock in locks():
        name = lock.relative_to(REPO)
        if args.write:
            n = rewrite(lock)
            if n:
                print(f"{name}: {n} code deps recorded")
            continue
        for stage, dep in stale(lock):
            print(f"{name}: {stage}: {dep['path']} is not the tree's", file=sys.stderr)
            bad += 1
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
