#!/usr/bin/env bash
# Every benchmark once, side by side: model-level speed (`t2m bench --quick`), HTTP latency of a 10 s motion per
# output format, and a short load test with an overload phase. One server (`t2m serve`, loopback) serves the HTTP
# benchmarks; it is stopped at the end.
# Usage: benchmarks/run_all.sh [MODEL_DIR]     (default: t2m/bundles/default)
# Env:   PYTHON (default python), T2M_MAX_QUEUE for the server (default 4), LOAD_SECONDS (default 20)
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
cd "$repo"
model="${1:-$repo/t2m/bundles/default}"
python="${PYTHON:-python}"
load_seconds="${LOAD_SECONDS:-20}"
export T2M_MAX_QUEUE="${T2M_MAX_QUEUE:-4}"

echo "## Machine"
echo
echo "- CPU: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//') ($(nproc) cores visible)"
echo "- RAM: $(awk '/MemTotal/ {printf "%.1f GiB", $2 / 1048576}' /proc/meminfo); load average: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "- $("$python" -c 'import platform, onnxruntime, numpy; print(f"Python {platform.python_version()}, onnxruntime {onnxruntime.__version__}, numpy {numpy.__version__}")')"
echo "- model bundle: $model ($("$python" -c 'import json, sys; m = json.load(open(sys.argv[1] + "/manifest.json")); print(m["name"], m["version"])' "$model"))"
echo

echo "## Generation speed (t2m bench --quick)"
echo
"$python" -m cli bench --quick
echo

port="$("$python" -c 'from benchmarks.server_process import free_port; print(free_port())')"
url="http://127.0.0.1:$port"
log="$(mktemp -t t2m-bench-server.XXXXXX.log)"
"$python" -m cli serve --host 127.0.0.1 --port "$port" --model "$model" --log-level warning >"$log" 2>&1 &
server_pid=$!
trap 'kill -INT "$server_pid" 2>/dev/null; wait "$server_pid" 2>/dev/null || true' EXIT
"$python" -c 'import sys; from benchmarks.server_process import wait_until_healthy; wait_until_healthy(sys.argv[1], 300)' "$url" \
  || { echo "server did not become healthy; log:"; tail -20 "$log"; exit 1; }

echo "## HTTP latency"
echo
"$python" benchmarks/http_latency.py --url "$url" --repeats 10
echo
echo "## Load (server T2M_MAX_QUEUE=$T2M_MAX_QUEUE)"
echo
"$python" benchmarks/load_test.py --url "$url" --server-pid "$server_pid" --clients 4 --seconds "$load_seconds" \
  --overload --overload-clients 64 --overload-seconds 5
