"""The quickstart's source store under other MKL code paths on this machine: MKL's CPU
detection (`mkl_serv_cpu_detect`, `mkl_serv_intel_cpu`, which libtorch_cpu.so calls through
its PLT) answered by a small preloaded library, so that MKL takes the path it would take on
another vendor's CPU; and, for comparison, with one of the CLI's pins lifted.

    PYTHONPATH=$PWD .venv/bin/python lab/scripts/mkl_branch.py [--variants NAME ...] [--vml]

Needs gcc (the preloaded library is built in a temporary folder). Prints, per variant, the
md5 DVC records for the store (``<md5>.dir``), beside quickstart/dvc.lock's. With ``--vml``,
instead, per shim variant and float32 operation of the data path (1,000,000 values in
[-1, 1), their absolute value for sqrt), how many results differ from the correctly rounded
one (float64 numpy, rounded once to float32).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
from tests.test_cross_cpu import dvc_dir_md5  # noqa: E402

# MKL's CPU detection, answered from the environment (defaults: what an AMD CPU answers)
SHIM = r"""
#include <stdlib.h>
static int val(const char *n, int d) { const char *s = getenv(n); return s ? atoi(s) : d; }
int mkl_serv_cpu_detect(void) { return val("SHIM_CPU_TYPE", 0); }
int mkl_serv_get_cpu_type(void) { return val("SHIM_CPU_TYPE", 0); }
int mkl_serv_intel_cpu_true(void) { return val("SHIM_INTEL", 0); }
int mkl_serv_intel_cpu(void) { return val("SHIM_INTEL", 0); }
"""
# name -> (environment with the shim, or None; statement run before the CLI pins)
VARIANTS = {
    "pinned": (None, ""),
    "shim_as_amd": ({"SHIM_INTEL": "0", "SHIM_CPU_TYPE": "0"}, ""),
    "shim_intel_t5": ({"SHIM_INTEL": "1", "SHIM_CPU_TYPE": "5"}, ""),
    "shim_intel_t6": ({"SHIM_INTEL": "1", "SHIM_CPU_TYPE": "6"}, ""),
    "shim_intel_t7": ({"SHIM_INTEL": "1", "SHIM_CPU_TYPE": "7"}, ""),
    "unpinned": (None, "arithmetic.PINNED.clear(); arithmetic.NUMPY_DISABLED = ()"),
    "aten_avx512": (None, "arithmetic.PINNED['ATEN_CPU_CAPABILITY'] = 'avx512'"),
    "openblas_native": (None, "del arithmetic.PINNED['OPENBLAS_CORETYPE']"),
    "numpy_avx512": (None, "arithmetic.NUMPY_DISABLED = ()"),
}
VML = """
from mimicgen_pipe.run import arithmetic
arithmetic.pin()
import numpy as np, torch
x = torch.rand(1_000_000, generator=torch.Generator().manual_seed(0)) * 2 - 1
for op, exact in (("sin", np.sin), ("cos", np.cos), ("acos", np.arccos), ("tanh", np.tanh),
                  ("sqrt", np.sqrt)):
    xi = x.abs() if op == "sqrt" else x
    y = getattr(torch, op)(xi).numpy().view(np.int32).astype(np.int64)
    r = exact(xi.numpy().astype(np.float64)).astype(np.float32).view(np.int32).astype(np.int64)
    print(f"  {op}: {np.count_nonzero(y != r)} of {y.size} off by up to {abs(y - r).max()} ulp")
"""
STAGE = """
import sys
from mimicgen_pipe.run import arithmetic
{edit}
from mimicgen_pipe import cli
sys.exit(cli.main(sys.argv[1:]))
"""


def _env(variant: str, shim: Path) -> dict[str, str]:
    """The environment of ``variant``'s process: the shim preloaded where it has one."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    answers = VARIANTS[variant][0]
    return env if answers is None else env | answers | {"LD_PRELOAD": str(shim)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--vml", action="store_true", help="the operations alone, per shim variant")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="mkl_branch_"))
    (work / "shim.c").write_text(SHIM)
    shim = work / "libshim.so"
    subprocess.run(["gcc", "-O2", "-shared", "-fPIC", "-o", shim, work / "shim.c"], check=True)
    if args.vml:
        for name in args.variants:
            print(name, flush=True)
            subprocess.run([sys.executable, "-c", VML], env=_env(name, shim), cwd=REPO, check=True)
        return
    lock = yaml.safe_load((REPO / "quickstart/dvc.lock").read_text())["stages"]["source"]
    print(f"quickstart/dvc.lock: {lock['outs'][0]['md5']}")
    for name in args.variants:
        out = work / name
        cmd = [sys.executable, "-c", STAGE.format(edit=VARIANTS[name][1]), "source",
               "--params", "quickstart/params.yaml", "--out", out / "source.zarr",
               "--metrics", out / "source.json"]  # fmt: skip
        subprocess.run([str(c) for c in cmd], env=_env(name, shim), cwd=REPO, check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
        print(f"{name}: {dvc_dir_md5(out / 'source.zarr')}", flush=True)


if __name__ == "__main__":
    main()
