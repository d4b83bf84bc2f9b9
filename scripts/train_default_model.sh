#!/usr/bin/env bash
# The exact commands that produced models/default (see its MODEL_CARD.md for wall times on a 2-core CPU).
# Datasets and checkpoints are not committed; this rebuilds them. Run from the repository root inside the
# training environment (scripts/setup_env.sh .venv train,dev). Each stage writes progress, train.log, log.csv
# and curves.png in its run directory; long stages can be resumed with --resume.
set -euo pipefail
SHARED="${T2M_SHARED:-../shared}"
DATA="${DATA:-data/bandai}"
RUNS="${RUNS:-runs}"

t2m data build --source "$SHARED/data/bandai-namco/bandai-namco-motion.tar.xz" --out "$DATA"

# VQ-VAE: T2M-GPT's architecture at width 128 / code dim 128, 512 codes, EMA + reset; 32-frame windows so that the
# 1-2 s raise-hand clips are seen too. Stopped at step VQ_STEPS_USED of the 3000 planned (session time limit).
t2m train vq --data "$DATA" --out "$RUNS/vq" --steps 3000 --batch-size 64 --window 32 --width 128 --code-dim 128 \
  --nb-code 512 --lr 2e-4 --warmup-steps 300 --lr-milestones 0.8 --log-every 25 --val-every 500 --save-every 250 \
  --threads 2 --seed 0

GPT_COMMAND

# Our own text-motion evaluator (the official one cannot be obtained here).
t2m train evaluator --data "$DATA" --out "$RUNS/evaluator" --text-cache "$RUNS/text_minilm.npz"

EXPORT_COMMAND

EVAL_COMMAND
