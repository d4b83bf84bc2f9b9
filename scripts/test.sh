#!/usr/bin/env bash
# One command from a fresh clone to the test results: installs everything the tests need, then runs pytest.
# Usage: scripts/test.sh [pytest args]   e.g. scripts/test.sh -m slow
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
venv="${T2M_VENV:-$repo/.venv}"
"$repo/scripts/setup_env.sh" "$venv" "train,dev"
cd "$repo"
exec "$venv/bin/pytest" "$@"
