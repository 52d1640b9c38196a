#!/usr/bin/env bash
# Sets up a fresh machine: the Vulkan driver SAPIEN needs, a virtualenv at .venv
# and the pinned Python dependencies (requirements.txt); for the tests, a second virtualenv at
# .venv-learners with robomimic's and lerobot's trainers, and FFmpeg. Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."

install_vulkan() {
  # SAPIEN creates render materials even for state-only simulation, so it
  # needs a Vulkan ICD. Debian 12's Mesa 22.3 lavapipe lacks
  # VK_KHR_external_semaphore_fd; Mesa 25 from bookworm-backports has it.
  if [ -r /etc/os-release ] && grep -q '^VERSION_CODENAME=bookworm' /etc/os-release; then
    if ! dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null | grep -q '^25'; then
      local sudo=""; [ "$(id -u)" = 0 ] || sudo="sudo"
      local list=/etc/apt/sources.list.d/bookworm-backports.sources
      if [ ! -e "$list" ]; then
        local mirror
        mirror=$(awk '/^URIs:/{print $2; exit}' /etc/apt/sources.list.d/debian.sources 2>/dev/null || true)
        [ -n "$mirror" ] || mirror=http://deb.debian.org/debian
        printf 'Types: deb\nURIs: %s\nSuites: bookworm-backports\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n' \
          "$mirror" | $sudo tee "$list" >/dev/null
      fi
      $sudo apt-get update -qq
      DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq -t bookworm-backports \
        mesa-vulkan-drivers libvulkan1 >/dev/null
    fi
  elif ! ldconfig -p 2>/dev/null | grep -q libvulkan.so.1; then
    echo "setup: no Vulkan loader found. SAPIEN needs a Vulkan driver even without a GPU:" >&2
    echo "  install libvulkan1 and Mesa >= 24.3 lavapipe (mesa-vulkan-drivers), or a GPU driver." >&2
    exit 1
  fi
}

pip_quiet() {
  # pip's notes about unused local index locations are noise here.
  .venv/bin/pip -q --disable-pip-version-check "$@" 2>&1 | { grep -v '^WARNING: Location' || true; }
  return "${PIPESTATUS[0]}"
}

install_venv() {
  local py=${PYTHON:-python3.11}
  command -v "$py" >/dev/null || py=python3
  [ -x .venv/bin/python ] || "$py" -m venv .venv
  # torch first and alone: pinned to the CPU wheel; anything that pulls an
  # unpinned torch later then finds it satisfied instead of fetching CUDA.
  pip_quiet install "torch==2.13.0"
  pip_quiet install -r requirements.txt
  # Test-only: robomimic's own dataset class reads our robomimic export in the tests.
  # 0.3.0 is its last release on PyPI; --no-deps because its dependencies pull a CUDA
  # torchvision (no CPU build here) and egl_probe (a C++ build); the dataset module needs
  # only numpy, h5py, torch, tqdm and termcolor (pinned in requirements.txt).
  pip_quiet install --no-deps "robomimic==0.3.0"
  pip_quiet install --no-deps -e .
}

install_ffmpeg() {
  # torchcodec, lerobot's video decoder in .venv-learners, loads the system's FFmpeg libraries.
  if ldconfig -p 2>/dev/null | grep 'libavdevice\.so\.' >/dev/null; then return; fi
  if command -v apt-get >/dev/null; then
    local sudo=""; [ "$(id -u)" = 0 ] || sudo="sudo"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends \
      ffmpeg >/dev/null
  else
    echo "setup: no FFmpeg libraries found: the LeRobot training test decodes video with them;" >&2
    echo "  install FFmpeg 4-8 with its shared libraries (libavcodec, libavdevice, ...)." >&2
  fi
}

install_learners_venv() {
  # A second venv, for the tests only: robomimic's and lerobot's own trainers train on our
  # exports there. Its packages are exact and installed --no-deps
  # (tests/learners/requirements.txt says why); --isolated so that they come from PyPI itself,
  # not from a local CPU torch wheel that pip's configuration may point at.
  local py=${PYTHON:-python3.11}
  command -v "$py" >/dev/null || py=python3
  [ -x .venv-learners/bin/python ] || "$py" -m venv .venv-learners
  .venv-learners/bin/pip -q --disable-pip-version-check --isolated install --no-deps \
    -r tests/learners/requirements.txt
}

say() { echo "setup: $*"; }
say "1/4 the Vulkan driver SAPIEN needs (Mesa 25 lavapipe on Debian 12)"
install_vulkan
say "2/4 .venv: CPU torch and the pinned packages of requirements.txt (about 2.5 GB)"
install_venv
say "3/4 FFmpeg's libraries (LeRobot's video decoder, for the tests)"
install_ffmpeg
say "4/4 .venv-learners: robomimic's and LeRobot's trainers, for the tests (about 4.7 GB)"
install_learners_venv
say "done: .venv for the pipelines (activate with: . .venv/bin/activate)," \
  ".venv-learners for the tests' outside trainers"
