#!/usr/bin/env bash
# One command from a fresh clone to a running service on the embedded models (no torch installed): the default
# T2M-HiFiGPT model, and the 1-layer GPT and masked models beside it (a request picks one with "model":
# "t2m-bandai-minilm" or "t2m-bandai-masked-minilm").
# Usage: scripts/serve.sh [t2m serve options]   (defaults: --host 0.0.0.0 --port 8000 --model default --model gpt
# --model masked; a --model option, T2M_MODEL_DIR or T2M_EXTRA_MODEL_DIRS replaces the choice of models)
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
venv="${T2M_VENV:-$repo/.venv-serve}"
"$repo/scripts/setup_env.sh" "$venv" ""
if [ "$#" -eq 0 ]; then set -- --host 0.0.0.0 --port 8000; fi
case " $* " in
  *" --model "*|*" --model="*) ;;
  *) if [ -z "${T2M_MODEL_DIR:-}${T2M_BUNDLE_PATH:-}${T2M_EXTRA_MODEL_DIRS:-}" ]; then
       set -- "$@" --model default --model gpt --model masked
     fi ;;
esac
exec "$venv/bin/t2m" serve "$@"
