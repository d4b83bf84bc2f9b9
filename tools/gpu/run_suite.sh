#!/usr/bin/env bash
# The GPU suite in one run: benchmarks/gpu_suite.py (python -m benchmarks.gpu_suite) on CUDA, every embedded model and the release sizes,
# onnxruntime-gpu with device-resident step caches against PyTorch eager on the same GPU. Prints one markdown table;
# OUT/gpu_suite.json keeps the rows. About 3-6 minutes on an H200 (most of it exporting the 228M-parameter graph).
#
# Needs a Python with torch (CUDA build) and numpy. onnx and onnxruntime-gpu come from wheels when they are not
# importable (no index, no network): GPU_WHEELS names the folders holding them (default "/tmp/ortgpu
# /tmp/gpu_wheelhouse"); they are installed with --no-deps into $SITE (default /tmp/t2m-gpu-site), put first on
# PYTHONPATH, so a CPU-only onnxruntime installed in the system stays untouched and is shadowed.
#   tools/gpu/run_suite.sh [OUT] [gpu_suite.py options...]      (OUT default: gpu-suite-out)
set -euo pipefail
repo="$(cd "$(dirname "$0")/../.." && pwd)"
out="${1:-gpu-suite-out}"; shift || true
python="${PYTHON:-python3}"
site="${SITE:-/tmp/t2m-gpu-site}"
wheels="${GPU_WHEELS:-/tmp/ortgpu /tmp/gpu_wheelhouse}"

has_cuda_ort() { PYTHONPATH="$site" "$python" -c \
  "import onnxruntime as o, sys; sys.exit('CUDAExecutionProvider' not in o.get_available_providers())" 2>/dev/null; }
find_wheel() { for dir in $wheels; do compgen -G "$dir/$1" | head -n 1 && return 0; done; return 0; }

mkdir -p "$site"
install=()
if ! has_cuda_ort; then install+=("$(find_wheel 'onnxruntime_gpu-*.whl')"); fi
if ! PYTHONPATH="$site" "$python" -c "import onnx" 2>/dev/null; then
  install+=("$(find_wheel 'onnx-*.whl')")
  "$python" -c "import ml_dtypes" 2>/dev/null || install+=("$(find_wheel 'ml_dtypes-*.whl')")
  # onnx 1.23's generated code checks for a protobuf runtime >= 6.31.1 (the wheelhouse's: 7.36.2)
  "$python" -c "import google.protobuf as p, sys; sys.exit(tuple(map(int, p.__version__.split('.')[:3])) < (6, 31, 1))" \
    2>/dev/null || install+=("$(find_wheel 'protobuf-*.whl')")
  "$python" -c "import typing_extensions" 2>/dev/null || install+=("$(find_wheel 'typing_extensions-*.whl')")
fi
wanted=()
for wheel in "${install[@]}"; do [ -n "$wheel" ] && wanted+=("$wheel"); done
if [ "${#wanted[@]}" -gt 0 ]; then
  echo "installing into $site: ${wanted[*]##*/}" >&2
  "$python" -m pip install --quiet --no-index --no-deps --target "$site" "${wanted[@]}"
fi
# onnxruntime-gpu loads CUDA 13, cuBLAS and cuDNN 9 by name: those torch brought as nvidia-* wheels are found here
nvidia_libs="$("$python" - <<'PY' 2>/dev/null || true
import glob, os
try:
    import nvidia
except ImportError:
    raise SystemExit
print(":".join(sorted({d for p in nvidia.__path__ for d in glob.glob(os.path.join(p, "*", "lib"))} |
                      {d for p in nvidia.__path__ for d in glob.glob(os.path.join(p, "cu*", "lib"))})))
PY
)"
export LD_LIBRARY_PATH="${nvidia_libs}${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
export PYTHONPATH="$site:$repo${PYTHONPATH:+:$PYTHONPATH}"
cd "$repo"
# GPU_SCRIPT: another benchmark module of the same environment and options (benchmarks.gpu_profile)
exec timeout "${SUITE_TIMEOUT_S:-420}" "$python" -m "${GPU_SCRIPT:-benchmarks.gpu_suite}" --out "$out" --device cuda "$@"
