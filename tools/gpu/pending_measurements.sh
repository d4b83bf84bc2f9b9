#!/usr/bin/env bash
# What is still unmeasured on a GPU (docs/gpu.md, "Next on a device"), in one device call after onnxruntime-gpu is unpacked there
# (docs/gpu.md, "Getting onnxruntime-gpu there" for the transport and "Next on a device" for why each part):
#   1. the default model's 1,000 motions/s: fp16 graphs at batch 256 and 1,024, in 1, 2 and 4 processes at once;
#   2. T2M-GPT release's 1.5 ms per token: the fixed-cache step without its head transposes, fp16, CUDA graphs;
#   3. the service's CUDA-graph path for T2M-GPT and MoMask imports, float32 and fp16 (`t2m quantize` now converts
#      gpt_step_fixed.onnx too): ms per request, ms per network call, the motions against the plain calls';
#   4. MoMask release's 20 ms: onnxruntime's transformer fusions, fp16, replayed (fewer kernels per call).
# Each part has its own time limit and writes its own folder, so a part cut off keeps what the others measured.
#   SITE=/tmp/t2m-gpu-site bash tools/gpu/pending_measurements.sh OUT
set -uo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="${1:?usage: pending_measurements.sh OUT}"
SUITE_TIMEOUT_S="${DEFAULT_S:-170}" bash "$here/run_suite.sh" "$out/default" --models default --graphs fp16 \
  --batches 256,1024 --processes 2,4 --repeats 3
SUITE_TIMEOUT_S="${T2M_GPT_S:-150}" bash "$here/run_suite.sh" "$out/t2m-gpt" --models t2m-gpt-release --graphs fp16 \
  --batches 1,16 --repeats 5
SUITE_TIMEOUT_S="${SERVICE_S:-180}" GPU_SCRIPT=benchmarks.gpu_service_check bash "$here/run_suite.sh" \
  "$out/service" --sizes release --repeats 5 --models t2m-gpt,momask
SUITE_TIMEOUT_S="${MOMASK_S:-60}" bash "$here/run_suite.sh" "$out/momask" --models momask-release \
  --graphs fp16-fused --batches 1 --repeats 5
