#!/usr/bin/env bash
# Builds .venv-official: the official MimicGen code (NVlabs/mimicgen) on robosuite 1.4.1 and
# MuJoCo 2.3.2, with robomimic at the commit MimicGen's installation docs name, so that
# benchmarks/official_mimicgen.py can time its generate loop beside ours. Optional: nothing
# of the project imports it. Idempotent: a second run with the same pins only checks.
#
#   bash scripts/official_mimicgen_venv.sh
#   MIMICGEN_SRC=/path/to/mimicgen ROBOMIMIC_SRC=/path/to/robomimic bash scripts/official_mimicgen_venv.sh
#
# MIMICGEN_SRC / ROBOMIMIC_SRC: local checkouts (at the commits below) instead of GitHub.
# PYTHON: the interpreter for the venv (default python3.11, else python3).
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=.venv-official
# PyPI's "mimicgen" is an unrelated package of the same name, hence the source.
MIMICGEN_COMMIT=72bd767c255545f462e7ccfb2731f2e5d4c1d9bb  # NVlabs/mimicgen main, 2025-08-16
# the commit docs/introduction/installation.md of MimicGen checks out
ROBOMIMIC_COMMIT=d0b37cf214bd24fb590d182edb6384333f67b661
MIMICGEN_SRC=${MIMICGEN_SRC:-git+https://github.com/NVlabs/mimicgen.git@$MIMICGEN_COMMIT}
ROBOMIMIC_SRC=${ROBOMIMIC_SRC:-git+https://github.com/ARISE-Initiative/robomimic.git@$ROBOMIMIC_COMMIT}

# Resolved with their dependencies, under the numpy pin.
DEPS=(
  "numpy==1.26.4"        # mujoco 2.3.2 is built against NumPy 1.x; it fails to import under 2.x
  "mujoco==2.3.2"        # MimicGen's docs: other versions change the robot dynamics
  "numba==0.60.0"        # robosuite's jitted math; its last release for numpy 1.26 and 2.0
  "scipy==1.13.1"        # robosuite; last release with numpy 1.x wheels for every 3.x here
  "opencv-python-headless==4.10.0.84"  # robosuite.utils imports cv2; headless needs no libGL
  "pillow==10.4.0"       # robosuite's texture loading
  "termcolor==2.4.0"     # robosuite's and robomimic's log colours
  "h5py==3.11.0"         # the source and generated hdf5 datasets; numpy 1.x wheels
  "tqdm==4.66.5"         # progress bars in mimicgen and robomimic
  "imageio==2.35.1"      # imported by robomimic's playback_dataset, which mimicgen imports
  "matplotlib==3.9.2"    # imported by robomimic's vis_utils on the same path; numpy 1.x wheels
  "six==1.16.0"          # mimicgen's config metaclass
  "gdown==5.2.0"         # imported at the top of mimicgen.utils.file_utils
  "huggingface_hub==0.24.6"  # the same (dataset download, never called here)
  "filelock==3.16.1" "typing-extensions==4.12.2" "sympy==1.13.3" "networkx==3.3"
  "jinja2==3.1.4" "fsspec==2024.9.0" "setuptools==75.1.0"  # torch's own imports
)
# --no-deps: their declared dependencies pull what is not needed and does not build here
# (robosuite: pynput -> evdev, a C build; opencv-python with libGL; robomimic: egl_probe, a
# CMake build, and tensorboard), or torch's optional GPU tool chain.
NODEPS=(
  "robosuite==1.4.1"     # MimicGen's docs: v1.4.1; 1.5+ changed the controller conventions
  # robomimic imports torch and torchvision at import (its policy models); torchvision has no
  # CPU build, and its build needs torch as PyPI builds it (with CUDA; it runs on CPU)
  "torch==2.14.1" "torchvision==0.29.1"
  # the CUDA libraries torch 2.14.1 loads at import (from its metadata); triton, cuda-bindings
  # and cuda-toolkit are left out: nothing here compiles or calls CUDA
  "nvidia-cublas==13.1.1.3" "nvidia-cuda-cupti==13.0.85" "nvidia-cuda-nvrtc==13.0.88"
  "nvidia-cuda-runtime==13.0.96" "nvidia-cudnn-cu13==9.24.0.43" "nvidia-cufft==12.0.0.61"
  "nvidia-cufile==1.15.1.6" "nvidia-curand==10.4.0.35" "nvidia-cusolver==12.0.4.66"
  "nvidia-cusparse==12.6.3.3" "nvidia-cusparselt-cu13==0.8.1" "nvidia-nccl-cu13==2.30.7"
  "nvidia-nvjitlink==13.4.92" "nvidia-nvshmem-cu13==3.4.5" "nvidia-nvtx==13.0.85"
)

fail() {
  echo "official_mimicgen_venv: $*" >&2
  exit 1
}

say() { echo "official_mimicgen_venv: $*"; }

pip_quiet() {
  # pip's notes about unused local index locations are noise here.
  "$VENV/bin/pip" -q --disable-pip-version-check "$@" 2>&1 | { grep -v '^WARNING: Location' || true; }
  return "${PIPESTATUS[0]}"
}

# What the pins and sources are now: a venv built from the same is left as it is.
stamp_text() {
  printf '%s\n' "${DEPS[@]}" "${NODEPS[@]}" "$MIMICGEN_SRC" "$ROBOMIMIC_SRC"
  for src in "$MIMICGEN_SRC" "$ROBOMIMIC_SRC"; do
    if [ -d "$src/.git" ]; then git -C "$src" rev-parse HEAD; fi
  done
}
STAMP="$VENV/.official-stamp"

smoke() {
  # Imports what the driver imports, and checks the versions it reports.
  "$VENV/bin/python" - <<'EOF'
import mujoco, robosuite, robomimic, mimicgen  # noqa: F401
from mimicgen.configs import config_factory
from mimicgen.datagen.data_generator import DataGenerator  # noqa: F401
from mimicgen.scripts.prepare_src_dataset import prepare_src_dataset  # noqa: F401
import mimicgen.envs.robosuite.stack  # noqa: F401
assert mujoco.__version__ == "2.3.2", mujoco.__version__
assert robosuite.__version__ == "1.4.1", robosuite.__version__
config_factory("stack", config_type="robosuite")
print(f"robosuite {robosuite.__version__}, mujoco {mujoco.__version__}, mimicgen {mimicgen.__version__}")
EOF
}

for src in "$MIMICGEN_SRC" "$ROBOMIMIC_SRC"; do
  case $src in
    git+*) ;;
    *) [ -f "$src/setup.py" ] || fail "$src is not a source checkout (no setup.py)" ;;
  esac
done

if [ -f "$STAMP" ] && [ "$(stamp_text)" = "$(cat "$STAMP")" ] \
  && versions=$(smoke 2>/dev/null | tail -1); then
  say "$VENV is up to date ($versions)"
  exit 0
fi

py=${PYTHON:-python3.11}
command -v "$py" >/dev/null || py=python3
"$py" -c 'import sys; assert sys.version_info[:2] == (3, 11)' 2>/dev/null \
  || fail "needs Python 3.11 (set PYTHON=/path/to/python3.11); $py is $("$py" --version 2>&1)"

if [ ! -x "$VENV/bin/python" ]; then
  say "creating $VENV with $("$py" --version)"
  "$py" -m venv "$VENV" || fail "could not create $VENV"
fi
rm -f "$STAMP"

say "installing numpy, mujoco and the other dependencies"
pip_quiet install "${DEPS[@]}" || fail "pip could not install the pinned dependencies (see above)"
say "installing robosuite and torch (no dependencies; several GB the first time)"
pip_quiet install --no-deps "${NODEPS[@]}" || fail "pip could not install robosuite/torch (see above)"
say "installing robomimic from $ROBOMIMIC_SRC"
pip_quiet install --no-deps "$ROBOMIMIC_SRC" || fail "pip could not install robomimic from $ROBOMIMIC_SRC"
say "installing mimicgen from $MIMICGEN_SRC"
pip_quiet install --no-deps "$MIMICGEN_SRC" || fail "pip could not install mimicgen from $MIMICGEN_SRC"

say "checking the imports"
versions=$(smoke | tail -1) || fail "$VENV was built but the official code does not import (see above)"
stamp_text >"$STAMP"
say "done: $versions; $(du -sh "$VENV" | cut -f1) at $VENV"
