"""Where MKL (linked into torch) runs on the data path: the quickstart's source, parse,
pose_noise and generate stages, each a `mimicgen-pipe` process as DVC runs it, with every
process they start (the motion planner's and the converter's children too) counting its
torch operations. Two kinds reach MKL: BLAS and LAPACK ones (products, factorisations),
which MKL_VERBOSE logs, and the float unary ones that torch hands to MKL's vector math
library, VML (sin, cos, exp, log, sqrt, atan, acos, asin, tan, tanh, erf, log10, log2,
trunc: the vms*/vmd* symbols in libtorch_cpu.so), which it does not.

    PYTHONPATH=$PWD .venv/bin/python lab/scripts/mkl_calls.py \
        [--params quickstart/params.yaml] [--demos 20] [--out lab/outputs/mkl_calls.json]

Prints, per stage, the MKL routines MKL_VERBOSE logged and each BLAS, LAPACK or VML
operation by dtype, shapes and caller (the first frame outside torch), with its count.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]

# Imported by every Python process started with this PYTHONPATH (the stage and its
# children): pins as mimicgen-pipe does, then counts torch's operations until exit.
SITECUSTOMIZE = """
import os
if os.environ.get("MKL_CALLS_DIR"):
    import atexit, json, sys
    from collections import Counter
    from mimicgen_pipe.run import arithmetic
    arithmetic.pin()
    import torch
    from torch.utils._python_dispatch import TorchDispatchMode

    BLAS_LAPACK = set("mm bmm addmm addmv mv dot vdot baddbmm addbmm addr triangular_solve "
                      "lu_solve geqrf ormqr cholesky cholesky_solve cholesky_inverse inverse det "
                      "logdet slogdet svd pinverse lstsq qr".split())
    VML = set("sin cos exp log sqrt atan acos asin tan tanh erf erfc erfinv log10 log2 "
              "trunc".split())

    def caller():
        f = sys._getframe(2)
        while f is not None and ("/torch/" in f.f_code.co_filename
                                 or f.f_code.co_filename == __file__):
            f = f.f_back
        if f is None:
            return "?"
        path = f.f_code.co_filename.split("site-packages/")[-1].split(os.getcwd() + "/")[-1]
        return f"{path}:{f.f_lineno} {f.f_code.co_name}"

    class Counted(TorchDispatchMode):
        ops = Counter()
        mkl = Counter()

        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            name = func.overloadpacket.__name__.rstrip("_")
            self.ops[name] += 1
            # vector norms are torch's own reductions; products torch may keep to its own
            # loops when small (MKL_VERBOSE says which reached MKL)
            linalg = name.startswith(("linalg", "_linalg")) and "norm" not in name
            kind = ("blas/lapack" if name in BLAS_LAPACK or linalg
                    else "vml" if name in VML else None)
            if kind is not None:
                ts = [a for a in args if isinstance(a, torch.Tensor)]
                dtype = str(ts[0].dtype).removeprefix("torch.") if ts else "?"
                shapes = " x ".join(str(tuple(t.shape)) for t in ts)
                self.mkl[f"{kind} {name} {dtype} {shapes} <- {caller()}"] += 1
            return func(*args, **(kwargs or {}))

    mode = Counted()
    mode.__enter__()

    @atexit.register
    def dump():
        out = os.path.join(os.environ["MKL_CALLS_DIR"], f"{os.getpid()}.json")
        with open(out, "w") as f:
            json.dump({"argv": sys.argv[:3], "ops": sum(mode.ops.values()),
                       "mkl": dict(mode.mkl)}, f)
"""


def _params(src: Path, dst: Path, demos: int) -> None:
    p = yaml.safe_load(src.read_text())
    p["generate"]["num_demos"] = demos
    p["generate"]["workers"] = 1  # in the stage's process: a pool's workers exit without atexit
    p["source"]["from_file"] = None
    dst.write_text(yaml.safe_dump(p))


def _stage(argv: list[str], work: Path, stage: str) -> dict:
    """Run one stage with counting on; its processes' counts merged, and MKL_VERBOSE's."""
    counts, hook = work / stage, work / "hook"
    counts.mkdir()
    verbose = work / f"{stage}.mkl_verbose"
    env = dict(
        os.environ,
        PYTHONPATH=f"{hook}{os.pathsep}{REPO}",
        MKL_CALLS_DIR=str(counts),
        MKL_VERBOSE="1",
        MKL_VERBOSE_OUTPUT_FILE=str(verbose),
    )
    exe = Path(sys.executable).with_name("mimicgen-pipe")
    subprocess.run([str(exe), *argv], env=env, check=True, cwd=REPO)
    processes = [json.loads(f.read_text()) for f in counts.glob("*.json")]
    mkl = Counter()
    for d in processes:
        mkl.update(d["mkl"])
    routines = Counter(
        line.split()[1].split("(")[0]
        for line in (verbose.read_text().splitlines() if verbose.exists() else [])
        if line.startswith("MKL_VERBOSE") and "(" in line.split()[1]
    )
    return {
        "processes": len(processes),
        "torch_operations": sum(d["ops"] for d in processes),
        "mkl_verbose_routines": dict(routines.most_common()),
        "operations_reaching_mkl": dict(mkl.most_common()),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--params", type=Path, default=Path("quickstart/params.yaml"))
    ap.add_argument("--demos", type=int, default=20, help="generated demos (guarantee mode)")
    ap.add_argument("--out", type=Path, default=Path("lab/outputs/mkl_calls.json"))
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="mkl_calls_"))
    (work / "hook").mkdir()
    (work / "hook/sitecustomize.py").write_text(SITECUSTOMIZE)
    params = work / "params.yaml"
    _params(args.params, params, args.demos)
    d = {k: work / f"{k}.zarr" for k in ("source", "parsed", "pose_noise", "generated")}
    stages = {
        "source": ["source", "--out", d["source"], "--metrics", work / "s.json"],
        "parse": ["parse", "--source", d["source"], "--out", d["parsed"]],
        "pose_noise": ["pose_noise", "--parsed", d["parsed"], "--out", d["pose_noise"]],
        "generate": ["generate", "--variant", "D0", "--parsed", d["pose_noise"],
                     "--out", d["generated"], "--metrics", work / "g.json"],
    }  # fmt: skip
    result = {"params": str(args.params), "generated_demos": args.demos, "stages": {}}
    for stage, argv in stages.items():
        argv = [str(a) for a in [argv[0], "--params", params, *argv[1:]]]
        r = result["stages"][stage] = _stage(argv, work, stage)
        print(f"== {stage}: {r['processes']} processes, {r['torch_operations']} torch operations")
        print(f"   MKL_VERBOSE: {r['mkl_verbose_routines'] or 'no BLAS or LAPACK call'}")
        for key, n in r["operations_reaching_mkl"].items():
            print(f"{n:>9}  {key}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
