#!/usr/bin/env bash
# Issue 17's figures side by side in one run, meant for an idle machine: release-size ms per token (float32 vs int8
# vs the reference sampler, 1 and 2 threads), time to first frame vs the whole motion (streamed), and continuous
# batching before/after (mixed short/long requests; 16 clients of 10 s motions). Prints the machine and its load.
# Usage: benchmarks/speed_suite.sh [MODEL_DIR]      Env: PYTHON (default python), SECONDS_PER_PHASE (default 30)
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
cd "$repo"
model="${1:-t2m/bundles/default}"                 # relative: the log names no machine's folders
python="${PYTHON:-python}"
phase_seconds="${SECONDS_PER_PHASE:-30}"
export PYTHONPATH="$repo${PYTHONPATH:+:$PYTHONPATH}"

machine() {
  echo "- CPU: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//') ($(nproc) cores visible)"
  echo "- load average: $(cut -d' ' -f1-3 /proc/loadavg); $(date -u +%FT%TZ)"
}

echo "## Machine"; machine
echo "- $("$python" -c 'import platform, onnxruntime, torch; print(f"Python {platform.python_version()}, onnxruntime {onnxruntime.__version__}, torch {torch.__version__}")')"
echo "- model bundle: $model"
echo
echo "## Release size: ms per token (int8_release_speed.py --threads 1 2)"
OMP_NUM_THREADS=1 "$python" benchmarks/int8_release_speed.py --threads 1 2
echo; machine; echo
echo "## Time to first frame (stream_latency.py, onnxruntime's threads, then 1 thread)"
"$python" benchmarks/stream_latency.py --model "$model" --repeats 30
"$python" benchmarks/stream_latency.py --model "$model" --repeats 30 --intra-op-threads 1
echo; machine; echo
echo "## Continuous batching before/after (continuous_batching.py --seconds $phase_seconds --rounds 2)"
"$python" benchmarks/continuous_batching.py --model "$model" --seconds "$phase_seconds" --rounds 2
echo; machine
