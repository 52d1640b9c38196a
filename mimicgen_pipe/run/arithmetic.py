"""The numeric libraries' code paths, pinned before they load, so that one CPU type gives
the same bytes run after run and machine after machine.

numpy, the OpenBLAS inside numpy's wheel, torch's own kernels, MKL (whose vector math
library computes torch's float sin, cos, acos, tanh and sqrt; no BLAS call reaches it on the
data path) and oneDNN (torch's LSTM and linear layers) each choose their code path at run
time from the CPU they find. Paths of one library agree to within rounding, not to the bit:
an FMA or an AVX-512 kernel sums in another order or rounds once instead of twice, and a
vector math kernel rounds another last bit. Left to choose, a source
demo's 4x4 pose products (numpy -> OpenBLAS dgemm) and every training step come out with
other last bits on another CPU type, and so does every hash downstream in ``dvc.lock``.

:func:`pin` sets each library's own switch to the AVX2/FMA path (x86-64-v3, which every
x86-64 server CPU since 2013-2015 has). It must run before numpy or torch is imported:
``mimicgen-pipe`` calls it first, and child processes (workers, the motion planner, Ray's
local workers) inherit the environment it sets. Measured: an AMD Zen 3 (the committed locks'
type) gives the same bytes with and without it; an Intel Xeon with AVX-512 gives other bytes
than Zen 3 with it, through MKL's vector math, whose ``MKL_CBWR`` branches are Intel's only
(on another vendor's CPU MKL runs its own choice), so the pins do not carry bytes across
vendors.
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

# each switch is read once, when its library loads
PINNED = {
    # numpy's OpenBLAS picks its kernels by core type (DYNAMIC_ARCH): FMA-less ones
    # (Sandybridge, Prescott) and AVX-512 ones give a source demo other last bits; Haswell's
    # are the AVX2/FMA kernels, the ones OpenBLAS runs on AMD Zen 1-3 too
    "OPENBLAS_CORETYPE": "Haswell",
    # MKL's conditional numerical reproducibility: the AVX2 code path on an Intel CPU that has
    # it (on other vendors' CPUs MKL ignores it and runs its own choice)
    "MKL_CBWR": "AVX2",
    # torch's vectorised kernels (Sleef transcendentals, reductions): avx512 ones differ
    "ATEN_CPU_CAPABILITY": "avx2",
    # oneDNN's JIT kernels: at most AVX2 instructions
    "ONEDNN_MAX_CPU_ISA": "AVX2",
}
# numpy's AVX-512 kernels (SVML's float64 transcendentals, AVX512F exp/log); merged into
# whatever a user disables: the pipeline's outputs came out the same with every numpy SIMD
# feature off as with AVX2 (its float32 sin/exp/log and float64 tanh do differ)
NUMPY_DISABLED = (
    "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL"
).split()
REQUIRED_FLAGS = ("avx2", "fma")


def cpu_flags(cpuinfo: Path = Path("/proc/cpuinfo")) -> set[str] | None:
    """The first CPU's feature flags from ``cpuinfo``, None where it cannot be read."""
    try:
        text = cpuinfo.read_text()
    except OSError:
        return None
    for line in text.splitlines():
        if line.startswith("flags"):
            return set(line.partition(":")[2].split())
    return None


def pinned_environment(environ: dict[str, str] | None = None) -> dict[str, str]:
    """The variables :func:`pin` sets, given the current ``environ`` (os.environ)."""
    environ = os.environ if environ is None else environ
    numpy_off = environ.get("NPY_DISABLE_CPU_FEATURES", "").replace(",", " ").split()
    merged = numpy_off + [f for f in NUMPY_DISABLED if f not in numpy_off]
    return PINNED | {"NPY_DISABLE_CPU_FEATURES": " ".join(merged)}


def switches() -> dict[str, str]:
    """The switches as this process has them set (to hand to processes that do not inherit
    this environment, such as a Ray cluster's workers)."""
    names = [*PINNED, "NPY_DISABLE_CPU_FEATURES"]
    return {k: os.environ[k] for k in names if k in os.environ}


def why_not_pinnable(cpuinfo: Path = Path("/proc/cpuinfo")) -> str | None:
    """None where the pinned paths can run here, else one line saying why not: not x86-64,
    or a CPU without AVX2 and FMA (``cpuinfo``'s flags; unread, it is taken to have them)."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return f"arithmetic not pinned on {platform.machine()}: the pins are for x86-64 CPUs"
    flags = cpu_flags(cpuinfo)
    missing = [f for f in REQUIRED_FLAGS if flags is not None and f not in flags]
    if missing:
        return (
            f"arithmetic not pinned: this CPU lacks {', '.join(missing)}; outputs will differ "
            "from dvc.lock in their last bits"
        )
    return None


def pin(cpuinfo: Path = Path("/proc/cpuinfo")) -> str | None:
    """Pin the libraries' code paths in ``os.environ`` for this process and its children.
    Returns None when pinned, else :func:`why_not_pinnable`'s line, and sets nothing: the
    run goes on with the CPU's own paths."""
    why = why_not_pinnable(cpuinfo)
    if why is None:
        os.environ.update(pinned_environment())
    return why
