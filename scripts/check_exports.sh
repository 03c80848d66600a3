#!/usr/bin/env bash
# `make check-exports`: demoforge's exports checked with the real libraries, each in its own venv.
#   .venv-lerobot    Python 3.12 + lerobot[dataset,training,diffusion] (pulls torch 2.11 with CUDA wheels, several GB)
#   .venv-robomimic  Python 3.11 + robomimic 0.3.0 + six (robomimic imports six without declaring it)
# A small sample (the pouring demo, 12 augmented episodes) is exported with the project's .venv, then
# loaded offline and trained for a few steps on CPU. Prints a pass/fail table; exit 1 if a check failed.
set -uo pipefail
cd "$(dirname "$0")/.."
PYENV_ROOT=${PYENV_ROOT:-$HOME/.pyenv}
PY312=${PY312:-$(ls -d "$PYENV_ROOT"/versions/3.12*/bin/python 2>/dev/null | tail -1)}
PY311=${PY311:-$(ls -d "$PYENV_ROOT"/versions/3.11*/bin/python 2>/dev/null | tail -1)}
WORK=${CHECK_EXPORTS_DIR:-$(mktemp -d /tmp/demoforge-check-exports.XXXXXX)}
mkdir -p "$WORK"
RESULTS="$WORK/results.jsonl"
: > "$RESULTS"
export MUJOCO_GL=${MUJOCO_GL:-egl} PREFECT_HOME=${PREFECT_HOME:-$PWD/.prefect} HF_HUB_OFFLINE=1 HF_DATASETS_OFFLINE=1
export WANDB_MODE=disabled
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"  # this checkout's code, also where .venv is another's editable install

step() {  # step NAME CMD...: run CMD, log to $WORK/NAME.log, record pass/fail
    local name=$1; shift
    local t0=$SECONDS log="$WORK/$(echo "$name" | tr -c 'A-Za-z0-9\n' '_' | cut -c1-80).log"
    if "$@" > "$log" 2>&1; then ok=true; else ok=false; fi
    # lerobot-train: the loss at the last step and the model size (an image backbone adds ~11M)
    local extra
    extra=$(grep -o 'step:2 .* loss:[0-9.]*' "$log" | grep -o 'loss:[0-9.]*' | head -1)
    extra="$extra $(grep -o 'num_learnable_params=[0-9]* ([0-9]*M)' "$log" | head -1)"
    extra=$(echo $extra)  # trimmed
    printf '{"check": "%s", "ok": %s, "detail": "%ss%s, log %s"}\n' "$name" "$ok" $((SECONDS - t0)) \
        "${extra:+, $extra}" "$log" >> "$RESULTS"
}

if [ ! -x .venv-lerobot/bin/lerobot-train ] || ! .venv-lerobot/bin/python -c "import diffusers" 2>/dev/null; then
    [ -n "$PY312" ] || { echo "check-exports: needs Python 3.12 (set PY312=/path/to/python3.12)" >&2; exit 2; }
    echo "creating .venv-lerobot (several GB of wheels) ..."
    "$PY312" -m venv .venv-lerobot && .venv-lerobot/bin/pip install -q --upgrade pip \
        && .venv-lerobot/bin/pip install -q 'lerobot[dataset,training,diffusion]' || exit 2
fi
# demoforge's Gymnasium environment in lerobot's venv: its own dependencies only, at the project's pinned versions
# (demoforge itself comes from PYTHONPATH; no Prefect, DuckDB, Open3D or OpenCV)
ENV_DEPS=$(grep -E '^(mujoco|mink|qpsolvers|daqp|scipy)==' requirements/lock.txt | tr '\n' ' ')
if ! .venv-lerobot/bin/python -c "import mujoco, mink, qpsolvers, daqp, scipy" 2>/dev/null; then
    .venv-lerobot/bin/pip install -q $ENV_DEPS || exit 2
fi
if [ ! -x .venv-robomimic/bin/python ] || ! .venv-robomimic/bin/python -c "import robomimic, six" 2>/dev/null; then
    [ -n "$PY311" ] || { echo "check-exports: needs Python 3.11 (set PY311=/path/to/python3.11)" >&2; exit 2; }
    echo "creating .venv-robomimic ..."
    "$PY311" -m venv .venv-robomimic && .venv-robomimic/bin/pip install -q --upgrade pip \
        && .venv-robomimic/bin/pip install -q 'robomimic==0.3.0' six || exit 2
fi

echo "work folder: $WORK"
export DEMOFORGE_WAREHOUSE="$WORK/warehouse"
DF=.venv/bin/demoforge
step "sample warehouse (pouring, 12 augmented episodes)" .venv/bin/python scripts/check_exports_sample.py "$WORK/warehouse" "$WORK/takes"
step "demoforge export lerobot --limit 8" $DF export lerobot --task pouring --out "$WORK/lerobot" --limit 8
step "demoforge export lerobot --limit 3 --with-images --image-size 160x120" \
    $DF export lerobot --task pouring --out "$WORK/lerobot_images" --limit 3 --with-images --image-size 160x120
step "demoforge export lerobot --robot aloha --unchecked --limit 6 (joint space)" \
    $DF export lerobot --task pouring --out "$WORK/lerobot_aloha" --robot aloha --unchecked --limit 6
step "demoforge export robomimic --valid-fraction 0.25" \
    $DF export robomimic --task pouring --out "$WORK/pouring.hdf5" --valid-fraction 0.25

.venv-lerobot/bin/python scripts/check_exports_lerobot.py "$WORK/lerobot" "$WORK/lerobot_images" "$WORK/lr" \
    > "$WORK/lerobot_checks.log" 2>&1
.venv-lerobot/bin/python scripts/check_exports_lerobot.py --joint-space "$WORK/lerobot_aloha" \
    > "$WORK/lerobot_aloha_checks.log" 2>&1
grep '^CHECK ' "$WORK/lerobot_aloha_checks.log" | cut -c7- >> "$RESULTS"
grep '^CHECK ' "$WORK/lerobot_checks.log" | cut -c7- >> "$RESULTS"
TRAIN=(.venv-lerobot/bin/lerobot-train --dataset.repo_id=demoforge/pouring --dataset.video_backend=pyav
       --policy.device=cpu --policy.push_to_hub=false --steps=2 --batch_size=2 --num_workers=0 --log_freq=1
       --save_checkpoint=false --wandb.enable=false)
step "lerobot-train ACT, 2 steps (state + environment_state)" "${TRAIN[@]}" --dataset.root="$WORK/lerobot" \
    --policy.type=act --policy.pretrained_backbone_weights=null --output_dir="$WORK/train_act"
step "lerobot-train Diffusion Policy, 2 steps (state + environment_state)" "${TRAIN[@]}" \
    --dataset.root="$WORK/lerobot" --policy.type=diffusion --output_dir="$WORK/train_diffusion"
step "lerobot-train ACT, 2 steps (camera images)" "${TRAIN[@]}" --dataset.root="$WORK/lerobot_images" \
    --policy.type=act --policy.pretrained_backbone_weights=null --output_dir="$WORK/train_act_images"
step "lerobot-train ACT, 2 steps (ALOHA joint space: 14 joints + environment_state)" "${TRAIN[@]}" \
    --dataset.root="$WORK/lerobot_aloha" --policy.type=act --policy.pretrained_backbone_weights=null \
    --output_dir="$WORK/train_act_aloha"
# closed loop: ACT trained long enough to learn (ACT_STEPS, default 2000) on a joint-space export of a larger sample,
# then rolled out in demoforge's environment on held-out scenes
step "sample warehouse for training (pouring, ${TRAIN_EPISODES:=60} augmented episodes)" \
    .venv/bin/python scripts/check_exports_sample.py "$WORK/warehouse_train" "$WORK/takes_train" --episodes "$TRAIN_EPISODES"
step "demoforge export lerobot --robot aloha --gripper 2f140 --unchecked ($TRAIN_EPISODES episodes, joint space)" \
    env DEMOFORGE_WAREHOUSE="$WORK/warehouse_train" $DF export lerobot --task pouring --out "$WORK/lerobot_aloha_train" \
    --robot aloha --gripper 2f140 --unchecked
# a CPU-sized ACT (lerobot's default, 512 wide with 4 encoder layers, takes seconds per step on 2 cores)
step "lerobot-train ACT, ${ACT_STEPS:=2000} steps (ALOHA joint space, chunks of 30, 256 wide)" .venv-lerobot/bin/lerobot-train \
    --dataset.repo_id=demoforge/pouring --dataset.root="$WORK/lerobot_aloha_train" --dataset.video_backend=pyav \
    --policy.type=act --policy.device=cpu --policy.push_to_hub=false --policy.pretrained_backbone_weights=null \
    --policy.chunk_size=30 --policy.n_action_steps=30 --policy.dim_model=256 --policy.dim_feedforward=1024 \
    --policy.n_encoder_layers=2 --policy.n_vae_encoder_layers=2 --policy.optimizer_lr=1e-4 --steps="$ACT_STEPS" --batch_size=16 --num_workers=0 \
    --log_freq=200 --save_freq="$ACT_STEPS" --wandb.enable=false --output_dir="$WORK/train_act_aloha_long"
.venv-lerobot/bin/python scripts/check_exports_lerobot_rollout.py \
    "$WORK/train_act_aloha_long/checkpoints/last/pretrained_model" --scenes "${ROLLOUT_SCENES:-10}" \
    > "$WORK/lerobot_rollout.log" 2>&1
grep '^CHECK ' "$WORK/lerobot_rollout.log" | cut -c7- >> "$RESULTS" \
    || echo '{"check": "lerobot ACT in demoforge'"'"'s Gymnasium environment", "ok": false, "detail": "see '"$WORK"'/lerobot_rollout.log"}' >> "$RESULTS"
.venv-robomimic/bin/python scripts/check_exports_robomimic.py "$WORK/pouring.hdf5" "$WORK/rm" \
    > "$WORK/robomimic_checks.log" 2>&1
grep '^CHECK ' "$WORK/robomimic_checks.log" | cut -c7- >> "$RESULTS"

.venv/bin/python - "$RESULTS" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
w = max(len(r["check"]) for r in rows)
print(f"\n| {'check':<{w}} | result | detail |\n|{'-' * (w + 2)}|--------|--------|")
for r in rows:
    print(f"| {r['check']:<{w}} | {'PASS' if r['ok'] else 'FAIL':<6} | {r['detail']} |")
bad = sum(not r["ok"] for r in rows)
print(f"\n{len(rows) - bad} of {len(rows)} checks passed")
sys.exit(1 if bad else 0)
PY
