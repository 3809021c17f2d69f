#!/usr/bin/env bash
# Set up everything the project needs on a fresh Debian or Ubuntu machine, then exit:
#   - system libraries: EGL with Mesa's drivers (headless rendering, software on a
#     machine without a GPU), libGL/libX11 and libusb/libudev (Open3D), libgomp
#     (scikit-learn), and Python's venv module if the distribution split it off;
#   - a virtual environment in .venv with the project installed (editable) and its test
#     tools: everything that building, tracking, detection and evaluation need.
# Options add the project's extras:
#   --train   PyTorch and onnx, to train the fingertip heatmap network (PyTorch's CPU
#             build on a machine without an NVIDIA GPU; the CUDA build, several GB, with one)
#   --view    rerun, for glove track --view / --rrd
#   --ray     Ray, for glove build --ray
# Running it again is quick: it installs only what is missing or changed.
set -euo pipefail
cd "$(dirname "$0")/.."

extras=dev
for option in "$@"; do
  case "$option" in
    --train) extras+=",train" ;;
    --view) extras+=",view" ;;
    --ray) extras+=",ray" ;;
    -h | --help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
    *) echo "setup: unknown option $option (expected --train, --view or --ray)" >&2; exit 2 ;;
  esac
done

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
wanted=$( (cat pyproject.toml scripts/setup.sh; echo "$extras") | sha256sum | cut -c1-16)
if [ "$(cat "$stamp" 2>/dev/null)" != "$wanted" ]; then
  echo "setup: installing the project into .venv (extras: $extras)"
  pip() { .venv/bin/python -m pip "$@" 2>&1 | grep -v "^WARNING: Location" || true; }
  pip install -q --upgrade pip
  if [[ $extras == *train* ]] && ! .venv/bin/python -c "import torch" 2>/dev/null; then
    if command -v nvidia-smi >/dev/null; then
      pip install -q "torch==2.13.0"
    else
      # Few retries: where PyTorch's index cannot be reached (no DNS, a firewall),
      # pip would otherwise retry every dependency for minutes.
      pip install -q --retries 1 --timeout 20 "torch==2.13.0" \
        --index-url https://download.pytorch.org/whl/cpu
      # Then the configured indexes' build (the CUDA one on PyPI, a few GB).
      .venv/bin/python -c "import torch" 2>/dev/null || pip install -q "torch==2.13.0"
    fi
  fi
  # The project wants Open3D's CPU build where it exists: the CUDA build an older
  # setup installed would share its files, so it goes first.
  if .venv/bin/python -m pip show -q open3d >/dev/null 2>&1 \
    && .venv/bin/python -c 'import platform, sys; sys.exit(not (sys.platform == "linux" and platform.machine() == "x86_64"))'; then
    pip uninstall -q -y open3d
    # Its files were the CPU build's too, if both were there: put them back.
    if .venv/bin/python -m pip show -q open3d-cpu >/dev/null 2>&1; then
      pip install -q --force-reinstall --no-deps open3d-cpu
    fi
  fi
  pip install -q --no-compile -e ".[$extras]"
  # Byte-code for every installed module, written once here: where
  # PYTHONDONTWRITEBYTECODE is set (as on some CI machines) Python would otherwise
  # compile NumPy's, SciPy's and Numba's sources again at every start, about half a
  # second of each command (glove bench track: first pose 0.95 s after the tracker
  # started without it, 0.53 s with it). About 200 MB, 10-20 s.
  .venv/bin/python -m compileall -q -j 0 .venv/lib/python*/site-packages >/dev/null 2>&1 || true
  modules="glovedb, builder, tracker, open3d, pyrender, zmq, mcap"
  [[ $extras != *train* ]] || modules+=", torch, onnx"
  [[ $extras != *view* ]] || modules+=", rerun"
  [[ $extras != *ray* ]] || modules+=", ray"
  .venv/bin/python -c "import $modules" \
    || { echo "setup: the installed project does not import" >&2; exit 1; }
  echo "$wanted" > "$stamp"
fi
# The project's own modules change between runs: compiled at every setup (a second).
.venv/bin/python -m compileall -q glovedb builder tracker fingertips glove_cli >/dev/null 2>&1 || true
