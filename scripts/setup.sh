#!/usr/bin/env bash
# Set up everything the project needs on a fresh Debian or Ubuntu machine, then exit:
#   - system libraries: EGL with Mesa's drivers (headless rendering, software on a
#     machine without a GPU), libGL/libX11 and libusb/libudev (Open3D), libgomp
#     (scikit-learn), and Python's venv module if the distribution split it off;
#   - a virtual environment in .venv with the project installed (editable), its test
#     tools and its training extra (PyTorch 2.13.0 and onnx, which only training the
#     fingertip heatmap network needs). Where pip finds PyTorch's CPU wheel at hand (a
#     find-links folder, as on our CI machines) it takes that; elsewhere it fetches
#     PyPI's build with its CUDA packages (several GB): to avoid that, first run
#     .venv/bin/pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu
# Running it again is quick: it installs only what is missing or changed.
set -euo pipefail
cd "$(dirname "$0")/.."

system_packages=(libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libx11-6 libusb-1.0-0 libudev1 libgomp1)
python=${PYTHON:-python3}

command -v "$python" >/dev/null || { echo "setup: $python not found; install Python 3.10 or newer" >&2; exit 1; }
"$python" -c 'import sys; sys.exit(sys.version_info < (3, 10))' \
  || { echo "setup: Python 3.10 or newer is needed, $python is $("$python" -V 2>&1)" >&2; exit 1; }
"$python" -c 'import ensurepip, venv' 2>/dev/null || system_packages+=(python3-venv)

missing=()
for package in "${system_packages[@]}"; do
  dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q "install ok installed" || missing+=("$package")
done
if ((${#missing[@]})); then
  if ! command -v apt-get >/dev/null; then
    echo "setup: please install these system libraries: ${missing[*]}" >&2
    exit 1
  fi
  sudo=""
  [ "$(id -u)" -eq 0 ] || sudo="sudo"
  echo "setup: installing ${missing[*]}"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

[ -x .venv/bin/python ] || "$python" -m venv .venv
stamp=.venv/.glove-setup
wanted=$(cat pyproject.toml scripts/setup.sh | sha256sum | cut -c1-16)
if [ "$(cat "$stamp" 2>/dev/null)" != "$wanted" ]; then
  echo "setup: installing the project into .venv"
  .venv/bin/python -m pip install -q --upgrade pip 2>&1 | grep -v "^WARNING: Location" || true
  .venv/bin/python -c "import torch" 2>/dev/null \
    || .venv/bin/python -m pip install -q "torch==2.13.0" 2>&1 | grep -v "^WARNING: Location" || true
  .venv/bin/python -m pip install -q -e ".[dev,train]" 2>&1 | grep -v "^WARNING: Location" || true
  .venv/bin/python -c "import glovedb, builder, tracker, open3d, pyrender, torch, onnx" \
    || { echo "setup: the installed project does not import" >&2; exit 1; }
  echo "$wanted" > "$stamp"
fi
