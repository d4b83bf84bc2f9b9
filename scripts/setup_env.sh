#!/usr/bin/env bash
# Creates (or reuses) the project's virtualenv and installs the project with the given extras.
# Usage: scripts/setup_env.sh VENV_DIR EXTRAS   e.g. scripts/setup_env.sh .venv "train,dev"
set -euo pipefail
venv="${1:?venv dir}"
extras="${2:-}"
repo="$(cd "$(dirname "$0")/.." && pwd)"
python="${PYTHON:-python3}"
if [ ! -x "$venv/bin/python" ]; then
  "$python" -m venv "$venv"
  "$venv/bin/python" -m pip install --quiet --upgrade pip
fi
# The CPU wheel of torch lies in /opt/wheels on these machines; a looser source would pull a CUDA build.
find_links=()
[ -d /opt/wheels ] && find_links=(--find-links /opt/wheels)
target="$repo"
[ -n "$extras" ] && target="$repo[$extras]"
"$venv/bin/python" -m pip install --quiet "${find_links[@]}" -e "$target"
