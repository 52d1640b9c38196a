"""Every committed ``dvc.lock`` is one consistent run: each stage's recorded dependency is
what its producer's lock entry records as output, and each params value a lock records is
the value in the params file now. Reads the locks as plain YAML (no DVC, no simulator)."""

from __future__ import annotations

import copy
import dataclasses
import functools
import importlib.util
from pathlib import Path

import pytest
import yaml

# the suite's lock is large: libyaml's loader reads it in a fraction of the pure-Python time
_Loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

REPO = Path(__file__).resolve().parents[1]
PIPELINES = (
    "dvc.yaml",
    "quickstart/dvc.yaml",
    "suite/dvc.yaml",
    "suite/robomimic/dvc.yaml",
    "suite/scaling/dvc.yaml",
    "suite/ablations/dvc.yaml",
    "transit/dvc.yaml",
    "transfer/dvc.yaml",
    "images/dvc.yaml",
)


def _lookup(mapping: object, dotted: str) -> object:
    for key in dotted.split("."):
        if not isinstance(mapping, dict) or key not in mapping:
            return KeyError(dotted)
        mapping = mapping[key]
    return mapping


def _wdirs(dvc_file: Path) -> dict[str, Path]:
    stages = (yaml.load(dvc_file.read_text(), _Loader) or {}).get("stages") or {}
    return {  # a foreach stage's body is its ``do``
        name: (dvc_file.parent / str(body.get("do", body).get("wdir", "."))).resolve()
        for name, body in stages.items()
    }


@functools.cache
def _params(path: Path) -> object:
    return yaml.load(path.read_text(), _Loader)


def locks(root: Path = REPO) -> dict[str, dict]:
    """Each pipeline's lock that exists, ``dvc.yaml`` path -> parsed ``dvc.lock``."""
    return {
        f: yaml.load((root / f).with_name("dvc.lock").read_text(), _Loader)
        for f in PIPELINES
        if (root / f).with_name("dvc.lock").is_file()
    }


Stage = tuple[str, str]  # (its pipeline's dvc.yaml, its name)


@dataclasses.dataclass(frozen=True)
class LockGraph:
    """Parsed locks as a graph of stages, across pipelines (a stage may read another
    pipeline's store)."""

    wdir: dict[Stage, Path]  # where a stage runs: its lock's paths are relative to it
    body: dict[Stage, dict]  # its lock entry
    producer: dict[Path, Stage]  # an output's absolute path -> the stage that records it
    md5: dict[Path, str | None]  # an output's absolute path -> the md5 recorded for it

    def upstream(self, key: Stage, seen: set[Stage]) -> set[Stage]:
        """``seen`` with ``key`` and every stage upstream of it added."""
        if key not in seen:
            seen.add(key)
            for dep in self.body[key].get("deps") or ():
                path = (self.wdir[key] / dep["path"]).resolve()
                # a dep inside an output folder (a store's file) is that folder's
                up = next(
                    (self.producer[p] for p in (path, *path.parents) if p in self.producer), None
                )
                if up is not None:
                    self.upstream(up, seen)
        return seen


def lock_graph(found: dict[str, dict], root: Path = REPO) -> LockGraph:
    """The graph of the parsed locks ``found`` (``dvc.yaml`` path -> lock) under ``root``."""
    graph = LockGraph({}, {}, {}, {})
    for dvc_file, lock in found.items():
        wdirs = _wdirs(root / dvc_file) if (root / dvc_file).is_file() else {}
        for stage, body in (lock.get("stages") or {}).items():
            key = (dvc_file, stage)
            wdir = wdirs.get(stage.split("@")[0], (root / dvc_file).parent.resolve())
            graph.wdir[key], graph.body[key] = wdir, body
            for out in body.get("outs") or ():
                path = (wdir / out["path"]).resolve()
                graph.producer[path], graph.md5[path] = key, out.get("md5")
    return graph


def inconsistencies(found: dict[str, dict], root: Path = REPO) -> list[tuple[str, str, str]]:
    """``(pipeline, stage, what)`` for every lock edge whose recorded dependency md5 differs
    from its producer's recorded output md5 (across all pipelines: a stage may read another
    pipeline's store), and every recorded params value that differs from its file."""
    graph = lock_graph(found, root)
    bad = []
    for (dvc_file, stage), body in graph.body.items():
        wdir = graph.wdir[dvc_file, stage]
        for dep in body.get("deps") or ():
            path = (wdir / dep["path"]).resolve()
            if path in graph.md5 and graph.md5[path] != dep.get("md5"):
                bad.append((dvc_file, stage, dep["path"]))
        for params_file, values in (body.get("params") or {}).items():
            current = _params(wdir / params_file)
            for key, value in values.items():
                if _lookup(current, key) != value:
                    bad.append((dvc_file, stage, f"{params_file}:{key}"))
    return bad


@pytest.fixture(scope="module")
def committed() -> dict[str, dict]:
    return locks()


@pytest.mark.parametrize("dvc_file", PIPELINES)
def test_each_lock_is_one_run(committed, dvc_file):
    bad = [(s, what) for f, s, what in inconsistencies(committed) if f == dvc_file]
    assert not bad, f"{dvc_file}: stages recorded inputs their producers no longer hold: {bad}"


def _quickstart(found: list[tuple[str, str, str]]) -> list[tuple[str, str, str]]:
    return [edge for edge in found if edge[0] == "quickstart/dvc.yaml"]


def test_a_broken_edge_or_a_changed_param_is_found(committed):
    edited = copy.deepcopy(committed)
    parse = edited["quickstart/dvc.yaml"]["stages"]["parse"]
    parse["deps"] = [
        dict(d, md5="0" * 32) if d["path"].endswith("source/stack_cube.zarr") else d
        for d in parse["deps"]
    ]
    assert _quickstart(inconsistencies(edited)) == [
        ("quickstart/dvc.yaml", "parse", "quickstart/data/source/stack_cube.zarr")
    ]
    edited = copy.deepcopy(committed)
    source = edited["quickstart/dvc.yaml"]["stages"]["source"]
    source["params"]["quickstart/params.yaml"]["source"]["seed"] = 12345
    assert _quickstart(inconsistencies(edited)) == [
        ("quickstart/dvc.yaml", "source", "quickstart/params.yaml:source")
    ]


def _relock_code():
    spec = importlib.util.spec_from_file_location("relock_code", REPO / "scripts/relock_code.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_each_locks_code_deps_are_the_code_in_the_tree():
    """Every code dep a lock records hashes as the tree's code does, so that a fresh clone's
    `dvc repro` re-runs nothing for code alone (scripts/relock_code.py --write records them
    after a change that moves no output)."""
    relock = _relock_code()
    stale = [(str(lock.relative_to(REPO)), s, d["path"]) for lock in relock.locks()
             for s, d in relock.stale(lock)]  # fmt: skip
    assert not stale, f"{len(stale)} code deps differ from the tree, e.g. {stale[:3]}"


def test_relock_code_sees_an_edited_file_and_records_it_in_place(tmp_path, monkeypatch):
    relock = _relock_code()
    (tmp_path / "mimicgen_pipe/core").mkdir(parents=True)
    (tmp_path / "mimicgen_pipe/core/a.py").write_text("x = 1\n")
    (tmp_path / "mimicgen_pipe/core/__pycache__").mkdir()
    (tmp_path / "mimicgen_pipe/core/__pycache__/a.pyc").write_bytes(b"\0")
    monkeypatch.setattr(relock, "REPO", tmp_path)
    relock.code_hash.cache_clear()
    relock.file_md5.cache_clear()
    now = relock.code_hash("mimicgen_pipe/core")
    assert now["nfiles"] == 1 and now["md5"].endswith(".dir")
    lock = tmp_path / "dvc.lock"
    text = (
        "schema: '2.0'\nstages:\n  parse:\n    cmd: mimicgen-pipe parse\n    deps:\n"
        "    - path: data/source/x.zarr\n      hash: md5\n      md5: aaa.dir\n      size: 9\n"
        "      nfiles: 1\n    - path: mimicgen_pipe/core\n      hash: md5\n      md5: old.dir\n"
        "      size: 1\n      nfiles: 7\n    outs:\n    - path: data/parsed/x.zarr\n"
        "      hash: md5\n      md5: bbb.dir\n      size: 3\n      nfiles: 1\n"
    )
    lock.write_text(text)
    assert [d["path"] for _, d in relock.stale(lock)] == ["mimicgen_pipe/core"]
    assert relock.rewrite(lock) == 1
    assert relock.stale(lock) == []
    after = yaml.safe_load(lock.read_text())["stages"]["parse"]
    assert after["deps"][1] == {"path": "mimicgen_pipe/core", "hash": "md5", **now}
    assert after["deps"][0]["md5"] == "aaa.dir" and after["outs"][0]["md5"] == "bbb.dir"
    assert (
        lock.read_text()
        .replace(now["md5"], "old.dir")
        .replace(
            f"size: {now['size']}\n      nfiles: 1\n    outs", "size: 1\n      nfiles: 7\n    outs"
        )
        == text
    )
