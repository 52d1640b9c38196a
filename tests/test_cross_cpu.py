"""The pinned arithmetic (mimicgen_pipe.run.arithmetic): the numeric libraries run the pinned
code paths in every process the CLI starts, the quickstart's chain gives the same bytes with
another CPU type's switches set, and on the CPU type that made the committed locks, the
bytes in quickstart/dvc.lock."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from mimicgen_pipe.run import arithmetic
from tests.conftest import REPO, cli

# Another machine type, emulated: numpy without any of its dispatched SIMD paths (as on a
# CPU that has none of them), and the other libraries' switches as a machine's own
# environment may set them (this workplace sets OPENBLAS_CORETYPE on some processors).
# Each of these alone gives a source store or a policy other last bits when nothing is pinned.
OTHER_CPU = {
    "NPY_DISABLE_CPU_FEATURES": "SSSE3 SSE41 POPCNT SSE42 AVX F16C FMA3 AVX2 "
    + " ".join(arithmetic.NUMPY_DISABLED),
    "OPENBLAS_CORETYPE": "Sandybridge",
    "ATEN_CPU_CAPABILITY": "default",
    "MKL_CBWR": "COMPATIBLE",
    "ONEDNN_MAX_CPU_ISA": "SSE41",
}
PROBE = """
import json
import mimicgen_pipe.cli  # pins, as `mimicgen-pipe` does
import numpy, threadpoolctl, torch
from numpy.core._multiarray_umath import __cpu_features__ as npy
info = threadpoolctl.threadpool_info()
blas = [i["architecture"] for i in info if i["internal_api"] == "openblas"]
print(json.dumps({"openblas": blas, "aten": torch.backends.cpu.get_cpu_capability(),
                  "numpy_avx512f": npy["AVX512F"], "numpy_sse2": npy["SSE2"]}))
"""
pinnable = pytest.mark.skipif(
    arithmetic.why_not_pinnable() is not None, reason="this CPU lacks the pinned paths (AVX2, FMA)"
)


def dvc_dir_md5(root: Path) -> str:
    """The md5 DVC records in dvc.lock for a directory output (``<md5>.dir``)."""
    files = sorted(p for p in root.rglob("*") if p.is_file())
    entries = [
        {"md5": hashlib.md5(p.read_bytes()).hexdigest(), "relpath": p.relative_to(root).as_posix()}
        for p in files
    ]
    return hashlib.md5(json.dumps(entries, sort_keys=True).encode()).hexdigest() + ".dir"


def locked_outs(lock: Path) -> dict[str, str]:
    """Output path -> md5 of every directory output recorded in a dvc.lock."""
    stages = yaml.safe_load(lock.read_text())["stages"]
    return {
        o["path"]: o["md5"] for s in stages.values() for o in s.get("outs", []) if "nfiles" in o
    }


def test_pins_merge_numpy_features_and_set_each_library_switch():
    env = arithmetic.pinned_environment({"NPY_DISABLE_CPU_FEATURES": "AVX2,FMA3 AVX512F"})
    features = env["NPY_DISABLE_CPU_FEATURES"].split()
    assert features[:2] == ["AVX2", "FMA3"]  # a user's own choice is kept
    assert sorted(set(features) - {"AVX2", "FMA3"}) == sorted(arithmetic.NUMPY_DISABLED)
    assert len(features) == len(set(features))
    assert {k: env[k] for k in arithmetic.PINNED} == arithmetic.PINNED


def test_a_cpu_without_avx2_is_not_pinned_and_says_so(tmp_path, monkeypatch):
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nflags\t\t: fpu sse sse2 avx\n")
    assert arithmetic.cpu_flags(info) == {"fpu", "sse", "sse2", "avx"}
    assert arithmetic.cpu_flags(tmp_path / "absent") is None
    monkeypatch.setattr(os, "environ", {})
    why = arithmetic.pin(info)
    assert why is not None and "avx2, fma" in why and "dvc.lock" in why
    assert os.environ == {}  # nothing half-pinned


@pinnable
def test_the_cli_runs_the_pinned_paths_whatever_the_machine_sets():
    env = dict(os.environ, **OTHER_CPU, PYTHONPATH=str(REPO))
    res = subprocess.run(
        [sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True
    )
    seen = json.loads(res.stdout)
    assert seen["openblas"] == ["Haswell"]  # not the Sandybridge kernels the machine asked for
    assert seen["aten"] == "AVX2"
    assert seen["numpy_avx512f"] is False and seen["numpy_sse2"] is True


# a few training steps of a small BC-RNN on the 20 generated demos
TRAIN = {
    "num_demos": 20,
    "cpu": {"hidden": 32, "epochs": 2, "steps_per_epoch": 10, "checkpoint_every": 1,
            "seeds": [0], "threads": 1, "device": "cpu"},
}  # fmt: skip


def run_chain(work: Path, env: dict[str, str] | None) -> dict[str, str]:
    """The quickstart's source -> parse -> pose_noise -> generate D0 as its dvc.yaml runs
    them, then a few training steps on the generated store; the md5 of each output
    directory."""
    work.mkdir()
    params = work / "params.yaml"
    doc = yaml.safe_load((REPO / "quickstart/params.yaml").read_text())
    doc["train"] = doc.get("train", {}) | TRAIN
    params.write_text(yaml.safe_dump(doc))
    q = "quickstart/data"
    out = {
        f"{q}/source/stack_cube.zarr": ["source"],
        f"{q}/parsed/stack_cube.zarr": ["parse", "--source", f"{q}/source/stack_cube.zarr"],
        f"{q}/pose_noise/stack_cube.zarr": [
            "pose_noise", "--parsed", f"{q}/parsed/stack_cube.zarr",
        ],
        f"{q}/generated/stack_cube_D0.zarr": [
            "generate", "--variant", "D0", "--parsed", f"{q}/pose_noise/stack_cube.zarr",
        ],
        "policies": ["train", "--data", "D0", "--store", f"{q}/generated/stack_cube_D0.zarr"],
    }  # fmt: skip
    for path, args in out.items():
        stage = args[0]
        extra = {"train": ["--plot", "train.csv"]}.get(stage, [])
        if stage not in ("parse", "pose_noise"):  # they write no metrics
            extra += ["--metrics", f"{stage}.json"]
        cli(*args, "--params", str(params), "--out", path, *extra, cwd=work, env=env)
    return {path: dvc_dir_md5(work / path) for path in out}


def made_the_locks(cpuinfo: Path = Path("/proc/cpuinfo")) -> bool:
    """Whether this CPU is of the type the committed locks were made on: an AMD with AVX2 and
    FMA (EPYC Zen 3 made them; a Zen 4 and a Zen 5 with AVX-512 rebuilt their stores). MKL's
    vector math, under torch's sqrt, acos and tanh, runs other kernels on an Intel CPU,
    which no switch it has makes an AMD's (docs/workflow.md)."""
    try:
        text = cpuinfo.read_text()
    except OSError:
        return False
    vendor = next((ln.partition(":")[2].strip() for ln in text.splitlines()
                   if ln.startswith("vendor_id")), None)  # fmt: skip
    return vendor == "AuthenticAMD" and {"avx2", "fma"} <= (arithmetic.cpu_flags(cpuinfo) or set())


@pytest.fixture(scope="module")
def chains(tmp_path_factory) -> tuple[dict[str, str], dict[str, str]]:
    """The quickstart chain's output md5s as this machine runs it, and with another CPU
    type's switches set."""
    work = tmp_path_factory.mktemp("chains")
    return run_chain(work / "as_is", None), run_chain(work / "other_cpu", OTHER_CPU)


@pinnable
@pytest.mark.sim
@pytest.mark.slow
def test_the_quickstart_chain_gives_the_same_bytes_on_an_emulated_other_cpu(chains):
    here, other = chains
    assert other == here


@pinnable
@pytest.mark.sim
@pytest.mark.slow
@pytest.mark.skipif(
    not made_the_locks(), reason="the committed locks are an AMD's bytes (MKL differs here)"
)
def test_the_quickstart_chain_gives_the_locked_bytes(chains):
    here, _ = chains
    locked = locked_outs(REPO / "quickstart/dvc.lock")
    for path, md5 in here.items():
        if path.startswith("quickstart/"):
            assert md5 == locked[path], path


def test_the_lock_type_is_an_amd_with_avx2_and_fma(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text("vendor_id\t: AuthenticAMD\nflags\t\t: fpu avx2 fma\n")
    assert made_the_locks(info)
    info.write_text("vendor_id\t: AuthenticAMD\nflags\t\t: fpu avx2 fma avx512f\n")
    assert made_the_locks(info)
    info.write_text("vendor_id\t: AuthenticAMD\nflags\t\t: fpu avx\n")
    assert not made_the_locks(info)
    info.write_text("vendor_id\t: GenuineIntel\nflags\t\t: fpu avx2 fma\n")
    assert not made_the_locks(info)
    assert not made_the_locks(tmp_path / "absent")
