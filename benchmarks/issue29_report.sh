#!/usr/bin/env bash
# Issue 29's figures on the CPU in one run, for an idle machine, as the issue asks them shown together:
#   1. the released sizes (random weights in the exact layouts, imported) float32 vs int8 / int4 per importer,
#      and the diffusion releases float32 vs int8 (benchmarks/released_models_speed.py, 1 and 2 onnxruntime threads);
#   2. short requests first, the code before issue 29 against this checkout over HTTP: the 2 s probe's p90 ratio
#      under the 30 s load, the long requests' answers/s, 16 clients' answers/s and p99 (benchmarks/step_order.py);
#   3. the device path without a device: what benchmarks/gpu_pending.sh will run on one, each part dry-run here on
#      the CPU provider, and the CPU tests of the device code (I/O binding, CUDA-graph replay, capture checks).
#   4. the CPU goals read off those figures (benchmarks/issue29_goals.py).
# Everything goes to OUT/report.md as well as stdout; OUT keeps the release bundles (reused by a second run) and
# the worktree of the older commit.
#   benchmarks/issue29_report.sh OUT [BEFORE_REV]     (BEFORE_REV: default 5164bad, the commit before issue 29)
# Env: PYTHON (default .venv/bin/python), SECONDS_PER_PHASE (15), ROUNDS (1), REPEATS (1).
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
cd "$repo"
out="${1:?usage: issue29_report.sh OUT [BEFORE_REV]}"
before_rev="${2:-5164bad}"
python="${PYTHON:-$repo/.venv/bin/python}"
mkdir -p "$out"
out="$(cd "$out" && pwd)"

machine() {
  echo "- CPU: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//') ($(nproc) cores visible)"
  echo "- load average: $(cut -d' ' -f1-3 /proc/loadavg); $(date -u '+%Y-%m-%d %H:%M UTC')"
}

report() {
  echo "# Issue 29 on the CPU, one run"
  echo
  echo "- code: $(git rev-parse --short HEAD)$(git diff --quiet HEAD || echo ' (with uncommitted changes)')"
  machine
  echo
  echo "## 1. Released sizes: float32 vs int8 / int4 per importer"
  echo
  OMP_NUM_THREADS=1 PYTHONPATH=. "$python" benchmarks/released_models_speed.py --repeats "${REPEATS:-1}" \
    --threads 1 2 --diffusion-threads 1 --schemes float32,int8,int4 --workdir "$out/releases" \
    --json-out "$out/released.json"
  echo
  echo "## 2. Short requests first: the code before issue 29 ($before_rev) vs this checkout"
  echo
  machine
  before="$out/before-$before_rev"
  [ -d "$before" ] || git worktree add --detach "$before" "$before_rev" >/dev/null
  "$python" benchmarks/step_order.py --before-code "$before" --before-model "$before/t2m/bundles/default" \
    --before-step-order every-cohort --seconds "${SECONDS_PER_PHASE:-15}" --rounds "${ROUNDS:-1}" \
    --json-out "$out/scheduling.json"
  echo
  echo "## 3. The device path without a device"
  echo
  machine
  echo
  echo "What benchmarks/gpu_pending.sh runs on a GPU, each part here on the CPU provider at small sizes:"
  echo
  echo '```'
  PYTHONPATH=. "$python" benchmarks/gpu_suite.py --out "$out/gpu-suite-cpu" --device cpu --tiny --models default \
    --graphs fp16 --batches 4 --processes 2 --repeats 1 2>&1 | awk '/^\| model/ {p = 1} p'
  PYTHONPATH=. "$python" benchmarks/gpu_service_check.py --out "$out/gpu-service-cpu" --device cpu --sizes small \
    --repeats 1 --models t2m-gpt,momask 2>&1 | awk '/^\| model/ {p = 1} p'
  echo '```'
  echo
  echo "The CPU tests of the device code:"
  echo
  echo '```'
  "$python" -m pytest -q -p no:cacheprovider tests/service/test_execution_providers.py \
    tests/service/test_bound_step.py tests/service/test_graphed_step.py tests/service/test_cuda_graph_serving.py \
    tests/export/test_capture_check.py tests/export/test_quantize_fixed_step.py tests/test_gpu_suite.py 2>&1 | tail -n 3
  echo '```'

  echo
  echo "## Issue 29's CPU goals, from the figures above"
  echo
  "$python" benchmarks/issue29_goals.py --scheduling "$out/scheduling.json" --released "$out/released.json"
}

report 2>&1 | tee "$out/report.md"
