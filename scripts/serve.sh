#!/usr/bin/env bash
# One command from a fresh clone to a running service on the embedded default model (no torch installed).
# Usage: scripts/serve.sh [t2m serve options]   (defaults: --host 0.0.0.0 --port 8000)
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
venv="${T2M_VENV:-$repo/.venv-serve}"
"$repo/scripts/setup_env.sh" "$venv" ""
if [ "$#" -eq 0 ]; then set -- --host 0.0.0.0 --port 8000; fi
exec "$venv/bin/t2m" serve "$@"
