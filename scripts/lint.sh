#!/usr/bin/env bash
# Static checks: ruff, then mypy, both configured in pyproject.toml ([tool.ruff], [tool.mypy]).
# Installs what they need as scripts/test.sh does: the dev extra pins ruff, mypy and the stub packages, and train
# gives mypy torch's types for t2m.model and t2m.export. Both checks run even if the first fails.
# Usage: scripts/lint.sh
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
venv="${T2M_VENV:-$repo/.venv}"
"$repo/scripts/setup_env.sh" "$venv" "train,dev"
cd "$repo"
status=0
echo "== ruff check ."
"$venv/bin/ruff" check . || status=1
echo "== mypy"
"$venv/bin/mypy" || status=1
exit "$status"
