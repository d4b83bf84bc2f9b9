#!/usr/bin/env bash
# The exact commands that produced t2m/bundles/gpt, the 1-layer T2M-GPT model (the default bundle up to 0.4.0; it then
# moved from t2m/bundles/default; see its MODEL_CARD.md for wall times on a 2-core CPU). The first command builds the
# dataset every training script uses.
# Datasets and checkpoints are not committed; this rebuilds them. Run from the repository root inside the
# training environment (scripts/setup_env.sh .venv train,dev). Each stage writes progress, train.log, log.csv
# and curves.png in its run directory; long stages can be resumed with --resume.
set -euo pipefail
SHARED="${T2M_SHARED:-../shared}"
DATA="${DATA:-data/bandai}"
RUNS="${RUNS:-runs}"

t2m data build --source "$SHARED/data/bandai-namco/bandai-namco-motion.tar.xz" --out "$DATA"

# VQ-VAE: T2M-GPT's architecture at width 128 / code dim 128, 512 codes, EMA + reset; 32-frame windows so that the
# 1-2 s raise-hand clips are seen too; windows drawn action-balanced (mass ~ clips**0.5) so rare actions (kick, bow,
# walk-back) are reconstructed too; a bone-length term (weight 0.5, metres) keeps each bone at one length.
# 21.1 min wall on 2 cores (15000 steps).
t2m train vq --data "$DATA" --out "$RUNS/vq" --steps 15000 --batch-size 64 --window 32 --width 128 --code-dim 128 \
  --nb-code 512 --lr 2e-4 --warmup-steps 300 --lr-milestones 0.8 --log-every 50 --val-every 1000 --save-every 500 \
  --threads 2 --seed 0 --balance-power 0.5 --bone-weight 0.5

# GPT: 4 blocks (2 + 2) x 256, 4 heads, MiniLM condition, length token, code corruption 0.5, condition noise up to
# 0.8, condition dropout 0.1; length-bucketed batches of 128, clips drawn action-balanced (mass ~ clips**0.3).
# 38.1 min wall on 2 cores (6000 steps; validation CE flattens after the lr drop at 4500).
t2m train gpt --data "$DATA" --vq "$RUNS/vq" --out "$RUNS/gpt" --steps 6000 --batch-size 128 --lr 4e-4 \
  --warmup-steps 200 --lr-milestones 0.75 --embed 256 --layers 4 --heads 4 --text-cache "$RUNS/text_minilm.npz" \
  --threads 2 --log-every 25 --val-every 500 --save-every 500 --seed 0 --balance-power 0.3 --cond-noise 0.8

# Our own text-motion evaluator (the official one cannot be obtained here).
t2m train evaluator --data "$DATA" --out "$RUNS/evaluator" --text-cache "$RUNS/text_minilm.npz" --steps 600 --threads 2

# The bundle: float32 decoder and GPT step graphs, int8 text encoder (41 MB in all), with the model card appended.
t2m export --vq "$RUNS/vq" --gpt "$RUNS/gpt" --int8 text --name t2m-bandai-minilm --version 0.3.0 \
  --model-card t2m/families/gpt/model_card.md -o t2m/bundles/gpt
# The index of the training captions and its calibrated unknown-text threshold (+4.8 MB, ~10 s; the card gets its
# "Unknown sentences" section with the false/missed warning rates).
t2m index-captions t2m/bundles/gpt --data "$DATA"
python scripts/share_bundle_files.py t2m/bundles/gpt   # text encoder, tokenizer, caption index: the default's copy

# The evaluation table and the kinematic probes of the model card.
t2m eval --data "$DATA" --evaluator "$RUNS/evaluator" --vq "$RUNS/vq" --gpt "$RUNS/gpt" --guidance 1 3 --repeats 3 \
  --mm-texts 30 --mm-repeats 10 --streams 100 --text-cache "$RUNS/text_minilm.npz" --threads 2 --out "$RUNS/eval.md"
# The guidance scales compared on the validation split only (the card's second table).
t2m eval --data "$DATA" --split val --evaluator "$RUNS/evaluator" --vq "$RUNS/vq" --gpt "$RUNS/gpt" \
  --guidance 1 1.5 2 3 --repeats 3 --mm-texts 30 --mm-repeats 10 --streams 100 --text-cache "$RUNS/text_minilm.npz" \
  --threads 2 --out "$RUNS/eval_val_guidance.md"
t2m eval probes --bundle t2m/bundles/gpt --seeds 5 --json-out "$RUNS/probes.json"
python scripts/render_motions.py --bundle t2m/bundles/gpt --out tmp/images-gpt --seed 0  # README: the default's
