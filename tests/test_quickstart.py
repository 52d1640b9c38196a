"""The README's five-minute command, run as a newcomer runs it: `dvc repro
quickstart/dvc.yaml` in a copy of the repository, giving a generated dataset, its DGR, its
robomimic, LeRobot and ManiSkill exports, one episode's camera images and their exports, and
a report, with the numbers committed in quickstart/metrics/; then the README's robomimic and
LeRobot commands, as written, train on those exports offline."""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from mimicgen_pipe.report.fmt import wilson_interval
from tests.test_cross_cpu import locked_outs, made_the_locks
from tests.test_docs import FENCE
from tests.test_output_safety import tree_digest

REPO = Path(__file__).resolve().parents[1]
LEARNERS = REPO / ".venv-learners"
needs_learners = pytest.mark.skipif(
    not (LEARNERS / "bin/python").exists(),
    reason="the learners' venv .venv-learners is missing (made by scripts/setup.sh)",
)
# the README's trainer commands made short for a test, by their own run-length flags
SHORT = {"robomimic": "--num_epochs 1 --epoch_every_n_steps 2", "lerobot": "--steps=1"}


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
    for sub in ("metrics", "timings", "plots", "report", "dvc.lock"):  # made by the run itself
        path = dest / "quickstart" / sub
        shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
    subprocess.run(["git", "init", "-q"], cwd=dest, check=True)
    return dest


@pytest.fixture(scope="module")
def quickstart(tmp_path_factory) -> tuple[Path, dict[str, str]]:
    """`dvc repro quickstart/dvc.yaml` run in a copy of the repository: the copy and the
    environment it ran in."""
    work = repository_copy(tmp_path_factory.mktemp("quickstart"))
    env = dict(os.environ, PYTHONPATH=str(work), PYTHONWARNINGS="ignore")
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env['PATH']}"
    res = subprocess.run(
        ["dvc", "repro", "quickstart/dvc.yaml"], cwd=work, env=env, capture_output=True, text=True
    )
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    return work, env


@pytest.mark.sim
@pytest.mark.slow
def test_the_quickstart_pipeline_gives_data_an_export_and_a_report(quickstart, tmp_path):
    work, env = quickstart
    q = work / "quickstart"
    ran = json.loads((q / "metrics/generate_stack_cube_D0.json").read_text())
    committed = json.loads((REPO / "quickstart/metrics/generate_stack_cube_D0.json").read_text())
    # on the CPU type that made the lock (mimicgen_pipe.run.arithmetic), the committed run bit for
    # bit: the same run id (a digest of the parsed store's bytes) and every store and export
    # with the md5 the committed lock holds; elsewhere MKL gives other last bits, and the
    # committed DGR holds within seed noise
    if made_the_locks():
        for key in ("attempts", "successes", "dgr", "run_id"):
            assert ran[key] == committed[key], key
        # but the videos: the renderer draws on the CPU outside the pinned arithmetic
        ran_outs, committed_outs = (
            locked_outs(q / "dvc.lock"),
            locked_outs(REPO / "quickstart/dvc.lock"),
        )
        for outs in (ran_outs, committed_outs):
            assert outs.pop("quickstart/media/stack_cube_D0")  # the render stage ran and was locked
        assert ran_outs == committed_outs
    assert same_rate_within_noise(ran["dgr"], ran["attempts"], committed["dgr"]), (ran, committed)
    assert ran["successes"] == committed["successes"]
    # bit for bit on this machine: the same run on one worker gives the same stores and id
    one = work / "one.yaml"
    one.write_text((q / "params.yaml").read_text().replace("workers: 2", "workers: 1"))
    again = tmp_path / "again/stack_cube_D0.zarr"
    cmd = ["mimicgen-pipe", "generate", "--params", str(one), "--variant", "D0",
           "--parsed", "quickstart/data/pose_noise/stack_cube.zarr", "--out", str(again),
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
    # one kept and one failed episode, shown in the report
    report = (q / "report/report.md").read_text()
    for name in ("kept_0", "failed_0"):
        assert (q / f"media/stack_cube_D0/{name}.mp4").stat().st_size > 0
        assert f"../media/stack_cube_D0/{name}.gif" in report

    import h5py

    export = q / "data/export/stack_cube_D0"
    with h5py.File(export / "demos.hdf5") as f:
        assert len(f["data"]) == ran["successes"] == 20
    info = json.loads((export / "lerobot/meta/info.json").read_text())
    assert info["total_episodes"] == 20
    with h5py.File(export / "trajectory.h5") as f:
        assert len(f) == 20
    # one episode's camera images, exported with them
    observed = json.loads((q / "metrics/observe_stack_cube_D0.json").read_text())
    assert observed["episodes"] == 1 and observed["frames"] > 0
    with h5py.File(q / "data/export/stack_cube_D0_observed/demos.hdf5") as f:
        assert list(f["data"]) == ["demo_0"]
        images = f["data/demo_0/obs/agentview_image"]
        assert images.shape == (observed["frames"], 84, 84, 3) and images[0].std() > 0
    check_a_typo_loses_nothing(work, env)
    check_experiments_and_compare(work, env)


def check_a_typo_loses_nothing(work: Path, env: dict[str, str]) -> None:
    """A typo in the quickstart's params, then `dvc repro`: the pipeline's first stage refuses
    it in one line before DVC removes any stage's outputs, so every store, export and
    tracked metrics file is as the run left it."""
    q = work / "quickstart"
    params = q / "params.yaml"
    before = {p: tree_digest(p) for p in (q / "data", q / "metrics")}
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


def readme_experiment() -> tuple[str, list[str]]:
    """README.md's experiment on the quickstart: its name and its ``-S`` settings."""
    for block in FENCE.finditer((REPO / "README.md").read_text()):
        for line in block.group(0).splitlines():
            if line.startswith("dvc exp run quickstart/dvc.yaml"):
                words = shlex.split(line.partition("#")[0])
                sets = [words[i + 1] for i, w in enumerate(words) if w == "-S"]
                return argument(line, "-n"), sets
    raise AssertionError("README.md: no `dvc exp run quickstart/dvc.yaml` command")


def check_experiments_and_compare(work: Path, env: dict[str, str]) -> None:
    """Two real experiments on the quickstart after its run, each `dvc exp run
    quickstart/dvc.yaml -S quickstart/params.yaml:<key>=<value>`: each edits the quickstart's
    own params file and re-runs exactly the stages downstream of the key; `mimicgen-pipe
    compare` then shows both beside the commit, within 120 columns. The first is the one
    README.md documents, pose-estimation noise L2, whose DGR leaves the base run's 95%
    interval."""

    def run(*args: str) -> str:
        res = subprocess.run(args, cwd=work, env=env, capture_output=True, text=True)
        assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
        return res.stdout + res.stderr

    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t"]
    run(*git, "add", "-A")
    run(*git, "commit", "-qm", "base")
    root_params = (work / "params.yaml").read_text()
    q = "quickstart/params.yaml"
    name, sets = readme_experiment()
    assert sets == [f"{q}:pose_noise.level=L2"], sets
    metrics = work / "quickstart/metrics/generate_stack_cube_D0.json"
    base = json.loads(metrics.read_text())
    out = run("dvc", "exp", "run", "quickstart/dvc.yaml", "-n", name, "-S", sets[0])
    downstream = {"check", "pose_noise", "generate@D0", "coverage@D0", "export@D0",
                  "render@D0", "observe", "export_observed", "report"}  # fmt: skip
    assert ran_stages(out) == downstream
    assert "level: L2" in (work / q).read_text()
    assert (work / "params.yaml").read_text() == root_params  # not the root's file
    low, high = wilson_interval(base["successes"], base["attempts"])
    noisy = json.loads(metrics.read_text())
    assert not low <= noisy["dgr"] <= high, (base, noisy)
    run("git", "checkout", "--", q)
    out = run("dvc", "exp", "run", "quickstart/dvc.yaml", "-n", "bins4",
              "-S", f"{q}:coverage.bins=4")  # fmt: skip
    # from the workspace the first left: generate runs back to the committed store
    assert {"check", "coverage@D0", "report"} <= ran_stages(out) <= downstream
    shown = run("mimicgen-pipe", "compare", "--pipeline", "quickstart", "--width", "120")
    lines = shown.splitlines()
    head = lines[0].split()
    assert head[-1] == "workspace" and {name, "bins4"} <= set(head[1:-1])
    assert head[0] not in (name, "bins4")  # the commit comes first
    assert max(map(len, lines)) <= 120
    rows = {line.split()[0]: line.split()[1:] for line in lines[1:] if line.strip()}
    level = rows["pose_noise.level"]
    assert level[head.index(name)] == "L2" and level[0] == "none"
    assert rows["coverage.bins"][head.index("bins4")] == "4"
    assert "dgr_D0" in rows and "coverage_D0" in rows


def quickstart_export() -> str:
    """The quickstart's export folder (of its first variant), as its dvc.yaml names it."""
    stage = yaml.safe_load((REPO / "quickstart/dvc.yaml").read_text())["stages"]["export"]
    params = yaml.safe_load((REPO / "quickstart/params.yaml").read_text())
    out = stage["outs"][0].replace("${task}", params["task"])
    return out.replace("${item.variant}", params["generate"]["variants"][0])


def readme_trainer_commands(readme: Path = REPO / "README.md") -> dict[str, str]:
    """README.md's commands of the learners' venv, by framework (robomimic, lerobot): each
    line of its code blocks that runs ``.venv-learners/bin/``, continued lines joined."""
    found: dict[str, str] = {}
    for block in FENCE.finditer(readme.read_text()):
        for line in block.group(0).replace("\\\n", " ").splitlines()[1:-1]:
            if ".venv-learners/bin/" in line:
                name = "lerobot" if "lerobot" in line else "robomimic"
                assert name not in found, f"README.md: a second {name} command: {line}"
                found[name] = " ".join(line.split())
    return found


def argument(command: str, flag: str) -> str:
    """The value of ``flag`` in a shell command (``--flag value`` or ``--flag=value``)."""
    words = shlex.split(command)
    for i, word in enumerate(words):
        if word == flag:
            return words[i + 1]
        if word.startswith(flag + "="):
            return word.partition("=")[2]
    raise AssertionError(f"{flag} not in {command}")


def run_readme_command(
    name: str, cwd: Path, home: Path, extra: str = ""
) -> subprocess.CompletedProcess:
    """README.md's ``name`` command run by bash in ``cwd``, as written plus ``extra``, with
    ``home`` as $HOME and none of the Hugging Face variables of this process."""
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("PYTHONPATH", "VIRTUAL_ENV", "XDG_CACHE_HOME") and not k.startswith("HF_")
    }
    env |= {"HOME": str(home), "MPLCONFIGDIR": str(home / "mpl")}  # fmt: skip
    return subprocess.run(
        ["bash", "-c", f"{readme_trainer_commands()[name]} {extra}"],
        cwd=cwd, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=1800,
    )  # fmt: skip


def test_the_readme_trainer_commands_name_the_quickstarts_exports():
    """README.md's robomimic and LeRobot commands read what the quickstart writes (its
    export folder as quickstart/dvc.yaml names it, in formats quickstart/params.yaml asks
    for), LeRobot's offline and with act.json's settings."""
    commands = readme_trainer_commands()
    assert set(commands) == {"robomimic", "lerobot"}, commands
    export = quickstart_export()
    formats = yaml.safe_load((REPO / "quickstart/params.yaml").read_text())["export"]["formats"]
    assert {"robomimic", "lerobot", "maniskill"} <= set(formats)
    robomimic = commands["robomimic"]
    assert "_robomimic_train.py" in robomimic  # robomimic's train.py exits 0 on a failure
    assert argument(robomimic, "--dataset") == f"{export}/demos.hdf5"
    assert (REPO / argument(robomimic, "--config")).is_file()
    lerobot = commands["lerobot"]
    assert lerobot.startswith("HF_HUB_OFFLINE=1 "), lerobot
    config = json.loads((REPO / argument(lerobot, "--config_path")).read_text())
    assert config["dataset"]["root"] == f"{export}/lerobot"
    act = json.loads((REPO / "configs/lerobot/act.json").read_text())
    assert {k: v for k, v in config.items() if k not in ("dataset", "job_name")} == {
        k: v for k, v in act.items() if k not in ("dataset", "job_name")
    }


@needs_learners
def test_the_readme_robomimic_command_fails_without_its_dataset(tmp_path):
    """README.md's robomimic command where the quickstart has not run: one line naming the
    dataset, a non-zero exit, and no run folder made."""
    for name in (".venv-learners", "configs", "mimicgen_pipe"):
        (tmp_path / name).symlink_to(REPO / name)
    home = tmp_path / "home"
    res = run_readme_command("robomimic", tmp_path, home)
    assert res.returncode != 0, res.stdout[-3000:]
    assert f"{quickstart_export()}/demos.hdf5: no such file" in res.stderr, res.stderr[-3000:]
    assert not (home / "robomimic_trained_models").exists()


@needs_learners
@pytest.mark.slow
def test_the_readme_lerobot_command_fails_without_its_dataset(tmp_path):
    """README.md's LeRobot command where the quickstart has not run: a non-zero exit,
    offline, and no checkpoint."""
    for name in (".venv-learners", "configs"):
        (tmp_path / name).symlink_to(REPO / name)
    res = run_readme_command("lerobot", tmp_path, tmp_path / "home", SHORT["lerobot"])
    assert res.returncode != 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert not list(tmp_path.glob("outputs/train/*/*/checkpoints"))


def check_the_readme_trainers(work: Path, home: Path) -> None:
    """README.md's robomimic and LeRobot commands, as written but for a shorter run, in
    ``work`` after the quickstart: each exits 0 and writes a checkpoint."""
    (work / ".venv-learners").symlink_to(LEARNERS)
    res = run_readme_command("robomimic", work, home, SHORT["robomimic"])
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert list(home.glob("robomimic_trained_models/*/*/models/model_epoch_1.pth")), res.stdout[
        -3000:
    ]
    res = run_readme_command("lerobot", work, home, SHORT["lerobot"])
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    saved = "outputs/train/*/*_act_stack_cube_D0/checkpoints/*/pretrained_model/model.safetensors"
    assert list(work.glob(saved)), res.stderr[-3000:]


@needs_learners
@pytest.mark.sim
@pytest.mark.slow
def test_the_readme_trainers_train_on_the_quickstarts_exports(quickstart, tmp_path):
    """README.md's trainer commands on the quickstart's exports. After the pipeline's test
    in this file: its experiments commit the workspace, which must not hold their outputs."""
    work, _ = quickstart
    try:
        check_the_readme_trainers(work, tmp_path / "home")
    finally:
        shutil.rmtree(work / "outputs", ignore_errors=True)  # hundreds of MB of ACT
