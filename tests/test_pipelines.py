"""The pipelines stand apart and an ablation re-runs only what it changes: a bare
`dvc repro` / `dvc exp run` considers the default pipeline (dvc.yaml) and nothing of the task
suite or the quickstart, and a changed generate or train key reaches only the stages that
read it and their downstream."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import networkx as nx
import pytest
import yaml

from mimicgen_pipe.sources import source_inputs

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def repo():
    from dvc.repo import Repo

    with Repo(str(REPO)) as repo:
        yield repo


@pytest.fixture(scope="module")
def graph(repo) -> nx.DiGraph:
    return repo.index.graph  # edges run from a stage to the stages it reads


def considered(graph: nx.DiGraph, pipeline: str) -> set:
    """What `dvc repro <pipeline>` looks at: its stages and everything upstream of them."""
    stages = {s for s in graph.nodes if s.relpath == pipeline}
    return stages.union(*(nx.descendants(graph, s) for s in stages))


def param_names(stage, params_file: str | None = None) -> list[str]:
    """The params a stage declares (only those of ``params_file``, a path from the
    repository root, when given)."""
    return [
        n
        for d in stage.deps
        if hasattr(d, "params") and (params_file is None or Path(d.fs_path) == REPO / params_file)
        for n in (d.params or d.hash_info.value)
    ]


def rerun(
    graph: nx.DiGraph, key: str, pipeline: str = "dvc.yaml", params_file: str | None = None
) -> set[str]:
    """Stages `dvc exp run <pipeline> -S <params_file>:key=...` re-runs: those listing ``key``
    (or its section) as a param of that file, and everything downstream of them."""
    pool = considered(graph, pipeline)
    # the check stage checks the whole params file on any edit, but writes the same stamp,
    # so nothing downstream of it re-runs for a params edit
    changed = {
        s
        for s in pool
        if s.addressing.rpartition(":")[2] != "check"
        and any(key == n or key.startswith(n + ".") for n in param_names(s, params_file))
    }
    hit = changed.union(*(nx.ancestors(graph, s) & pool for s in changed))
    return {s.addressing for s in hit}


def test_a_bare_repro_runs_the_default_pipeline_only(graph):
    outside = sorted(f"{s.relpath}:{s.addressing}" for s in considered(graph, "dvc.yaml"))
    outside = [s for s in outside if not s.startswith("dvc.yaml:")]
    assert not outside, f"the default pipeline pulls in: {outside}"
    for other in ("quickstart/dvc.yaml", "transit/dvc.yaml"):
        assert {s.relpath for s in considered(graph, other)} == {other}
    # the suite's report reads its three studies, each a pipeline of its own on its stores
    studies = {"suite/robomimic/dvc.yaml", "suite/scaling/dvc.yaml", "suite/ablations/dvc.yaml"}
    assert {s.relpath for s in considered(graph, "suite/dvc.yaml")} == {"suite/dvc.yaml"} | studies
    for study in studies:
        assert {s.relpath for s in considered(graph, study)} == {study, "suite/dvc.yaml"}
    # robot transfer's StackCube cells read the default pipeline's source demos
    upstream = {s.addressing for s in considered(graph, "transfer/dvc.yaml")}
    assert {"source", "parse", "pose_noise"} <= upstream
    assert not {"generate@D0", "train@D0", "report"} & upstream


@pytest.mark.parametrize("section", ["generate", "train"])
def test_a_changed_key_reaches_only_its_readers_and_their_downstream(graph, section):
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    for key in params[section]:
        hit = rerun(graph, f"{section}.{key}")
        assert not {"source", "parse", "pose_noise"} & hit, f"{section}.{key}: {sorted(hit)}"
        if section == "generate":
            assert not {"train_source", "evaluate_source@D0", "evaluate_source@D1"} & hit


def test_the_counts_of_two_common_ablations(graph):
    selection = rerun(graph, "generate.selection")
    main = {
        f"{s}@{v}"
        for s in ("generate", "coverage", "train", "evaluate", "export", "render")
        for v in ("D0", "D1")
    } | {"report", "observe", "export_observed"}
    # every ablation run starts from the pipeline's generation settings
    runs = yaml.safe_load((REPO / "params.yaml").read_text())["ablations"]["runs"]
    main |= {f"ablation@{run}" for run in runs}
    assert selection == main  # robot transfer is a pipeline of its own
    assert rerun(graph, "train.profile") == {
        "train_source",
        "train@D0",
        "train@D1",
        "evaluate_source@D0",
        "evaluate_source@D1",
        "evaluate@D0",
        "evaluate@D1",
        "report",
    }


def test_each_pipeline_reruns_only_its_own_files_readers(graph):
    """`dvc exp run <pipeline> -S <its params file>:<key>=...` on the suite, transit and
    robot-transfer pipelines: the stages of that pipeline that read the key and their
    downstream, none of another pipeline; the root params file reaches none of them."""
    t = "transfer/dvc.yaml"
    noise = rerun(graph, "generate.action_noise", t, "transfer/params.yaml")
    assert len([s for s in noise if s.startswith("transfer/dvc.yaml:generate_transfer@")]) == 18
    assert len([s for s in noise if "generate_transfer_maniskill@" in s]) == 4
    assert {f"{t}:observe_transfer@stack", f"{t}:report_transfer"} <= noise
    # Stack Three's policy chain: its 1000 D0 demos, then the policies trained on them
    policy = {f"{t}:{s}_transfer_policy@stack_three" for s in ("generate", "train", "evaluate")}
    assert policy <= noise and len(noise) == 24 + len(policy)
    assert rerun(graph, "train.cpu", t, "transfer/params.yaml") == policy - {
        f"{t}:generate_transfer_policy@stack_three"
    } | {f"{t}:report_transfer"}
    scaling = rerun(graph, "suite.scaling.max_attempts", "suite/dvc.yaml", "suite/params.yaml")
    assert {s.split(":")[-1].split("@")[0] for s in scaling} == {
        "generate_suite_scaling", "train_suite_scaling", "evaluate_suite_scaling", "report_suite"
    }  # fmt: skip
    assert len(scaling) == 1 + 3 + 3 + 1  # the peg_insertion store, 200/1000/5000 demos
    q = "quickstart/dvc.yaml"
    noise = rerun(graph, "pose_noise.level", q, "quickstart/params.yaml")
    assert {s.split(":")[-1] for s in noise} == {
        "pose_noise", "generate@D0", "coverage@D0", "export@D0", "render@D0", "observe",
        "export_observed", "report",
    }  # fmt: skip
    for pipeline in ("suite/dvc.yaml", "transit/dvc.yaml", t):
        assert rerun(graph, "generate.action_noise", pipeline, "params.yaml") == set()


@pytest.mark.parametrize(
    "key",
    ["generate.workers", "generate.executor", "train.workers", "evaluate.workers",
     "evaluate.executor", "export.workers", "observe.workers", "maniskill.lean_step",
     "ray.address"],
)  # fmt: skip
def test_a_key_that_changes_no_number_re_runs_nothing(graph, key):
    assert rerun(graph, key) == set()


def test_plots_of_one_pipeline_are_shown_by_its_dvc_yaml_target(repo):
    """docs/workflow.md's `dvc plots show '<pipeline>/dvc.yaml::'` draws the plots that
    pipeline declares and none of another's (DVC names each plot after its dvc.yaml)."""
    declared: dict[str, set[str]] = {}
    for plot in repo.index.plots:
        declared.setdefault(str(Path(plot.stage.dvcfile.path).relative_to(REPO)), set()).add(
            str(plot)
        )
    assert {"dvc.yaml", "quickstart/dvc.yaml"} <= set(declared)
    for dvcfile in ("dvc.yaml", "quickstart/dvc.yaml"):
        shown = repo.plots.show(targets=[f"{dvcfile}::"])["workspace"]["sources"]["data"]
        assert set(shown) == declared[dvcfile], dvcfile


def test_only_the_report_summaries_are_declared_metrics(repo):
    """`dvc exp show` and `dvc metrics diff` show every declared metric: each pipeline's
    report stage declares its summary.json and nothing else is one, so that a comparison of
    runs fits a screen. A stage's own metrics file is an uncached output."""
    declared = {
        (Path(o.fs_path).relative_to(REPO).as_posix(), s.addressing.rpartition(":")[2])
        for s in repo.index.stages
        for o in s.outs
        if o.metric
    }
    summaries = {  # a study's pipeline (suite/<study>/dvc.yaml) reports in its suite's report
        (p.parent / "report/summary.json").relative_to(REPO).as_posix()
        for p in PIPELINES
        if p.parent in (REPO, *REPO.glob("*"))
    }
    assert {path for path, _ in declared} == summaries
    assert all(stage.startswith("report") for _, stage in declared), sorted(declared)
    per_stage = [
        o for s in repo.index.stages for o in s.outs if "metrics" in Path(o.def_path).parts
    ]
    assert per_stage and not [str(o) for o in per_stage if o.use_cache or o.metric]


def test_only_the_quickstart_and_the_default_source_stages_track_an_inputs_folder():
    """source.from_file is allowed where the source stage tracks <pipeline>/inputs/."""
    found = {
        f.relative_to(REPO).as_posix(): source_inputs.inputs_folder(f)
        for f in (REPO / "dvc.yaml", *REPO.glob("*/dvc.yaml"))
    }
    assert {f: d.relative_to(REPO).as_posix() for f, d in found.items() if d} == {
        "dvc.yaml": "inputs",
        "quickstart/dvc.yaml": "quickstart/inputs",
    }
    assert all((d / "README.md").is_file() for d in found.values() if d)


PIPELINE_LINES = 250  # a pipeline definition reads on a screen or two
PIPELINES = [
    REPO / "dvc.yaml",
    *sorted(REPO.glob("*/dvc.yaml")),
    *sorted(REPO.glob("*/*/dvc.yaml")),
]


def yaml_shortcuts(text: str) -> list[str]:
    """The anchors, aliases and merge keys of a YAML text, each as 'line N: what'."""
    found = []
    for token in yaml.scan(text):
        if isinstance(token, (yaml.AnchorToken, yaml.AliasToken)):
            kind = "anchor &" if isinstance(token, yaml.AnchorToken) else "alias *"
            found.append(f"line {token.start_mark.line + 1}: {kind}{token.value}")
        elif isinstance(token, yaml.ScalarToken) and token.plain and token.value == "<<":
            found.append(f"line {token.start_mark.line + 1}: merge key <<")
    return found


def test_yaml_shortcuts_finds_anchors_aliases_and_merge_keys_but_not_comments():
    text = "a: &k [x]\nb: *k\nc:\n  <<: {d: 1}\n  e: 2  # <<: *k\n"
    assert yaml_shortcuts(text) == ["line 1: anchor &k", "line 2: alias *k", "line 4: merge key <<"]


@pytest.mark.parametrize("path", PIPELINES, ids=lambda p: p.relative_to(REPO).as_posix())
def test_a_pipeline_has_no_yaml_anchors_aliases_or_merge_keys(path):
    """A merge key silently drops the merged keys a stage also sets (its deps, say), and an
    alias hides what a stage reads: every stage is written out in full."""
    assert yaml_shortcuts(path.read_text()) == [], path.relative_to(REPO).as_posix()


@pytest.mark.parametrize("path", PIPELINES, ids=lambda p: p.relative_to(REPO).as_posix())
def test_a_pipeline_fits_its_line_limit(path):
    lines = len(path.read_text().splitlines())
    assert lines <= PIPELINE_LINES, f"{path.relative_to(REPO)}: {lines} lines"


def stand_in(stage: dict) -> dict:
    """``stage`` (a dvc.yaml stage) with a command that writes its outs instead of running
    the stage: its deps, params and outputs as they are. An out given as a mapping (an
    uncached metrics file) gets a file, any other a folder."""
    files = [next(iter(o)) for o in stage["outs"] if isinstance(o, dict)]
    cmd = [f"mkdir -p {o} && echo x > {o}/x" for o in stage["outs"] if isinstance(o, str)]
    cmd += [f"mkdir -p $(dirname {f}) && echo 1 > {f}" for f in files]
    return stage | {"cmd": " && ".join(cmd)}


def test_editing_a_brought_in_demo_file_makes_dvc_rerun_its_source_stage(tmp_path, monkeypatch):
    """On DVC itself, with the quickstart's and the default pipeline's real source stages
    (a stand-in command): a file of a pipeline's inputs folder, named by source.from_file,
    edited in place (a demo dropped) makes `dvc status` list that pipeline's source stage."""
    work = tmp_path / "repo"
    # the stages' code deps and the check stage's stamps, as committed
    shutil.copytree(REPO / "mimicgen_pipe", work / "mimicgen_pipe",
                    ignore=shutil.ignore_patterns("__pycache__"))  # fmt: skip
    for folder in ("", "quickstart"):
        real = yaml.safe_load((REPO / folder / "dvc.yaml").read_text())
        (work / folder).mkdir(parents=True, exist_ok=True)
        shutil.copy(REPO / folder / "params.checked", work / folder / "params.checked")
        shutil.copytree(REPO / folder / "inputs", work / folder / "inputs")
        (work / folder / "inputs/demo.h5").write_bytes(b"demo 1, demo 2")
        params = (REPO / folder / "params.yaml").read_text()
        from_file = f"{folder}/inputs/demo.h5".lstrip("/")
        (work / folder / "params.yaml").write_text(
            params.replace("from_file: null", f"from_file: {from_file}")
        )
        pipeline = {k: v for k, v in real.items() if k != "stages"}
        pipeline["stages"] = {"source": stand_in(real["stages"]["source"])}
        (work / folder / "dvc.yaml").write_text(yaml.safe_dump(pipeline))
    from dvc.repo import Repo

    monkeypatch.chdir(work)  # DVC reads the targets from the working directory
    monkeypatch.setenv("DVC_SITE_CACHE_DIR", str(tmp_path / "site_cache"))
    subprocess.run(["git", "init", "-q"], check=True)
    Repo.init(str(work)).close()
    with Repo(str(work)) as repo:
        repo.reproduce("dvc.yaml")
        repo.reproduce("quickstart/dvc.yaml")
    with Repo(str(work)) as repo:
        assert repo.status() == {}
    (work / "quickstart/inputs/demo.h5").write_bytes(b"demo 1")
    with Repo(str(work)) as repo:
        assert list(repo.status()) == ["quickstart/dvc.yaml:source"]
    (work / "inputs/demo.h5").write_bytes(b"demo 2")
    with Repo(str(work)) as repo:
        assert sorted(repo.status()) == ["quickstart/dvc.yaml:source", "source"]
