#!/usr/bin/env bash
# T2M-HiFiGPT (a residual VQ-VAE at 8 frames per code + the double-tier GPT) trained on Bandai-Namco, sized
# so that all stages take about 2 hours on this project's 2-core CPU machine: the exact commands that produced
# the default bundle t2m/bundles/default (0.2.0, 0.2.1, 0.3.0) on 2026-11-25. Stages 1 and 2 ran with ONE thread
# beside the masked model's continued training (t2m/families/masked/train_embedded_model.sh, 2b/3b) and helper work, so their wall
# times are upper bounds; 2b ran alone on 2 threads, 2c on one beside its control. Run from the repository root in
# the training environment; every stage writes progress, train.log, log.csv and curves.png in its run directory and
# can be continued with --resume.
set -euo pipefail
DATA="${DATA:-data/bandai}"           # built by `t2m data build` (t2m/families/gpt/train_embedded_model.sh, first command)
RUNS="${RUNS:-runs}"
TEXT="$RUNS/text_minilm.npz"          # the GPT's caption cache: shared, computed once (~1 min)

# 1. RVQ-VAE as in the paper: 8 frames per code (--down-t 3), R = 6 depths of ONE shared codebook of 256 codes (dim
#    128; the paper: 256 x 512), greedy residual search, EMA + dead-code reset (pooled over depths), quantiser dropout
#    0.2; 32-frame windows (the paper's crop), the default VQ's width, action balance and bone term.
#    Ran 24000 steps (raised from the planned 15000 when one thread gave ~11.5 steps/s): 43.8 min wall; validation
#    reconstruction loss 0.032 (the default 1D VQ: 0.058; the masked model's joint VQ: 0.025).
t2m train vq --data "$DATA" --out "$RUNS/rvq" --steps 24000 --batch-size 64 --window 32 --width 128 --code-dim 128 \
  --nb-code 256 --down-t 3 --quantizer residual --residual-layers 6 --shared-codebook --quantizer-dropout 0.2 \
  --lr 2e-4 --warmup-steps 300 --lr-milestones 0.8 --balance-power 0.5 --bone-weight 0.5 --log-every 50 \
  --val-every 1000 --save-every 500 --threads 1 --seed 0

# 2. The double-tier GPT: width 256, 4 heads, 3 temporal + 3 residual layers (the default GPT: 256 x 4 layers), 25
#    time steps (10 s), MiniLM condition with length conditioning (keep 0.8), per-time-step corruption tau 0.5,
#    condition dropout 0.1 (the paper's), condition noise 0.8 and action balance 0.3 as the default GPT's, stop loss
#    weight 1. Encoding every clip with the VQ once: ~1 min. Ran 3000 steps (cut from 6000 to fit the session; the
#    first 250 under a 4000-step plan, resumed): 60 min wall + 8 min for the first 250 steps; validation code CE 3.38
#    (step 500) -> 2.87, depth-0 accuracy 0.38 -> 0.55, stop accuracy 0.95 -> 0.99 (still improving).
t2m train hifigpt --data "$DATA" --vq "$RUNS/rvq" --out "$RUNS/hifigpt" --steps 3000 --batch-size 64 --lr 4e-4 \
  --warmup-steps 200 --lr-milestones 0.75 --embed 256 --heads 4 --temporal-layers 3 --residual-gpt-layers 3 \
  --max-tokens 25 --corruption 0.5 --cond-drop 0.1 --cond-noise 0.8 --length-keep 0.8 --stop-weight 1.0 \
  --balance-power 0.3 --text-cache "$TEXT" --log-every 25 --val-every 500 --save-every 250 --threads 1 --seed 0
# (That was 0.1.0: R@1 0.724, FID 0.018, but the left-hand probe at 0.57 < the suite's 0.6.)
# 2b. 0.2.0: the same run resumed to 6000 steps (the lr schedule is a function of --steps: 4e-4 again until 4500,
#     then 4e-5), chosen because the validation loss was still falling at 3000. 31.6 min on 2 idle threads;
#     validation code CE 2.868 -> 2.866 (2.98 while the lr was high), depth-0 accuracy 0.55 -> 0.59, stop 0.9998.
t2m train hifigpt --data "$DATA" --vq "$RUNS/rvq" --out "$RUNS/hifigpt" --steps 6000 --batch-size 64 --lr 4e-4 \
  --warmup-steps 200 --lr-milestones 0.75 --embed 256 --heads 4 --temporal-layers 3 --residual-gpt-layers 3 \
  --max-tokens 25 --corruption 0.5 --cond-drop 0.1 --cond-noise 0.8 --length-keep 0.8 --stop-weight 1.0 \
  --balance-power 0.3 --text-cache "$TEXT" --log-every 25 --val-every 500 --save-every 250 --threads 2 --seed 0 \
  --resume

# 2c. 0.3.0: a new decoder on the same codes (the encoder, codebooks and GPT stay): its dilated residual blocks read
#     only past frames, so it looks 3 steps ahead instead of 25 and a one-sentence motion streams early frames; and
#     64-frame windows of all 6 depths (no quantiser dropout: the GPT always gives 6), so its dilation-9 taps see
#     real neighbours more often than in stage 1's 32-frame windows. Starts from stage 1's decoder (taps moved one
#     into the past). 12000 steps, one thread beside the control run: 26 min. The control (the same training without
#     causal blocks, --no-causal-decoder-blocks --out "$RUNS/rvq_refit") separates what causality costs.
t2m train vq-decoder --data "$DATA" --vq "$RUNS/rvq" --out "$RUNS/rvq_causal" --steps 12000 --batch-size 64 \
  --window 64 --lr 2e-4 --warmup-steps 200 --lr-milestones 0.7 --bone-weight 0.5 --balance-power 0.5 --log-every 50 \
  --val-every 1000 --save-every 500 --threads 1 --seed 0

# The evaluator of the default GPT's table (t2m/families/gpt/train_embedded_model.sh; deterministic, 0.6 min), if missing.
[ -d "${EVALUATOR:-$RUNS/evaluator}" ] || t2m train evaluator --data "$DATA" --out "${EVALUATOR:-$RUNS/evaluator}" \
  --text-cache "$TEXT" --steps 600 --threads 2

# 3. The bundle (seeded guided rollout checks in its card), for the service, `t2m bench --bundle` and the probes.
#    0.2.1: int8 text encoder AND step graphs (10 MB -> 2.7 MB each). Shipped by the int8 rule (Table 1 within float32's intervals, probes held), measured on the
#    bundle as served (step 4b): Table 1 within the float32 export's intervals, the probes held, 2x faster. (0.2.0 was
#    the same export with --int8 text only; its float32 step graphs reproduce PyTorch's rollout codes exactly.)
#    0.3.0: the same export with stage 2c's decoder (--vq rvq_causal; the step graphs and text encoder come out byte
#    for byte as 0.2.1's: export is deterministic and the GPT and codebooks are the same).
t2m export --family hifigpt --vq "$RUNS/rvq_causal" --hifigpt "$RUNS/hifigpt" --int8 text,temporal,residual \
  --name t2m-bandai-hifigpt-minilm --version 0.3.0 --model-card t2m/families/hifigpt/model_card.md -o t2m/bundles/default
t2m index-captions t2m/bundles/default --data "$DATA"
python scripts/share_bundle_files.py      # the gpt and masked bundles link the default's text files

# 4. Evaluation: the same `t2m eval`, evaluator, split, repeats and stream settings as the default
#    GPT's table, so the tables compare; crops are multiples of 8 frames (at most 192). The VQ reconstruction row's
#    root-relative MPJPE is the residual VQ's (the goal: <= 15 mm; the 1-layer VQ: 42 mm). Generation runs the
#    service's loop (t2m.families.hifigpt.loop) at the crops' lengths, guidance 1 and 3 on code logits.
#    Guidance 1 was left out to fit the session.
#    0.3.0 (and the control): the same with --vq "$RUNS/rvq_causal" (--vq "$RUNS/rvq_refit"), --out
#    "$RUNS/eval_hifigpt_causal.md" ("$RUNS/eval_hifigpt_refit.md"), --threads 1: 1.8 min each.
t2m eval --data "$DATA" --evaluator "${EVALUATOR:-$RUNS/evaluator}" --vq "$RUNS/rvq" --hifigpt "$RUNS/hifigpt" \
  --guidance 3 --repeats 3 --mm-texts 30 --mm-repeats 10 --streams 100 --text-cache "$TEXT" --threads 2 \
  --out "$RUNS/eval_hifigpt2.md"
# 4b. Table 1 of the bundle as served (its own graphs through the service's loop; 48 s), for the int8 decision: run it
#     on a float32 export (--int8 text, -o DIR) too and compare.
t2m eval --bundle t2m/bundles/default --data "$DATA" --evaluator "${EVALUATOR:-$RUNS/evaluator}" --guidance 3 \
  --repeats 3 --mm-texts 30 --mm-repeats 10 --streams 100 --threads 2 --out "$RUNS/eval_bundle_default.md"
# The kinematic probes on the bundle (free wordings x 5 seeds), beside the GPT model's; and its request speed.
t2m eval probes --bundle t2m/bundles/default --seeds 5 --json-out "$RUNS/probes_hifigpt2.json"
t2m bench --bundle default --bundle gpt --bundle masked --threads 1 --repeats 10    # then --threads 2
python scripts/render_motions.py --bundle t2m/bundles/default --out docs/images --seed 0   # the README pictures

# Measurements behind these choices, 2026-11-25, a worktree, on the project machine (2 cores, torch
# 2.13.0+cpu) while another session's joint-VQ training and test suite held the cores (load average 5-7: our runs
# went about 5x slower than on an idle machine, so absolute figures below are pessimistic; the estimates above scale
# the RATIO to the default model's step, measured side by side, by the default model's idle throughput).
#
# VQ reconstruction after 400 steps (batch 64 x 32 frames, width/code 128, --threads 2, the options above but
# --lr-milestones 1.0 --warmup-steps 50), on the first 256 val windows of 64 frames (root-relative MPJPE = the pose;
# global = with the integrated root drift):
#   x4, 1 layer, K 512 (the default VQ's shape):   val_recon 0.173, root-relative 67.5 mm, 135 s (1.00x)
#   x4, R 4 shared, K 256:                           val_recon 0.168, root-relative 67.9 mm, 327 s (2.42x)
#   x8, R 4 shared, K 256:                           val_recon 0.231, root-relative 87.7 mm, 163 s (1.21x)
#   x8, R 6 shared, K 256:                           val_recon 0.235, root-relative 90.0 mm, 163 s (1.21x)
#   x8, R 6 per-depth codebooks, K 256:              val_recon 0.217, root-relative 92.2 mm, 172 s (1.27x)
# What this does and does not decide: 400 steps are too few for the depth to matter (the decoder, not the
# quantiser, limits every run: 68-92 mm against the default VQ's 42 mm after 15000 steps), and x8 starts ~20 mm
# behind x4. x4 with R 4 costs 2.4x per VQ step and doubles the GPT's time steps (50 instead of 25, 5 network calls
# each: 250 calls per 10 s against 175 for x8 R 6, t2m/families/hifigpt/bench.py), so the run follows the paper (x8,
# R 6, shared codebook: the cheapest at equal R). STILL TO MEASURE in the real run (item 5): whether x8 R 6 reaches <= 15 mm
# root-relative after 15000 steps; if it stalls above the 1-layer VQ's 42 mm, rerun step 1 with --down-t 2
# --residual-layers 4 (and --max-tokens 50 in step 2, ~+40 min) before training the GPT.
#
# Training step cost, interleaved in one process (forward + backward + AdamW on random batches of the real shapes;
# median of 10 steps each, a one-off script not kept):
#   default GPT (E 256, 4 layers, batch 128 x 50 codes):       2213 ms (1.00x; idle: 2.6 steps/s = 336 motions/s)
#   HiFiGPT E 256, 2 + 2 layers, batch 64 x 25 steps x R 6:   1869 ms (0.84x -> ~3.1 steps/s idle)
#   HiFiGPT E 256, 3 + 3 layers, batch 64 x 25 steps x R 6:   2764 ms (1.25x -> ~2.1 steps/s idle; chosen)
# Same session, `t2m train gpt` at the default size for 60 steps: 62 motions/s (336 idle): the ~5x load factor.
# Budget: 26 + 2 (captions, codes) + 48 + 1 (evaluator) + 1 (export) + 10-20 (eval) + ~5 (probes, bench)
# ~ 1 h 40 min - 1 h 50 min.
