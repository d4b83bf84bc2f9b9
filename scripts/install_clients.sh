#!/usr/bin/env bash
# Install the real third-party clients that `pytest -m clients` drives (CI runs this before that suite):
#   - Blender (Debian package; headless import of our BVH and glb)      ~170 MB download, ~640 MB on disk, ~1 min
#   - the Khronos glTF validator (npm, pinned by tools/gltf-validator/package-lock.json)
#   - the independent BVH parsers from PyPI: bvh, bvhio
# Idempotent: what is already there is left alone. Needs root (or sudo) for apt-get.
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
python="${PYTHON:-python}"
sudo=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "install_clients.sh: need root or sudo for apt-get" >&2; exit 1; }
  sudo="sudo"
fi

apt_packages=()
command -v blender >/dev/null || apt_packages+=(blender)
command -v node >/dev/null || apt_packages+=(nodejs)
command -v npm >/dev/null || apt_packages+=(npm)
# Debian's Blender runs on the system Python; its glTF importer needs numpy there (a recommended package).
/usr/bin/python3 -c "import numpy" 2>/dev/null || apt_packages+=(python3-numpy)
if [ "${#apt_packages[@]}" -gt 0 ]; then
  echo "install_clients.sh: apt-get install ${apt_packages[*]}"
  $sudo apt-get update -q
  $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${apt_packages[@]}"
fi

echo "install_clients.sh: npm ci in tools/gltf-validator"
(cd "$repo/tools/gltf-validator" && npm ci --no-audit --no-fund --loglevel=error)

echo "install_clients.sh: pip install bvh bvhio"
"$python" -m pip install -q "bvh==0.3" "bvhio==1.5.4"

# --- chromium: headless browser for tests/clients/test_viewer.py (the web viewer at /) -------------------------------
# The Debian package, driven over the DevTools protocol by tests/clients/chromium_cdp.py (websockets, already a
# dependency of uvicorn[standard]): no Playwright/Selenium, no browser download at test time.
if ! command -v chromium >/dev/null; then
  echo "install_clients.sh: apt-get install chromium"
  $sudo apt-get update -q
  $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends chromium
fi
echo "install_clients.sh: $(chromium --version 2>/dev/null | head -1)"
# --- end chromium ----------------------------------------------------------------------------------------------------

echo "install_clients.sh: done ($(blender --version 2>/dev/null | head -1); node $(node --version))"
